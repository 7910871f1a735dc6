"""Sessions on disk (rimu.session/1): round trip, every loader error, and the CLI end to end."""

from __future__ import annotations

import filecmp
import json
import shutil

import numpy as np
import pytest

from calibration.presets import preset
from calibration.session_io import load_session, save_session
from calibration.truth import load_truth
from fdi.errors import FileFormatError
from fdi.units import DPH
from rimu.cli import main


def _same(a, b, exact_angles=False):
    for col in ("t", "step", "raw_gyro"):
        np.testing.assert_array_equal(getattr(b, col), getattr(a, col), err_msg=col)
    if a.raw_accel is None:
        assert b.raw_accel is None
    else:
        np.testing.assert_array_equal(b.raw_accel, a.raw_accel, err_msg="raw_accel")
    for col in ("inner", "outer", "inner_rate", "outer_rate"):
        np.testing.assert_allclose(getattr(b, col), getattr(a, col), rtol=5e-16, atol=5e-15,
                                   err_msg=col)
    assert b.sample_rate_hz == a.sample_rate_hz and b.latitude_deg == a.latitude_deg
    assert b.gravity == a.gravity
    assert (b.gyro_raw_unit, b.accel_raw_unit) == (a.gyro_raw_unit, a.accel_raw_unit)
    np.testing.assert_array_equal(b.gyro_config.H, a.gyro_config.H)
    assert b.gyro_config.sensor_names == a.gyro_config.sensor_names
    assert b.gyro_config.groups == a.gyro_config.groups
    assert [(s.index, s.kind, s.label, s.pair) for s in b.steps] == \
           [(s.index, s.kind, s.label, s.pair) for s in a.steps]
    for sa, sb in zip(a.steps, b.steps, strict=True):
        np.testing.assert_array_equal(sb.mat_pb, sa.mat_pb, err_msg=f"step {sa.index} mat_pb")


def test_round_trip(tmp_path, tiny_session, tetrad_session):
    for name, s in (("tiny", tiny_session), ("tetrad", tetrad_session)):
        d = tmp_path / name
        save_session(s, d)
        back = load_session(d)
        _same(s, back)
        assert back.meta["mounts"] == s.meta["mounts"]
        assert back.meta["sequence"] == s.meta["sequence"]
        # save -> load -> save reproduces the files byte for byte
        save_session(back, tmp_path / (name + "2"))
        for f in ("manifest.json", "samples.csv"):
            assert filecmp.cmp(d / f, tmp_path / (name + "2") / f, shallow=False), f
    np.testing.assert_allclose(back.inputs()[0], tetrad_session.inputs()[0], atol=1e-15)


def test_documented_columns(tmp_path, tiny_session):
    save_session(tiny_session, tmp_path)
    header = (tmp_path / "samples.csv").read_text().splitlines()[0].split(",")
    assert header[:6] == ["t", "step", "inner_deg", "outer_deg", "inner_rate_dps",
                          "outer_rate_dps"]
    assert header[6:] == [f"gyro.{n}" for n in ("x1", "y1", "z1", "x2", "y2", "z2")] + \
                         [f"accel.{n}" for n in ("x1", "y1", "z1", "x2", "y2", "z2")]
    m = json.loads((tmp_path / "manifest.json").read_text())
    assert m["schema"] == "rimu.session/1"
    assert m["samples"]["columns"] == header
    assert m["raw_units"] == {"gyro": "LSB", "accel": "LSB"}
    assert m["steps"][2]["pair"] == 4 and m["steps"][0]["mount"] == "x_inner_z_up"


@pytest.fixture()
def saved(tmp_path, tiny_session):
    d = tmp_path / "s"
    save_session(tiny_session, d)
    return d


def _edit_manifest(d, fn):
    p = d / "manifest.json"
    doc = json.loads(p.read_text())
    fn(doc)
    p.write_text(json.dumps(doc))


def _edit_csv(d, fn):
    p = d / "samples.csv"
    lines = p.read_text().splitlines()
    fn(lines)
    p.write_text("\n".join(lines) + "\n")


def _set_cell(lines, lineno, col, value):
    cells = lines[lineno - 1].split(",")
    cells[lines[0].split(",").index(col)] = value
    lines[lineno - 1] = ",".join(cells)


def _load_err(d):
    with pytest.raises(FileFormatError) as ei:
        load_session(d)
    return ei.value


def test_missing_files(saved):
    (saved / "samples.csv").unlink()
    e = _load_err(saved)
    assert e.path.endswith("samples.csv") and "cannot read" in str(e)
    (saved / "manifest.json").unlink()
    e = _load_err(saved)
    assert e.path.endswith("manifest.json")
    e = _load_err(saved / "nowhere")
    assert "no such session directory" in str(e)


