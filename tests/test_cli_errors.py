"""Every sub-command given a bad file: exit code 2, one stderr line naming the file, no
traceback (real subprocesses, the way a user meets them).

The cases run two at a time in one module fixture (each is a fresh interpreter).
"""

from __future__ import annotations

import json
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from replay.can_write import write_flight_log
from replay.flight import save_flight_dir, simulate_flight
from studies.synthetic import synthetic_calibration

ROOT = Path(__file__).resolve().parents[1]


def _files(d: Path) -> dict[str, Path]:
    cal = synthetic_calibration("cone6", seed=2)
    cal.save(d / "cal.json")
    f = simulate_flight(cal, 0.5, seed=1)
    save_flight_dir(f, d / "flight")
    write_flight_log(f, d / "flight.log")
    (d / "cal_cut.json").write_text((d / "cal.json").read_text()[:500])
    (d / "bad.toml").write_text("[[sensor]\naxis = [1, 0, 0]\n")
    (d / "seq.toml").write_text('schema = "rimu.sequence/1"\nmount = []\n')
    (d / "garbage.blf").write_bytes(b"LOGG" + bytes(range(256)) * 4)
    (d / "thr.json").write_text('{"schema": "rimu.thresholds/1", "kind": [1, 2]}')
    (d / "map.toml").write_text('schema = "rimu.channel_map/1"\nkind = "gyro"\n'
                                '[[sensors]]\nname = 3\n')
    (d / "scen.toml").write_text('schema = "rimu.scenario/1"\n[[faults]]\nsensor = "x"\n')
    (d / "truth_bin.json").write_bytes(b"\xff\xfe\x00garbage")
    bad_flight = d / "flight_bad"
    save_flight_dir(f, bad_flight)
    (bad_flight / "samples.csv").write_bytes(
        (bad_flight / "samples.csv").read_bytes()[:200] + b"\xc3\x28,\xff\n")
    lines = (d / "flight.log").read_text().split("\n")
    lines.insert(10, "garbage here")
    (d / "garbage_line.log").write_text("\n".join(lines))
    sess = d / "sess"
    sess.mkdir()
    (sess / "manifest.json").write_text('{"schema": "rimu.session/1", "sample_rate_hz": "x"}')
    return {"d": d, "cal": d / "cal.json"}


CASES = {
    "parity": (["parity", "{d}/bad.toml"], "bad.toml"),
    "calibrate_missing": (["calibrate", "turntable",
                           "{d}/nowhere", "--out", "{d}/o.json"], "nowhere"),
    "calibrate_manifest": (["calibrate", "turntable",
                            "{d}/sess", "--out", "{d}/o.json"], "manifest.json"),
    "simulate_calibration_config": (["simulate", "calibration", "--config", "{d}/bad.toml",
                                     "--out", "{d}/s1"], "bad.toml"),
    "simulate_calibration_sequence": (["simulate", "calibration", "--config", "cone6",
                                       "--sequence", "{d}/seq.toml", "--out", "{d}/s2"],
                                      "seq.toml"),
    "simulate_flight_cal": (["simulate", "flight", "--cal", "{d}/cal_cut.json", "--duration",
                             "1", "--out", "{d}/f1"], "cal_cut.json"),
    "simulate_flight_truth": (["simulate", "flight", "--cal", "{cal}", "--truth",
                               "{d}/truth_bin.json", "--duration", "1", "--out", "{d}/f2"],
                              "truth_bin.json"),
    "monitor_file_thresholds": (["monitor-file", "{d}/flight", "--cal", "{cal}",
                                 "--thresholds", "{d}/thr.json"], "thr.json"),
    "monitor_file_samples": (["monitor-file", "{d}/flight_bad", "--cal", "{cal}"],
                             "samples.csv"),
    "replay_strict_garbage": (["replay", "{d}/garbage.blf", "--cal", "{cal}", "--strict",
                               "--no-progress"], "garbage.blf"),
    "replay_map": (["replay", "{d}/flight.log", "--cal", "{cal}", "--map", "{d}/map.toml",
                    "--no-progress"], "map.toml"),
    "replay_inject": (["replay", "{d}/flight.log", "--cal", "{cal}", "--inject",
                       "{d}/scen.toml", "--no-progress"], "scen.toml"),
    "replay_strict_garbage_line": (["replay", "{d}/garbage_line.log", "--cal", "{cal}",
                                    "--strict", "--no-progress"], "garbage_line.log:11"),
    "monitor_cal": (["monitor", "--interface", "virtual", "--channel", "rimu-test-errors",
                     "--cal", "{d}/cal_cut.json", "--duration", "0.1"], "cal_cut.json"),
}


LENIENT = {
    "replay_garbage_line": ["replay", "{d}/garbage_line.log", "--cal", "{cal}", "--no-progress",
                            "--report", "{d}/report.json"],
}
"""Damage the user did not ask to be strict about: exit 0, the report says where and why."""


def _run(argv: list[str]) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "rimu", *argv], capture_output=True,
                          text=True, timeout=120, cwd=ROOT)


SLOW = {"calibrate_missing", "simulate_calibration_config", "simulate_flight_truth",
        "monitor_file_samples", "replay_map"}
"""Cases run only with ``--slow`` (each is an interpreter start, about a second)."""


def _wanted(config) -> set[str]:
    return set(CASES) if config.getoption("--slow") else set(CASES) - SLOW


@pytest.fixture(scope="module")
def results(tmp_path_factory, pytestconfig) -> dict[str, tuple[subprocess.CompletedProcess,
                                                                str]]:
    f = _files(tmp_path_factory.mktemp("cli"))
    jobs = {}
    wanted = _wanted(pytestconfig)
    with ThreadPoolExecutor(2) as pool:
        for name, (argv, fname) in CASES.items():
            if name not in wanted:
                continue
            args = [a.format(d=f["d"], cal=f["cal"]) for a in argv]
            jobs[name] = (pool.submit(_run, args), fname)
        for name, argv in LENIENT.items():
            args = [a.format(d=f["d"], cal=f["cal"]) for a in argv]
            jobs[name] = (pool.submit(_run, args), str(f["d"]))
        return {k: (fut.result(), fname) for k, (fut, fname) in jobs.items()}


@pytest.mark.parametrize("case", [pytest.param(c, marks=pytest.mark.slow) if c in SLOW else c
                                  for c in sorted(CASES)])
def test_bad_file_gives_one_line_and_exit_2(results, case):
    proc, fname = results[case]
    err = proc.stderr
    assert "Traceback" not in err, err
    assert proc.returncode == 2, (proc.returncode, err, proc.stdout[-500:])
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    assert lines[0].startswith("rimu: error: ") and fname in lines[0], lines[0]


def test_damaged_log_without_strict_exits_0_and_reports_where(results):
    proc, d = results["replay_garbage_line"]
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr
    fr = json.loads((Path(d) / "report.json").read_text())["frames"]
    assert fr["read"] == fr["used"] + 1 and fr["rejected"] == {"garbage_line": 1}, fr
    assert fr["errors"][0]["where"] == "line 11" and fr["errors"][0]["text"] == "garbage here"
