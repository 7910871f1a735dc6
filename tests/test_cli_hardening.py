"""Issue 10, field hardening: every defect of the report as a regression test.

A refused command exits 2 with exactly one line on stderr, no traceback, and leaves no file
behind (the test compares the folder before and after). The commands run in-process
(``rimu.cli.main``) on small files made once per module.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
from pathlib import Path

import pytest

from fdi.calfile import check_compatible, check_plausible, load_calibration
from fdi.errors import CalibrationError, ConfigError
from replay.can_write import write_flight_log
from replay.faults import parse_fault
from replay.flight import save_flight_dir, simulate_flight
from rimu.argtypes import nonnegative_int, positive_float, positive_int
from rimu.cli import main
from rimu.outputs import atomic_dir, atomic_file, atomic_write_text, output_dir, output_file
from studies.synthetic import synthetic_calibration


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("hardening")
    cal6 = synthetic_calibration("cone6", seed=2, raw_unit="mV")
    cal6.save(d / "cal6.json")
    cal4 = synthetic_calibration("tetrad", seed=3, raw_unit="mV")
    cal4.save(d / "cal4.json")
    f6 = simulate_flight(cal6, 1.0, seed=1)
    write_flight_log(f6, d / "f6.blf")
    save_flight_dir(f6, d / "flight6")
    f4 = simulate_flight(cal4, 1.0, seed=1)
    write_flight_log(f4, d / "f4.log")
    (d / "existing.txt").write_text("keep me\n")
    (d / "adir").mkdir()
    assert main(["simulate", "calibration", "--preset", "cone-paper", "--turns", "1",
                 "--out", str(d / "sess")]) == 0
    return {"d": d, "cal6": d / "cal6.json", "cal4": d / "cal4.json", "f6": d / "f6.blf",
            "f4": d / "f4.log", "flight6": d / "flight6", "sess": d / "sess"}


def _tree(d: Path) -> dict[str, float]:
    return {str(p.relative_to(d)): p.stat().st_mtime_ns for p in d.rglob("*")}


def refused(capsys, d: Path, argv: list[str], needle: str) -> str:
    """Run argv; check exit 2, one stderr line containing needle, nothing written in d."""
    capsys.readouterr()
    before = _tree(d)
    rc = main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert rc == 2, (argv, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "Traceback" not in err and needle in err, err
    assert _tree(d) == before, "a file was left behind or changed"
    return err


def _usage_error(capsys, argv: list[str], needle: str) -> None:
    """An option refused by its type while parsing: exit 2, one line."""
    capsys.readouterr()
    rc = main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert rc == 2
    assert len(err.strip().splitlines()) == 1 and needle in err, err
    assert err.startswith("rimu: error: argument "), err


# ----------------------------------------------------------------- output paths ---------
def test_calibrate_out_is_a_directory(files, capsys):
    refused(capsys, files["d"], ["calibrate", "turntable",
                                 files["sess"], "--out", files["d"] / "adir"],
            "is a directory")


def test_calibrate_compare_missing_refused_before_writing(files, capsys):
    d = files["d"]
    refused(capsys, d, ["calibrate", "turntable", files["sess"], "--out", d / "cal_new.json",
                        "--compare", d / "nope.json"], "no such file")


def test_calibrate_compare_bad_truth_refused_before_writing(files, capsys):
    d = files["d"]
    refused(capsys, d, ["calibrate", "turntable", files["sess"], "--out", d / "cal_new.json",
                        "--compare", files["cal6"]], "cal6.json")


@pytest.mark.parametrize("cmd", [
    ["simulate", "calibration", "--preset", "cone-paper"],
    ["simulate", "flight", "--cal", "{cal6}", "--duration", "1"],
    ["demo", "--duration", "40", "--no-rrd"],
])
def test_directory_output_that_is_a_file(files, capsys, cmd):
    argv = [c.format(**files) for c in cmd] + ["--out", files["d"] / "existing.txt"]
    refused(capsys, files["d"], argv, "is a file, expected a directory")


def test_simulate_flight_log_output_missing_directory(files, capsys):
    refused(capsys, files["d"], ["simulate", "flight", "--cal", files["cal6"], "--duration",
                                 "1", "--out", files["d"] / "nodir" / "x.blf"],
            "does not exist")


def test_monitor_file_report_in_missing_directory(files, capsys):
    refused(capsys, files["d"], ["monitor-file", files["flight6"], "--cal", files["cal6"],
                                 "--report", files["d"] / "nodir" / "r.json"],
            "directory")


@pytest.mark.parametrize("opt", ["--rrd", "--report"])
def test_replay_outputs_in_missing_directory(files, capsys, opt):
    refused(capsys, files["d"], ["replay", files["f6"], "--cal", files["cal6"], "--no-progress",
                                 opt, files["d"] / "nodir" / "x.out"], "does not exist")


def test_replay_writes_report_and_recording_atomically(files, tmp_path, capsys):
    rep, rrd = tmp_path / "r.json", tmp_path / "x.rrd"
    assert main(["replay", str(files["f6"]), "--cal", str(files["cal6"]), "--no-progress",
                 "--report", str(rep), "--rrd", str(rrd)]) == 0
    assert json.loads(rep.read_text())["samples"] == 100
    assert rrd.stat().st_size > 0
    # the report's picture beside it (issue 30: --report writes a PNG), and no temp file
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.json", "r.png", "x.rrd"]


def test_failure_mid_replay_leaves_no_recording_or_report(files, tmp_path, capsys):
    """--strict on a log with a garbage line fails while reading, after the recording was
    opened: neither the recording, nor the report, nor a temporary file stays."""
    lines = files["f4"].read_text().splitlines()
    lines.insert(40, "this is not a frame")
    log = tmp_path / "bad.log"
    log.write_text("\n".join(lines) + "\n")
    out = tmp_path / "out"
    out.mkdir()
    refused(capsys, out, ["replay", log, "--cal", files["cal4"], "--strict", "--no-progress",
                          "--rrd", out / "x.rrd", "--report", out / "r.json"], "bad.log:41")
    assert list(out.iterdir()) == []


def test_spawn_without_display(files, tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr("sys.platform", "linux")
    refused(capsys, files["d"], ["replay", files["f6"], "--cal", files["cal6"], "--spawn"],
            "no display")
    rrd = tmp_path / "x.rrd"
    assert main(["replay", str(files["f6"]), "--cal", str(files["cal6"]), "--spawn",
                 "--rrd", str(rrd), "--no-progress"]) == 0
    err = capsys.readouterr().err
    assert "no display" in err and rrd.is_file()


def test_demo_negative_duration_refused_before_writing(files, capsys):
    out = files["d"] / "demo_out"
    _usage_error(capsys, ["demo", "--duration", "-5", "--out", out], "--duration")
    assert not out.exists()


# ----------------------------------------------------------------- limits ---------------
@pytest.mark.parametrize("opt,val", [("--duration", "nan"), ("--duration", "-5"),
                                     ("--duration", "inf"), ("--max-frames", "-1"),
                                     ("--max-frames", "0"), ("--idle-timeout", "-1"),
                                     ("--window", "0"), ("--bitrate", "-1")])
def test_monitor_limits(files, capsys, opt, val):
    _usage_error(capsys, ["monitor", "--interface", "virtual", "--channel", "x", "--cal",
                          files["cal6"], opt, val], opt)


@pytest.mark.parametrize("val", ["nan", "-300", "0", "inf", "1e400"])
def test_simulate_flight_max_rate(files, capsys, val):
    _usage_error(capsys, ["simulate", "flight", "--cal", files["cal6"], "--duration", "1",
                          "--out", files["d"] / "never", "--max-rate", val], "--max-rate")


@pytest.mark.parametrize("opt", ["--turns", "--table-rate-dps"])
def test_zero_is_not_default(files, capsys, opt):
    _usage_error(capsys, ["simulate", "calibration", "--preset", "cone-paper", "--out",
                          files["d"] / "never", opt, "0"], opt)


def test_simulate_flight_rate_zero(files, capsys):
    _usage_error(capsys, ["simulate", "flight", "--cal", files["cal6"], "--duration", "1",
                          "--out", files["d"] / "never", "--rate", "0"], "--rate")


def test_fault_onset_after_flight_end_refused(files, capsys):
    refused(capsys, files["d"], ["simulate", "flight", "--cal", files["cal6"], "--duration",
                                 "2", "--fault", "step:1:8sigma:5", "--out",
                                 files["d"] / "late"], "not within the flight")


def test_argtypes_messages():
    with pytest.raises(argparse.ArgumentTypeError, match="finite"):
        positive_float()("nan")
    with pytest.raises(argparse.ArgumentTypeError, match=r"positive number in \(0.0, 10.0\]"):
        positive_float(10.0)("11")
    with pytest.raises(argparse.ArgumentTypeError, match="whole number"):
        positive_int()("1.5")
    assert nonnegative_int()("0") == 0 and positive_float()("1e-300") == 1e-300


# ----------------------------------------------------------------- mismatches -----------
def test_four_sensor_calibration_on_six_sensor_log(files, tmp_path, capsys):
    """Was: exit 0, statistic 1.2e6, 105 deg/s RMS error. A recorded log (no sidecar) is
    refused from its messages; a simulated one from its truth sidecar too."""
    log = tmp_path / "recorded.blf"
    shutil.copy(files["f6"], log)
    refused(capsys, tmp_path, ["replay", log, "--cal", files["cal4"], "--no-progress"],
            "RIMU_GYRO_05, RIMU_GYRO_06")
    refused(capsys, files["d"], ["replay", files["f6"], "--cal", files["cal4"],
                                 "--no-progress"], "6 gyro sensors, the calibration")


def test_six_sensor_calibration_on_four_sensor_log(files, capsys):
    refused(capsys, files["d"], ["replay", files["f4"], "--cal", files["cal6"],
                                 "--no-progress"], "4 gyro sensors, the calibration")


def test_flight_folder_of_other_sensor_set(files, capsys):
    refused(capsys, files["d"], ["monitor-file", files["flight6"], "--cal", files["cal4"]],
            "6 gyro sensors")


def test_flight_manifest_unit_contradicts_calibration(files, tmp_path, capsys):
    fl = tmp_path / "flight"
    shutil.copytree(files["flight6"], fl)
    man = json.loads((fl / "manifest.json").read_text())
    man["raw_unit"] = "LSB"
    (fl / "manifest.json").write_text(json.dumps(man))
    refused(capsys, tmp_path, ["monitor-file", fl, "--cal", files["cal6"]],
            "expects raw outputs in 'mV'")


def test_flight_manifest_unknown_key_refused(files, tmp_path, capsys):
    fl = tmp_path / "flight"
    shutil.copytree(files["flight6"], fl)
    man = json.loads((fl / "manifest.json").read_text())
    man["raw_unti"] = "mV"
    (fl / "manifest.json").write_text(json.dumps(man))
    refused(capsys, tmp_path, ["monitor-file", fl, "--cal", files["cal6"]],
            "did you mean 'raw_unit'?")


def test_channel_map_unit_contradicts_calibration(files, tmp_path, capsys):
    lines = ['schema = "rimu.channel_map/1"', 'kind = "gyro"']
    for i in range(6):
        lines += ["[[sensors]]", f'name = "g{i + 1}"', f'message = "RIMU_GYRO_{i + 1:02d}"',
                  'signal = "RAW"', 'unit = "deg/s"']
    m = tmp_path / "map.toml"
    m.write_text("\n".join(lines) + "\n")
    refused(capsys, tmp_path, ["replay", files["f6"], "--cal", files["cal6"], "--map", m,
                               "--no-progress"], "is in 'deg/s'")


def test_check_compatible_accepts_generic_units(files):
    cal = load_calibration(files["cal6"])
    check_compatible(cal, 6, "raw", "x")
    check_compatible(cal, 6, ["mV"] * 6, "x")
    with pytest.raises(ConfigError, match="sensor 3"):
        check_compatible(cal, 6, ["mV", "mV", "V", "mV", "mV", "mV"], "x")


def _rad_session(src: Path, dst: Path) -> None:
    import csv

    shutil.copytree(src, dst)
    rows = list(csv.reader((dst / "samples.csv").open()))
    i, o = rows[0].index("inner_rate_dps"), rows[0].index("outer_rate_dps")
    for r in rows[1:]:
        r[i] = repr(math.radians(float(r[i])))
        r[o] = repr(math.radians(float(r[o])))
    with (dst / "samples.csv").open("w", newline="") as f:
        csv.writer(f).writerows(rows)


def test_table_rates_in_rad_s_refused(files, tmp_path, capsys):
    """The session's table-rate columns in rad/s: the Earth rate the rate test recovers is
    57x too small, far beyond chi2.isf(1e-9, 1); refused, no calibration file written."""
    _rad_session(files["sess"], tmp_path / "sess")
    refused(capsys, tmp_path, ["calibrate", "turntable",
                               tmp_path / "sess", "--out", tmp_path / "c.json"],
            "horizontal Earth rate")


def test_plausible_session_passes(files, tmp_path, capsys):
    out = tmp_path / "c.json"
    assert main(["calibrate", "turntable", str(files["sess"]), "--out", str(out)]) == 0
    check_plausible(load_calibration(out), "x")
    cal = load_calibration(out)
    er = cal.extra["earth_rate_fit"]
    for k in ("horizontal_dph", "horizontal_dph_sd", "scatter_sd_dph"):
        er[k] /= math.degrees(1.0)            # what rad/s read as deg/s does to the fit
    with pytest.raises(CalibrationError, match="z = "):
        check_plausible(cal, "x")


# ----------------------------------------------------------------- stdout / cosmetics ---
def test_parity_has_no_negative_zero(capsys):
    for cfg in ("cone6", "tetrad"):
        assert main(["parity", cfg]) == 0
        out = capsys.readouterr().out
        assert "-0. " not in out and "-0.]" not in out, out
        assert main(["parity", cfg, "--json"]) == 0
        d = json.loads(capsys.readouterr().out)
        assert not any(math.copysign(1.0, x) < 0 and x == 0 for r in d["V"] for x in r)


def test_warnings_go_to_stderr_json_stays_clean(files, tmp_path, capsys):
    log = tmp_path / "cut.blf"
    log.write_bytes(files["f6"].read_bytes()[:-200])
    rep = tmp_path / "r.json"
    assert main(["replay", str(log), "--cal", str(files["cal6"]), "--no-progress",
                 "--report", str(rep)]) == 0
    cap = capsys.readouterr()
    assert "rimu: warning:" in cap.err and "rimu: warning" not in cap.out


# ----------------------------------------------------------------- outputs module -------
def test_atomic_file_leaves_nothing_on_failure(tmp_path):
    p = tmp_path / "x.json"
    p.write_text("old")
    with pytest.raises(RuntimeError), atomic_file(p) as tmp:
        tmp.write_text("half")
        raise RuntimeError("disk full")
    assert p.read_text() == "old" and sorted(os.listdir(tmp_path)) == ["x.json"]
    atomic_write_text(p, "new")
    assert p.read_text() == "new" and sorted(os.listdir(tmp_path)) == ["x.json"]


def test_atomic_dir_removes_what_it_created_on_failure(tmp_path):
    out = tmp_path / "a" / "b"
    with pytest.raises(RuntimeError), atomic_dir(out) as tmp:
        (tmp / "f.txt").write_text("x")
        raise RuntimeError
    assert list(tmp_path.iterdir()) == []
    with atomic_dir(out) as tmp:
        (tmp / "f.txt").write_text("x")
    assert [p.name for p in out.iterdir()] == ["f.txt"]
    assert sorted(p.name for p in out.parent.iterdir()) == ["b"]


def test_output_checks(tmp_path):
    with pytest.raises(ConfigError, match="is a directory"):
        output_file(tmp_path, "--out")
    with pytest.raises(ConfigError, match="does not exist"):
        output_file(tmp_path / "no" / "x.json", "--out")
    (tmp_path / "f").write_text("")
    with pytest.raises(ConfigError, match="is a file"):
        output_dir(tmp_path / "f", "--out")
    with pytest.raises(ConfigError, match="is a file, not a directory"):
        output_dir(tmp_path / "f" / "sub", "--out")
    assert output_dir(tmp_path / "new" / "deeper", "--out") == tmp_path / "new" / "deeper"


def test_fault_spec_helper_used_above_is_valid(files):
    # guards the onset test: the spec itself is fine, only its onset is out of the flight
    f = parse_fault("step:1:8sigma:5", load_calibration(files["cal6"]))
    assert f.onset == 5.0