@pytest.mark.parametrize(("what", "edit", "field", "step"), [
    ("wrong schema", lambda d: d.update(schema="rimu.flight/1"), "schema", None),
    ("wrong version", lambda d: d.update(schema="rimu.session/2"), "schema", None),
    ("unknown unit", lambda d: d["raw_units"].update(gyro="furlongs"), "raw_units.gyro", None),
    ("missing rate", lambda d: d.pop("sample_rate_hz"), "sample_rate_hz", None),
    ("bad latitude", lambda d: d.update(latitude_deg=123.0), "latitude_deg", None),
    ("bad step kind", lambda d: d["steps"][1].update(kind="spin"), "kind", 2),
    ("bad mounting", lambda d: d["steps"][2].update(mat_pb=[[1, 0, 0], [0, 1, 0], [0, 0, 2]]),
     "mat_pb", 3),
    ("dangling pair", lambda d: d["steps"][2].update(pair=9), "pair", 3),
    ("bad axes", lambda d: d["configuration"]["gyro"]["axes"].__setitem__(0, [2, 0, 0]),
     "configuration.gyro", None),
    ("names", lambda d: d["configuration"]["gyro"].update(sensor_names=["a"]),
     "configuration.gyro.sensor_names", None),
])
def test_manifest_errors(saved, what, edit, field, step):
    _edit_manifest(saved, edit)
    e = _load_err(saved)
    assert e.path.endswith("manifest.json"), what
    assert e.field == field, f"{what}: {e}"
    assert e.step == step, f"{what}: {e}"


def test_bad_json(saved):
    (saved / "manifest.json").write_text('{"schema": "rimu.session/1",\n "oops"\n}')
    e = _load_err(saved)
    assert e.line == 3 and "not valid JSON" in str(e)


def test_missing_column(saved):
    def drop(lines):
        cols = lines[0].split(",")
        j = cols.index("gyro.z1")
        for k, ln in enumerate(lines):
            cells = ln.split(",")
            del cells[j]
            lines[k] = ",".join(cells)
    _edit_csv(saved, drop)
    e = _load_err(saved)
    assert e.field == "gyro.z1" and e.line == 1 and "missing column" in str(e)


def test_nan_sample_names_line_step_and_column(saved):
    _edit_csv(saved, lambda lines: _set_cell(lines, 120, "accel.y2", "nan"))
    e = _load_err(saved)
    # line 120 is data row 119 (0-based 118): the tiny session's steps are 50, 50, 100, 100
    assert (e.line, e.field, e.step) == (120, "accel.y2", 3), str(e)
    assert "finite" in str(e)


def test_non_numeric_sample(saved):
    _edit_csv(saved, lambda lines: _set_cell(lines, 7, "outer_deg", "abc"))
    e = _load_err(saved)
    assert (e.line, e.field) == (7, "outer_deg"), str(e)
    assert "'abc'" in str(e)


def test_ragged_row(saved):
    def cut(lines):
        lines[9] = ",".join(lines[9].split(",")[:-2])
    _edit_csv(saved, cut)
    e = _load_err(saved)
    assert e.line == 10 and "expected 18" in str(e)


def test_step_not_in_manifest(saved):
    _edit_csv(saved, lambda lines: _set_cell(lines, 300, "step", "7"))
    e = _load_err(saved)
    assert (e.line, e.field) == (300, "step") and "not a step of the manifest" in str(e)


def test_truncated_file(saved):
    _edit_csv(saved, lambda lines: lines.__delitem__(slice(250, None)))
    e = _load_err(saved)
    assert e.field == "samples.rows" and "249 sample rows, the manifest says 300" in str(e)


def test_step_with_too_few_samples(saved):
    # keep only 5 samples of step 2 (rows 52..101 hold step 2)
    _edit_csv(saved, lambda lines: lines.__delitem__(slice(56, 101)))
    _edit_manifest(saved, lambda d: d["samples"].pop("rows"))
    e = _load_err(saved)
    assert (e.step, e.field) == (2, "step") and "5 samples, expected at least 10" in str(e)


def test_time_not_increasing(saved):
    _edit_csv(saved, lambda lines: _set_cell(lines, 40, "t", "0"))
    e = _load_err(saved)
    assert (e.line, e.field, e.step) == (40, "t", 1), str(e)


