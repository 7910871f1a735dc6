"""Issue 30, the edges a user touches: a CLI harness over every command that reads a file.

For each command: deep, huge, non-finite and negative fields, gaps, duplicates and outputs
over inputs. Every refusal is one line and exit 2, no traceback, no wrong exit 0, and no
input file changes (the inputs are hashed before and after every call). The commands run
in-process (``rimu.cli.main``) on small files made once per module: a simulated two-IMU
flight calibrated in flight (the calibration file with the most fields rimu writes).
"""

from __future__ import annotations

import copy
import hashlib
import json
import math
import re
import time
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import chi2

from fdi.calfile import CALIBRATION_NUMBER_RULES, calibration_from_dict
from fdi.errors import FileFormatError
from fdi.fileio import number_rule
from fdi.settings import Thresholds
from rimu.cli import main

RUN_LIMIT_S = 60.0


@pytest.fixture(scope="module")
def world(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("edges")
    assert main(["simulate", "flight", "--imus", "2", "--duration", "30", "--seed", "3",
                 "--out", str(d / "fl")]) == 0
    assert main(["calibrate", "in-flight", str(d / "fl"), "--out", str(d / "cal.json")]) == 0
    assert main(["simulate", "flight", "--imus", "2", "--duration", "30", "--seed", "4",
                 "--max-rate", "0.001", "--out", str(d / "rest")]) == 0
    assert main(["simulate", "flight", "--cal", str(d / "cal.json"), "--duration", "2",
                 "--out", str(d / "log.asc")]) == 0
    thr = Thresholds(kind="gyro", n=6, sample_rate_hz=50.0, false_alarms_per_hour=1.0,
                     scales=(1, 8), alpha=(1e-7, 1e-7), variance_factor=(1.0, 1.0),
                     threshold=(float(chi2.isf(1e-7, 3)),) * 2)
    thr.save(d / "thr.json")
    (d / "out").mkdir()
    return {"d": d, "fl": d / "fl", "rest": d / "rest", "cal": d / "cal.json", "log": d / "log.asc",
            "map": d / "log.map.toml", "thr": d / "thr.json", "out": d / "out"}


def _hashes(w) -> dict[str, str]:
    """sha256 of every input file of the module (everything but ``out/``)."""
    return {str(p.relative_to(w["d"])): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(w["d"].rglob("*")) if p.is_file()
            and w["out"] not in p.parents}


def run(capsys, w, argv) -> tuple[int, str, str]:
    """Run argv in-process; the inputs must not change, and it must end within a minute."""
    capsys.readouterr()
    before = _hashes(w)
    t0 = time.monotonic()
    rc = main([str(a) for a in argv])
    took = time.monotonic() - t0
    cap = capsys.readouterr()
    assert took < RUN_LIMIT_S, (argv, took)
    assert _hashes(w) == before, f"an input changed: {argv}"
    return rc, cap.out, cap.err


def refused(capsys, w, argv, needle: str = "") -> str:
    """exit 2, one stderr line containing ``needle``, no traceback."""
    rc, _, err = run(capsys, w, argv)
    lines = err.strip().splitlines()
    errs = [x for x in lines if x.startswith("rimu: error:")]
    assert rc == 2, (argv, err)
    assert len(errs) == 1 and "Traceback" not in err, err
    assert needle in errs[0], (needle, errs[0])
    return errs[0]


# -- the commands that read a calibration, and how each is called --------------------------
def _cal_commands(w, cal) -> dict[str, list]:
    o = w["out"]
    return {
        "monitor-file": ["monitor-file", w["fl"], "--cal", cal],
        "tune": ["tune", "--cal", cal, "--false-alarms-per-hour", "1", "--out", o / "t.json"],
        "export c": ["export", "c", "--cal", cal, "--thresholds", w["thr"], "--out", o / "c"],
        "evaluate": ["evaluate", "--cal", cal, "--runs", "1", "--duration", "10",
                     "--out", o / "ev"],
        "replay": ["replay", w["log"], "--cal", cal, "--map", w["map"]],
        "diagnose": ["diagnose", w["fl"], "--cal", cal],
        "simulate flight": ["simulate", "flight", "--cal", cal, "--duration", "2",
                            "--out", o / "sf"],
        "parity": ["parity", "cone6", "--misalignment", cal],
        "monitor": ["monitor", "--interface", "virtual", "--channel", "edges-never",
                    "--cal", cal, "--duration", "0.1"],
    }


def _leaves(doc, path=()):
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from _leaves(v, (*path, k))
    elif isinstance(doc, list):
        for j, v in enumerate(doc):
            yield from _leaves(v, (*path, j))
    elif isinstance(doc, int | float) and not isinstance(doc, bool):
        yield path, doc


def _set(doc, path, value):
    doc = copy.deepcopy(doc)
    _put(doc, path, value)
    return doc


def _put(doc, path, value):
    """Set the leaf at ``path`` in place; return the value it held."""
    for k in path[:-1]:
        doc = doc[k]
    old, doc[path[-1]] = doc[path[-1]], value
    return old


def _keys(path) -> str:
    return ".".join(k for k in path if isinstance(k, str))


def _bad_values(path, value) -> list[float]:
    """NaN, inf and, where the rule bounds the field, a value beyond each bound."""
    out = [math.nan, math.inf if value >= 0 else -math.inf]
    idx = [k for k in path if isinstance(k, int)]
    rule = number_rule(_keys(path), CALIBRATION_NUMBER_RULES, idx)
    if rule is not None and rule.lo is not None:
        out.append(rule.lo - 1.0 - abs(value) if rule.lo == 0 else rule.lo - abs(rule.lo))
    if rule is not None and rule.hi is not None:
        out.append(rule.hi + 1.0 + abs(rule.hi))
    return out


def _field_name(path) -> str:
    out = ""
    for k in path:
        out += f"[{k + 1}]" if isinstance(k, int) else (f".{k}" if out else k)
    return out


def test_every_numeric_leaf_of_a_real_calibration_is_checked_on_load(world):
    """Each numeric leaf set to NaN, ±inf or beyond its rule's bound: refused naming it."""
    doc = json.loads(world["cal"].read_text())
    calibration_from_dict(doc, "cal.json")          # the file itself loads
    leaves = list(_leaves(doc))
    assert len(leaves) > 400 and any(_keys(p).startswith("extra.inflight") for p, _ in leaves)
    missed = []
    for path, v in leaves:
        for bad in _bad_values(path, v):
            _put(doc, path, bad)
            try:
                calibration_from_dict(doc, "cal.json")
            except FileFormatError as exc:
                assert "\n" not in str(exc)
            else:
                missed.append((_field_name(path), bad))
            finally:
                _put(doc, path, v)
    assert not missed, missed[:20]


@pytest.mark.parametrize("field", [
    "sensors.gyro.bias_sd", "sensors.gyro.scale_factor_sd", "sensors.gyro.misalignment_mrad_sd",
    "sensors.gyro.residual_rms", "sensors.gyro.timing_jitter_ms",
    "noise_covariance.sample_rate_hz", "sample_rate_hz", "allan.gyro.tau_s", "allan.gyro.adev",
    "residual_tails.gyro.scales.quantile", "residual_tails.gyro.scales.quantile_upper",
    "extra.inflight.imus.imu2.time_offset_ms_sd", "extra.inflight.imus.imu2.timing_jitter_ms",
    "extra.inflight.imus.imu2.scale_sd", "extra.inflight.imus.imu2.residual_rms_dps",
    "extra.inflight.imus.imu2.time_offset_check.sd_bootstrap_ms",
])
def test_fields_that_must_be_nonnegative_have_a_rule_saying_so(field):
    """The issue's classes (sds, Allan tau/adev, tail quantiles, rates): lo >= 0."""
    rule = number_rule(field, CALIBRATION_NUMBER_RULES, [])
    assert rule is not None and rule.lo is not None and rule.lo >= 0, (field, rule)


def test_covariance_diagonals_must_be_nonnegative():
    for key in ("noise_covariance.gyro", "sensors.gyro.input_error_cov"):
        diag = number_rule(key, CALIBRATION_NUMBER_RULES, [1, 1])
        off = number_rule(key, CALIBRATION_NUMBER_RULES, [0, 1])
        assert diag is not None and diag.lo == 0.0, key
        assert off is None or off.lo is None, key


def _classes(doc):
    """One leaf per field class (path with indices dropped), first one found."""
    seen = {}
    for path, v in _leaves(doc):
        seen.setdefault(re.sub(r"\d+", "#", repr([k if isinstance(k, str) else 0
                                                  for k in path])), (path, v))
    return list(seen.values())


def _every_class_every_command(world, capsys, rotate: bool) -> None:
    doc = json.loads(world["cal"].read_text())
    bad_cal = world["out"] / "bad_cal.json"
    classes = _classes(doc)
    assert len(classes) > 40
    commands = list(_cal_commands(world, bad_cal).items())
    for j, (path, v) in enumerate(classes):
        bads = _bad_values(path, v)
        bad = bads[j % len(bads)]
        bad_cal.write_text(json.dumps(_set(doc, path, bad)))
        name = _field_name(path)
        for cmd, argv in ([commands[j % len(commands)]] if rotate else commands):
            line = refused(capsys, world, argv)
            assert name.split("[")[0].split(".")[-1] in line, (cmd, name, line)


def test_each_class_of_bad_calibration_field_is_refused_in_one_line(world, capsys):
    """Every class of numeric field (one leaf each, the bad value rotating over NaN, inf
    and out of range), each through one command that reads calibrations (rotating):
    exit 2, one line naming the field."""
    _every_class_every_command(world, capsys, rotate=True)


@pytest.mark.campaign
def test_every_command_refuses_every_class_of_bad_calibration_field(world, capsys):
    """The same for every command on every class (about 550 runs, 25 s: ``--campaign``)."""
    _every_class_every_command(world, capsys, rotate=False)


def test_each_command_refuses_one_bad_field(world, capsys):
    """The fast cut of the test above: one NaN in ``extra.inflight`` (not read by any
    command's arithmetic, so only the load-time rule can catch it) for every command."""
    doc = json.loads(world["cal"].read_text())
    bad_cal = world["out"] / "bad_cal1.json"
    bad_cal.write_text(json.dumps(_set(doc, ("extra", "inflight", "imus", "imu2",
                                             "time_offset_ms"), math.nan)))
    for _, argv in _cal_commands(world, bad_cal).items():
        refused(capsys, world, argv, "extra.inflight.imus.imu2.time_offset_ms")


# -- bounded parsers ------------------------------------------------------------------------
def _deep_json(n=100_000) -> str:
    return "[" * n + "]" * n


def test_deep_nesting_and_huge_numbers_refused_everywhere(world, capsys):
    doc = json.loads(world["cal"].read_text())
    o = world["out"]
    deep_cal = o / "deep_cal.json"
    text = json.dumps(_set(doc, ("extra", "method"), None))
    deep_cal.write_text(text.replace('"method": null', '"method": ' + _deep_json(), 1))
    digits = o / "digits_cal.json"
    digits.write_text(text.replace('"sample_rate_hz": 50.0', '"sample_rate_hz": '
                                   + "5" * 5000, 1))
    for cal, needle in ((deep_cal, "nested deeper"), (digits, "5000 digits")):
        for cmd in ("monitor-file", "tune", "export c"):
            refused(capsys, world, _cal_commands(world, cal)[cmd], needle)
    deep_thr = o / "deep_thr.json"
    deep_thr.write_text('{"schema": "rimu.thresholds/2", "x": ' + _deep_json() + "}")
    refused(capsys, world, ["monitor-file", world["fl"], "--cal", world["cal"],
                            "--thresholds", deep_thr], "nested deeper")
    refused(capsys, world, ["export", "c", "--cal", world["cal"], "--thresholds", deep_thr,
                            "--out", o / "c"], "nested deeper")
    deep_toml = o / "deep.toml"
    deep_toml.write_text("x = " + _deep_json() + "\n")
    refused(capsys, world, ["parity", deep_toml], "nested deeper")
    refused(capsys, world, ["ingest", world["fl"] / "samples.csv", "--map", deep_toml,
                            "--out", o / "ing"], "nested deeper")
    deep_sec = o / "sections.json"
    deep_sec.write_text('{"a": ' + _deep_json() + "}")
    fer = o / "fer.csv"
    fer.write_text("gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z\n" + "0,0,0,0,0,9.8\n" * 10)
    refused(capsys, world, ["calibrate", "ferraris", fer, "--sections", deep_sec,
                            "--sample-rate-hz", "100", "--out", o / "f.json"],
            "nested deeper")


def test_a_huge_scale_factor_and_a_missing_raw_unit_are_refused(world, capsys):
    doc = json.loads(world["cal"].read_text())
    o = world["out"]
    huge = o / "huge_sf.json"
    huge.write_text(json.dumps(_set(doc, ("sensors", "gyro", 0, "scale_factor"), 1e300)))
    refused(capsys, world, _cal_commands(world, huge)["monitor-file"], "scale_factor")
    no_unit = copy.deepcopy(doc)
    del no_unit["sensors"]["gyro"][2]["raw_unit"]
    nu = o / "no_unit.json"
    nu.write_text(json.dumps(no_unit))
    refused(capsys, world, _cal_commands(world, nu)["monitor-file"], "raw_unit")


def test_a_manifest_rate_the_time_stamps_contradict_is_refused(world, capsys, tmp_path):
    import shutil

    fl = tmp_path / "fl500"
    shutil.copytree(world["fl"], fl)
    man = json.loads((fl / "manifest.json").read_text())
    man["sample_rate_hz"] = 500.0
    (fl / "manifest.json").write_text(json.dumps(man))
    refused(capsys, world, ["monitor-file", fl, "--cal", world["cal"]], "sample_rate_hz")
    refused(capsys, world, ["characterise", fl], "time stamps show")


# -- outputs over inputs ----------------------------------------------------------------------
def test_no_output_is_or_lies_inside_an_input(world, capsys):
    fl, cal = world["fl"], world["cal"]
    cases = [
        ["calibrate", "static", fl, "--out", fl / "samples.csv"],
        ["calibrate", "in-flight", fl, "--out", fl / "cal.json"],
        ["calibrate", "in-flight", fl, "--out", world["out"] / "x.json", "--report", fl],
        ["characterise", fl, "--report", fl],
        ["characterise", fl, "--report", fl / "rep"],
        ["monitor-file", fl, "--cal", cal, "--report", fl / "r.json"],
        ["monitor-file", fl, "--cal", cal, "--report", cal],
        ["diagnose", fl, "--cal", cal, "--report", fl / "d"],
        ["diagnose", fl, "--cal", cal, "--out", cal],
        ["tune", "--cal", cal, "--false-alarms-per-hour", "1", "--out", cal],
        ["export", "c", "--cal", cal, "--out", cal],
        ["evaluate", "--cal", cal, "--runs", "1", "--corpus", fl, "--out", fl / "ev"],
        ["replay", world["log"], "--cal", cal, "--map", world["map"], "--report", world["log"]],
        ["replay", world["log"], "--cal", cal, "--map", world["map"], "--rrd", world["map"]],
        ["ingest", fl / "samples.csv", "--out", fl / "samples.csv"],
        ["simulate", "flight", "--cal", cal, "--duration", "2", "--out", cal],
    ]
    for argv in cases:
        refused(capsys, world, argv, "input")


# -- no silent gap ----------------------------------------------------------------------------
def _edit_samples(src: Path, dst: Path, edit) -> Path:
    """A copy of the flight folder ``src`` whose rows (and aux rows) ``edit(i, cells)`` changes."""
    import shutil

    shutil.copytree(src, dst)
    for f in ("truth.json", "truth_rates.npy"):
        (dst / f).unlink(missing_ok=True)
    for name in ("samples.csv", "aux.csv"):
        p = dst / name
        if not p.exists():
            continue
        head, *rows = p.read_text().splitlines()
        out = [head]
        for i, r in enumerate(rows):
            c = r.split(",")
            edit(i, c, name)
            out.append(",".join(c))
        p.write_text("\n".join(out) + "\n")
    return dst


@pytest.fixture(scope="module")
def gappy(world) -> Path:
    """The flight with a 1e6 s gap, 50 duplicate time stamps and 200 all-NaN rows."""
    t = [float(r.split(",")[0]) for r in
         (world["rest"] / "samples.csv").read_text().splitlines()[1:]]

    def edit(i, c, name):
        x = t[i] + (1e6 if i >= 1000 else 0.0)
        if 300 < i <= 350:
            x = t[300]
        c[0] = repr(x)
        if name == "samples.csv" and 600 <= i < 800:
            c[1:] = ["nan"] * (len(c) - 1)

    return _edit_samples(world["rest"], world["d"] / "gappy", edit)


def _warnings(err: str) -> list[str]:
    return [x for x in err.splitlines() if x.startswith("rimu: warning:")]


def test_gaps_duplicates_and_empty_rows_are_said_by_every_flight_reader(world, gappy, capsys):
    o = world["out"]
    runs = {
        "monitor-file": ["monitor-file", gappy, "--cal", world["cal"], "--report",
                         o / "mf.json"],
        "characterise": ["characterise", gappy, "--json"],
        "calibrate static": ["calibrate", "static", gappy, "--out", o / "st.json"],
    }
    for cmd, argv in runs.items():
        rc, out, err = run(capsys, world, argv)
        assert rc == 0, (cmd, err)
        said = [w for w in _warnings(err) if "in the time stamps" in w]
        assert len(said) == 1, (cmd, err)
        assert all(k in said[0] for k in ("2 gaps", "50 duplicate", "200 rows")), said
        if cmd == "characterise":
            tb = json.loads(out)["time_base"]
        elif cmd == "monitor-file":
            tb = json.loads((o / "mf.json").read_text())["time_base"]
            span = tb["span_s"]
            assert f"{span:.6g} s of time stamps" in out        # as ingest states it
            assert "monitored across 2 gap(s)" in out
        else:
            tb = json.loads((o / "st.json").read_text())["extra"]["time_base"]
        assert (tb["gaps"], tb["duplicate_time_stamps"], tb["empty_rows"]) == (2, 50, 200)
        assert tb["gap_longest_s"] > 1e6 - 1


def test_a_clean_flight_gets_no_warning_and_says_it_is_regular(world, capsys):
    rc, out, err = run(capsys, world, ["monitor-file", world["fl"], "--cal", world["cal"]])
    assert rc == 0 and not [w for w in _warnings(err) if "time stamps" in w], err
    assert "time stamps: regular" in out
    assert "alarms 0 inside the envelope, 0 outside it" in out


def test_backward_time_stamps_refused_with_their_count(world, capsys):
    def edit(i, c, name):
        if i in (100, 500):
            c[0] = "0.0"

    back = _edit_samples(world["fl"], world["d"] / "back", edit)
    line = refused(capsys, world, ["monitor-file", back, "--cal", world["cal"]],
                   "time goes backwards (2 time stamps")
    assert "samples.csv:102" in line


def _renamed(world, name, names) -> Path:
    import shutil

    d = world["d"] / name
    shutil.copytree(world["fl"], d)
    man = json.loads((d / "manifest.json").read_text())
    man["sensor_names"] = names(man["sensor_names"])
    man["columns"] = ["t", *man["sensor_names"]]
    (d / "manifest.json").write_text(json.dumps(man))
    _, body = (d / "samples.csv").read_text().split("\n", 1)
    (d / "samples.csv").write_text(",".join(man["columns"]) + "\n" + body)
    return d


def test_sensor_names_other_than_the_calibrations(world, capsys):
    perm = _renamed(world, "perm", lambda n: [n[1], n[0], *n[2:]])
    refused(capsys, world, ["monitor-file", perm, "--cal", world["cal"]], "another order")
    other = _renamed(world, "other", lambda n: list("abcdef"))
    rc, _, err = run(capsys, world, ["monitor-file", other, "--cal", world["cal"]])
    assert rc == 0
    assert any("matched by position" in w and "a=imu1.x" in w for w in _warnings(err)), err


# -- up-front refusals --------------------------------------------------------------------------
def test_a_zero_filled_samples_file_stops_the_command_at_once(world, capsys, tmp_path):
    import os
    import shutil

    d = tmp_path / "sparse"          # outside the hashed inputs: 2 GiB would be read there
    shutil.copytree(world["fl"], d)
    os.truncate(d / "samples.csv", 2 << 30)            # 2 GiB, sparse: NUL bytes after the text
    for argv in (["monitor-file", d, "--cal", world["cal"]], ["characterise", d]):
        t0 = time.monotonic()
        refused(capsys, world, argv, "NUL byte")
        assert time.monotonic() - t0 < 30


def test_work_that_cannot_finish_and_ignored_options_are_refused(world, capsys):
    cal, o = world["cal"], world["out"]
    line = refused(capsys, world, ["evaluate", "--cal", cal, "--runs", "100000", "--duration",
                                   "86400", "--out", o / "ev"], "--yes")
    assert "100000 flight(s)" in line and "budget" in line
    for argv in (["export", "c", "--cal", cal, "--thresholds", world["thr"],
                  "--false-alarms-per-hour", "5", "--out", o / "c"],
                 ["monitor-file", world["fl"], "--cal", cal, "--thresholds", world["thr"],
                  "--false-alarms-per-hour", "5"]):
        refused(capsys, world, argv, "--false-alarms-per-hour cannot be combined")
    refused(capsys, world, ["tune", "--cal", cal, "--false-alarms-per-hour", "1",
                            "--drift-horizon-s", "100", "--out", o / "t.json"], "drift model")


def test_a_dbc_factor_of_ten_gets_a_hint(world, capsys):
    from replay.frames import DEFAULT_DBC

    dbc = world["out"] / "x10.dbc"
    dbc.write_text(Path(DEFAULT_DBC).read_text().replace("(1,0) [-3.4E+038",
                                                         "(10,0) [-3.4E+038"))
    base = ["replay", world["log"], "--cal", world["cal"], "--map", world["map"]]
    rc, _, err = run(capsys, world, [*base, "--dbc", dbc])
    assert rc == 0 and any("a DBC factor" in w for w in _warnings(err)), err
    rc, _, err = run(capsys, world, base)
    assert rc == 0 and not any("a DBC factor" in w for w in _warnings(err)), err


# -- small lies ----------------------------------------------------------------------------------
def test_evaluate_without_flights_prints_no_nan_rate(world, capsys):
    rc, out, err = run(capsys, world, ["evaluate", "--cal", world["cal"], "--runs", "0",
                                       "--sweep-runs", "2", "--no-progress",
                                       "--out", world["out"] / "ev0"])
    assert rc == 0, err
    assert "nan" not in out and "no rate" in out
    assert "evaluate: 0 flight(s) of 60 s + 2 short sweep run(s)" in out


def test_repeat_never_prints_an_empty_interval_as_zero():
    from calibration.repeat import run_to_run_sd
    from rimu.commands.repeat import run_sd_text

    # five estimates scattered far less than their sigma: the Q-profile interval is empty
    tau, (lo, hi) = run_to_run_sd([0.0, 0.01, -0.01, 0.005, -0.005], [1.0] * 5)
    assert tau == 0.0 and hi == 0.0
    text = run_sd_text(tau, lo, hi)
    assert "[0, 0]" not in text and "no interval" in text
    assert run_sd_text(0.5, 0.1, 0.9).endswith("]")


def test_parity_prints_the_calibrated_axes_its_help_promises(world, capsys):
    rc, out, _ = run(capsys, world, ["parity", "cone6", "--misalignment", world["cal"]])
    assert rc == 0 and "H_c (calibrated axes) =" in out and "V_c =" in out


def test_static_drifts_say_their_frames_and_agree(world, capsys):
    """The two drift vectors of one IMU are the same drift in two frames: equal norms."""
    from fdi.calfile import load_calibration

    rc, out, _ = run(capsys, world, ["calibrate", "static", world["rest"], "--out",
                                     world["out"] / "st2.json"])
    assert rc == 0
    assert "in imu2's axes" in out and "in imu1's axes" in out
    st = load_calibration(world["out"] / "st2.json").extras.static
    own = st.drift_attribution.own["imu2"].drift
    rel = st.imus["imu2"].relative_drift
    assert np.isclose(np.linalg.norm(own), np.linalg.norm(rel), rtol=1e-9)


def test_tests_read_the_shared_data_through_rimu_shared_data():
    """No test hard-codes ``../shared/data``: each path to it honours RIMU_SHARED_DATA."""
    root = Path(__file__).resolve().parent
    bad = []
    for p in root.rglob("*.py"):
        lines = p.read_text(encoding="utf-8").splitlines()
        for j, ln in enumerate(lines):
            if re.search(r'"shared"\s*/\s*"data"', ln) and not any(
                    "RIMU_SHARED_DATA" in x for x in lines[max(0, j - 2):j + 1]):
                bad.append(f"{p.relative_to(root)}:{j + 1}")
    assert not bad, bad
