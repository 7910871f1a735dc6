"""``rimu repeat``: text and JSON output, --out, and one-line errors (exit 2) on bad input."""

import json

import pytest
from _cli import run as _run
from _diagnose_sessions import session

from calibration.session_io import save_session


@pytest.fixture(scope="module")
def dirs(tmp_path_factory):
    d = tmp_path_factory.mktemp("repeat")
    for k in (1, 2):
        save_session(session("tetrad-paper", 7100 + k)[0], d / f"s{k}")
    save_session(session("cone-paper", 1)[0], d / "cone")
    s, _ = session("tetrad-paper", 7103)
    import dataclasses

    save_session(dataclasses.replace(s, outer=s.outer + 0.05), d / "shifted")
    return d


def test_json_parses_and_says_why_not_stacked(dirs, capsys):
    code, out, err = _run(capsys, "repeat", dirs / "s1", dirs / "shifted", "--json",
                          "--out", dirs / "out1")
    assert code == 0, err
    doc = json.loads(out)
    assert doc["schema"] == "rimu.repeat/1"
    assert len(doc["sessions"]) == 2 and len(doc["session_verdicts"]) == 2
    rep = doc["repeatability"]
    assert rep["n_tested"] == 16 and len(rep["parameters"]) == 16
    p = rep["parameters"][0]
    assert p["sensor"] == 1 and p["parameter"] == "bias" and p["dof"] == 1
    assert len(p["values"]) == 2 and p["run_sd_ci"][0] <= p["run_sd_ci"][1]
    assert doc["stack"] is None and "outer angle" in doc["stack_skipped"]
    for f in ("calibration_1.json", "calibration_2.json", "repeat.json"):
        assert (dirs / "out1" / f).is_file(), f
    assert not (dirs / "out1" / "stacked_calibration.json").exists()


@pytest.mark.slow
def test_text_and_stack_written(dirs, capsys):
    code, out, err = _run(capsys, "repeat", dirs / "s1", dirs / "s2", "--out", dirs / "out")
    assert code == 0, err
    assert "run-to-run repeatability" in out and "stack of 2 sessions" in out
    assert "model adequacy (alpha 0.01):" in out
    for f in ("calibration_1.json", "calibration_2.json", "stacked_calibration.json",
              "stacked/manifest.json", "repeat.json"):
        assert (dirs / "out" / f).is_file(), f
    doc = json.loads((dirs / "out" / "repeat.json").read_text())
    assert doc["schema"] == "rimu.repeat/1" and doc["stack"]["n_sessions"] == 2
    assert doc["stack"]["verdict"] in ("adequate", "adequate within sequence limits",
                                       "effects not ruled out",
                                       "effects suspected")


@pytest.mark.parametrize("case,needle", [
    ("single", "at least two sessions"),
    ("config", "gyro configuration"),
    ("missing", "nope"),
    ("stack", "outer angle"),
])
def test_bad_input_one_line_exit_2(dirs, capsys, case, needle):
    argv = {"single": ["repeat", dirs / "s1"],
            "config": ["repeat", dirs / "s1", dirs / "cone"],
            "missing": ["repeat", dirs / "s1", dirs / "nope"],
            "stack": ["repeat", dirs / "s1", dirs / "shifted", "--stack"]}[case]
    code, out, err = _run(capsys, *argv)
    assert code == 2
    assert out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0], err
