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
    assert main(["calibrate", "--in-flight", str(d / "fl"), "--out", str(d / "cal.json")]) == 0
    assert main(["simulate", "flight", "--cal", str(d / "cal.json"), "--duration", "2",
                 "--out", str(d / "log.asc")]) == 0
    thr = Thresholds(kind="gyro", n=6, sample_rate_hz=50.0, false_alarms_per_hour=1.0,
                     scales=(1, 8), alpha=(1e-7, 1e-7), variance_factor=(1.0, 1.0),
                     threshold=(float(chi2.isf(1e-7, 3)),) * 2)
    thr.save(d / "thr.json")
    (d / "out").mkdir()
    return {"d": d, "fl": d / "fl", "cal": d / "cal.json", "log": d / "log.asc",
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
    refused(capsys, world, ["calibrate", "--ferraris", fer, "--sections", deep_sec,
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
        ["calibrate", "--static", fl, "--out", fl / "samples.csv"],
        ["calibrate", "--in-flight", fl, "--out", fl / "cal.json"],
        ["calibrate", "--in-flight", fl, "--out", world["out"] / "x.json", "--report", fl],
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