# -- CLI end to end ----------------------------------------------------------------------------
def test_cli_writes_a_loadable_session_and_truth(tmp_path, capsys):
    out = tmp_path / "cone"
    rc = main(["simulate", "calibration", "--preset", "cone-paper", "--out", str(out),
               "--seed", "7", "--effect", "warmup=20", "--effect-sensors", "2"])
    assert rc == 0
    said = capsys.readouterr().out
    assert "cone-paper" in said and "warmup=20 on sensors 2" in said
    s = load_session(out)
    cal, eff, sens = load_truth(out / "truth.json")
    assert eff == {"warmup": 20.0} and sens == {"warmup": (2,)}
    _, truth, _ = preset("cone-paper")
    np.testing.assert_allclose(cal.gyro.H, truth.gyro.H, atol=1e-15)
    np.testing.assert_allclose(cal.sets["accel"].biases, truth.sets["accel"].biases,
                               rtol=1e-14)
    assert cal.earth_rate_dph == pytest.approx(15.041, abs=1e-3)
    assert s.raw_gyro.shape == (36800, 6) and s.raw_accel.shape == (36800, 6)
    assert s.meta["seed"] == 7


def test_cli_random_parameters_and_custom_sequence(tmp_path, capsys):
    seq = tmp_path / "seq.toml"
    seq.write_text('schema = "rimu.sequence/1"\ntable_rate_dps = 60.0\n'
                   'mount = "x_inner_y_up"\n'
                   '[[steps]]\ninner_rate_w = 1\n[[steps]]\ninner_rate_w = -1\n'
                   '[[steps]]\nouter_rate_w = 1\n[[steps]]\nouter_rate_w = -1\n'
                   '[[steps]]\ninner_deg = 90\nouter_rate_w = 1\n'
                   '[[steps]]\ninner_deg = 90\nouter_rate_w = -1\n')
    rc = main(["simulate", "calibration", "--config", "tetrad", "--out", str(tmp_path / "t"),
               "--sequence", str(seq), "--latitude-deg", "48.1"])
    assert rc == 0
    s = load_session(tmp_path / "t")
    assert len(s.steps) == 6 and s.latitude_deg == 48.1 and s.raw_accel is None
    cal, eff, _ = load_truth(tmp_path / "t" / "truth.json")
    assert eff == {} and cal.latitude_deg == 48.1
    capsys.readouterr()


def test_cli_extra_noise_recorded(tmp_path, capsys):
    rc = main(["simulate", "calibration", "--preset", "tetrad-paper", "--out",
               str(tmp_path / "n"), "--bias-instability-dph", "2", "--bias-correlation-s", "50",
               "--rate-random-walk-dph-rth", "0.5"])
    assert rc == 0
    assert "bias instability 2 deg/h" in capsys.readouterr().out
    doc = json.loads((tmp_path / "n" / "truth.json").read_text())
    noise = doc["extra"]["noise"]
    assert noise["bias_instability"]["gyro"] == pytest.approx(2 * DPH)
    assert noise["random_walk"]["gyro"] == pytest.approx(0.5 * DPH / 60)
    assert noise["bias_correlation_s"] == 50


@pytest.mark.parametrize("argv", [
    ["--config", "nonesuch"],
    ["--preset", "cone-paper", "--config", "tetrad"],
    ["--config", "tetrad", "--effect", "wobble=1"],
    ["--config", "tetrad", "--effect", "warmup=1", "--effect-sensors", "9"],
    ["--config", "tetrad", "--sequence", "missing.toml"],
    ["--out-missing-config"],
    ["--config", "tetrad", "--bias-instability-dph", "-1"],
    ["--config", "tetrad", "--turns", "0.001"],
])
def test_cli_errors_one_line_exit_2(tmp_path, capsys, argv):
    if argv == ["--out-missing-config"]:
        argv = []
    rc = main(["simulate", "calibration", "--out", str(tmp_path / "x"), *argv])
    err = capsys.readouterr().err
    assert rc == 2
    assert err.startswith("rimu: error:") and err.count("\n") == 1, err
    shutil.rmtree(tmp_path / "x", ignore_errors=True)


@pytest.mark.parametrize(("edit", "field", "step"), [
    (lambda d: d.update(latitude=1.0), "latitude", None),
    (lambda d: d["steps"][1].update(lable="x"), "lable", 2),
    (lambda d: d["samples"].update(row=3), "samples.row", None),
    (lambda d: d["steps"][1].update(index=1), "steps[2].index", None),
])
def test_unknown_or_duplicate_manifest_keys_are_refused(saved, edit, field, step):
    _edit_manifest(saved, edit)
    e = _load_err(saved)
    assert (e.field, e.step) == (field, step), str(e)
