"""Fuzz every command's numeric options with hypothesis: NaN, inf, negative, zero, huge, text.

- Parsing: every numeric option of every registered command (found by walking the parser,
  so commands added later are covered) either parses or is refused with exit 2 and one
  stderr line — never another exception.
- Running: the commands that run quickly on small inputs (replay, monitor-file, monitor on a
  virtual bus, simulate flight, simulate calibration) are run with one fuzzed option on
  top of valid ones: exit 0 or 2, one stderr line on 2, no traceback, no hang.

- Damaged inputs (issue 19): every command that reads a file is run on a damaged copy
  (truncated, bytes overwritten, a line duplicated or inserted, a number replaced by NaN,
  1e308, an empty field...): exit 0 with its output written, or exit 2 with one stderr line
  and nothing written; every stderr line is a ``rimu:`` line; each case under a time limit
  (a hang fails the test instead of stalling the run).

The default run tries a few examples per option (about 10 s in all); ``--slow`` 20 more per
option. Valid values that only make the work long (a 2 h simulated flight, a session with
a table rate of 1e-6 °/s) are not run: they are work, not faults (the limits that bound
them are tested by the parse test and tests/test_cli_hardening.py).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import shutil
import signal
import time
import uuid
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from replay.can_write import write_flight_log
from replay.flight import save_flight_dir, simulate_flight
from rimu import argtypes
from rimu.cli import build_parser, main
from studies.ferraris_sim import imucal_like_truth, simulate_ferraris
from studies.synthetic import synthetic_calibration

SPECIAL = ["nan", "NaN", "inf", "-inf", "+inf", "-1", "0", "-0", "0.0", "-0.0", "1e308",
           "1e400", "-1e400", "-5", "1", "3", "0.5", "1e-300", "5e-324", "abc", "", "1,5",
           "0x10", "99999999999999999999999", "-99999999999999999999999", "2.5e9", "1e12"]
VALUES = st.one_of(st.sampled_from(SPECIAL),
                   st.floats(allow_nan=True, allow_infinity=True).map(repr),
                   st.integers(min_value=-(2**70), max_value=2**70).map(str))
SLOW = settings(max_examples=20, deadline=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture,
                                       HealthCheck.too_slow])
FAST = settings(max_examples=6, deadline=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture,
                                       HealthCheck.too_slow])


def _numeric(action: argparse.Action) -> bool:
    t = action.type
    return t in (int, float) or getattr(t, "__module__", "") == argtypes.__name__


def numeric_options() -> list[tuple[tuple[str, ...], str]]:
    """(sub-command path, option) of every numeric option of every command."""
    out = []

    def walk(p: argparse.ArgumentParser, path: tuple[str, ...]) -> None:
        for a in p._actions:
            if isinstance(a, argparse._SubParsersAction):
                for name, sub in a.choices.items():
                    walk(sub, (*path, name))
            elif a.option_strings and _numeric(a):
                out.append((path, a.option_strings[-1]))

    walk(build_parser(), ())
    return sorted(set(out))


OPTIONS = numeric_options()


def test_the_walk_finds_the_known_options():
    got = {(" ".join(p), o) for p, o in OPTIONS}
    for want in [("demo", "--duration"), ("monitor", "--max-frames"),
                 ("simulate flight", "--max-rate"), ("simulate calibration", "--turns"),
                 ("replay", "--false-alarms-per-hour"), ("monitor-file", "--max-events")]:
        assert want in got, sorted(got)


def _parse(path: tuple[str, ...], opt: str, value: str, capsys) -> None:
    capsys.readouterr()
    try:
        build_parser().parse_args([*path, opt, value])
    except SystemExit as exc:
        err = capsys.readouterr().err
        assert exc.code == 2, err
        assert len(err.strip().splitlines()) == 1, err
        assert "Traceback" not in err


@pytest.mark.parametrize("path,opt", OPTIONS, ids=[" ".join(p) + " " + o for p, o in OPTIONS])
@settings(max_examples=10, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(value=VALUES)
def test_parsing_a_numeric_option_never_raises(path, opt, value, capsys):
    _parse(path, opt, value, capsys)


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> dict[str, str]:
    d = tmp_path_factory.mktemp("fuzz")
    cal = synthetic_calibration("cone6", seed=5)
    cal.save(d / "cal.json")
    f = simulate_flight(cal, 0.3, seed=2)
    write_flight_log(f, d / "f.log")
    save_flight_dir(f, d / "flight")
    rng = np.random.default_rng(0)
    (d / "x.csv").write_text("time_s,imu1_gyr_x_rps,imu1_gyr_y_rps,imu1_gyr_z_rps\n" + "".join(
        f"{i / 100!r},{rng.normal():.6f},{rng.normal():.6f},{rng.normal():.6f}\n"
        for i in range(300)))
    s = simulate_ferraris(imucal_like_truth(3), seed=3)
    part = np.full(s.gyro.shape[0], "", dtype=object)
    for k, idx in s.sections.items():
        part[idx] = k
    (d / "fer.csv").write_text("part,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z\n" + "".join(
        f"{part[i]}," + ",".join(f"{v:.9g}" for v in (*s.gyro[i], *s.accel[i])) + "\n"
        for i in range(s.gyro.shape[0])))
    assert main(["simulate", "calibration", "--config", "tetrad", "--sequence",
                 "tetrad-paper", "--turns", "0.05", "--out", str(d / "sess")]) == 0
    assert main(["calibrate", "turntable", str(d / "sess"), "--out", str(d / "sess_cal.json")]) == 0
    assert main(["simulate", "flight", "--imus", "2", "--duration", "12",
                 "--out", str(d / "imus")]) == 0
    assert main(["calibrate", "in-flight", str(d / "imus"), "--out",
                 str(d / "imus_cal.json")]) == 0
    return {"d": str(d), "cal": str(d / "cal.json"), "log": str(d / "f.log"),
            "flight": str(d / "flight"), "csv": str(d / "x.csv"), "fer": str(d / "fer.csv"),
            "sess": str(d / "sess"), "sess_cal": str(d / "sess_cal.json"),
            "imus": str(d / "imus"), "imus_cal": str(d / "imus_cal.json")}


def _base(cmd: str, io: dict[str, str]) -> list[str]:
    d = io["d"]
    return {
        "replay": ["replay", io["log"], "--cal", io["cal"], "--no-progress"],
        "monitor-file": ["monitor-file", io["flight"], "--cal", io["cal"]],
        "monitor": ["monitor", "--interface", "virtual", "--channel",
                    f"fuzz-{uuid.uuid4().hex}", "--cal", io["cal"], "--duration", "0.1",
                    "--idle-timeout", "0.05", "--max-frames", "5"],
        "simulate flight": ["simulate", "flight", "--cal", io["cal"], "--duration", "0.3",
                            "--out", f"{d}/out_{uuid.uuid4().hex}"],
        "simulate calibration": ["simulate", "calibration", "--config", "tetrad",
                                 "--sequence", "tetrad-paper", "--turns", "0.05", "--out",
                                 f"{d}/sess_{uuid.uuid4().hex}"],
        "calibrate ferraris": ["calibrate", "ferraris", io["fer"], "--sample-rate-hz", "100",
                               "--out", f"{d}/cal_{uuid.uuid4().hex}.json"],
        "diagnose": ["diagnose", io["sess"], "--cal", io["sess_cal"]],
        "ingest": ["ingest", io["csv"], "--out", f"{d}/ing_{uuid.uuid4().hex}"],
        "repeat": ["repeat", io["sess"], io["sess"]],        # refused: the same session twice
    }[cmd]


RUN_OPTIONS = [(c, o) for p, o in OPTIONS for c in [" ".join(p)]
               if c in ("replay", "monitor-file", "monitor", "simulate flight",
                        "simulate calibration", "calibrate ferraris", "diagnose", "ingest",
                        "repeat")]
# valid but slow: a long simulated flight or session is work, not a fault; keep them short
_SLOW_VALID = {("simulate flight", "--duration"): 2.0, ("monitor", "--duration"): 1.0,
               ("monitor", "--idle-timeout"): 1.0, ("simulate flight", "--rate"): 1000.0,
               ("simulate calibration", "--turns"): 0.1,
               ("simulate calibration", "--table-rate-dps"): None}


def _too_slow(cmd: str, opt: str, value: str) -> bool:
    lim = _SLOW_VALID.get((cmd, opt), "none")
    if lim == "none":
        return False
    try:
        x = float(value)
    except ValueError:
        return False
    if lim is None:                          # any valid table rate: the session is long
        return x > 0 and x == x and x != float("inf")
    return x == x and abs(x) > lim and abs(x) != float("inf")


@contextlib.contextmanager
def time_limit(seconds: float, what: object):
    """Fail (instead of stalling the run) when the block takes longer than ``seconds``."""
    def alarm(signum, frame):
        raise TimeoutError(f"no answer within {seconds:g} s: {what}")

    old = signal.signal(signal.SIGALRM, alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


LIMIT_S = 60.0
"""Most time one fuzz case may take (a hang fails the test)."""


def _run(cmd: str, opt: str, value: str, io: dict[str, str], capsys) -> None:
    if _too_slow(cmd, opt, value):
        return
    argv = [*_base(cmd, io), opt, value]
    capsys.readouterr()
    t0 = time.monotonic()
    with time_limit(LIMIT_S, argv):
        rc = main(argv)
    err = capsys.readouterr().err
    assert time.monotonic() - t0 < LIMIT_S, ("too slow", argv)
    assert rc in (0, 2), (argv, rc, err)
    assert "Traceback" not in err, err
    if rc == 2:
        assert len([x for x in err.splitlines() if "error" in x]) == 1, err


@pytest.mark.parametrize("cmd,opt", RUN_OPTIONS, ids=[f"{c} {o}" for c, o in RUN_OPTIONS])
@FAST
@given(value=VALUES)
def test_running_with_a_fuzzed_option_exits_0_or_2(cmd, opt, value, inputs, capsys):
    _run(cmd, opt, value, inputs, capsys)


@pytest.mark.slow
@pytest.mark.parametrize("cmd,opt", RUN_OPTIONS, ids=[f"{c} {o}" for c, o in RUN_OPTIONS])
@SLOW
@given(value=VALUES)
def test_running_with_a_fuzzed_option_exits_0_or_2_many(cmd, opt, value, inputs, capsys):
    _run(cmd, opt, value, inputs, capsys)


# ------------------------------------------------------------------ damaged inputs ------
DAMAGES = st.one_of(
    st.tuples(st.just("truncate"), st.floats(0.0, 1.0)),
    st.tuples(st.just("overwrite"), st.floats(0.0, 1.0), st.binary(min_size=1, max_size=40)),
    st.tuples(st.just("duplicate_line"), st.floats(0.0, 1.0)),
    st.tuples(st.just("insert_line"), st.floats(0.0, 1.0),
              st.sampled_from(["", "garbage", ",,,,", "1,2", "\x00\x01", "nan,nan,nan,nan",
                               '{"schema": 1}', "t,a,b"])),
    st.tuples(st.just("replace_number"), st.floats(0.0, 1.0),
              st.sampled_from(["nan", "inf", "-inf", "1e308", "-1e308", "", "x", "0",
                               "1e-320", "99999999999999999999"])),
)


def damage(path: Path, how: tuple) -> None:
    """Apply one damage to the file ``path`` in place."""
    data = path.read_bytes()
    kind, where = how[0], how[1]
    at = int(where * len(data))
    if kind == "truncate":
        data = data[:at]
    elif kind == "overwrite":
        data = data[:at] + how[2] + data[at + len(how[2]):]
    else:
        lines = data.split(b"\n")
        k = min(int(where * len(lines)), len(lines) - 1)
        if kind == "duplicate_line":
            lines.insert(k, lines[k])
        elif kind == "insert_line":
            lines.insert(k, how[2].encode())
        else:                           # the first number at or after line k
            import re

            for j in range(k, len(lines)):
                m = re.search(rb"-?\d+\.?\d*(e-?\d+)?", lines[j])
                if m:
                    lines[j] = lines[j][:m.start()] + how[2].encode() + lines[j][m.end():]
                    break
        data = b"\n".join(lines)
    path.write_bytes(data)


# (name, input to damage (key of the inputs fixture, file inside a folder), argv with {in}
#  for the damaged input and {out} for a fresh output, whether the output must exist on 0)
DAMAGE_CASES = [
    ("ingest csv", "csv", "", ["ingest", "{in}", "--out", "{out}"], True),
    ("calibrate ferraris", "fer", "", ["calibrate", "ferraris", "{in}", "--sample-rate-hz",
                                       "100", "--out", "{out}"], True),
    ("calibrate session samples", "sess", "samples.csv", ["calibrate", "turntable", "{in}",
                                                          "--out", "{out}"], True),
    ("calibrate session manifest", "sess", "manifest.json", ["calibrate", "turntable",
                                                             "{in}", "--out", "{out}"], True),
    ("monitor-file samples", "flight", "samples.csv", ["monitor-file", "{in}", "--cal", "{cal}",
                                                       "--report", "{out}"], True),
    ("monitor-file manifest", "flight", "manifest.json", ["monitor-file", "{in}", "--cal",
                                                          "{cal}", "--report", "{out}"], True),
    ("monitor-file calibration", "cal", "", ["monitor-file", "{flight}", "--cal", "{in}",
                                             "--report", "{out}"], True),
    ("replay log", "log", "", ["replay", "{in}", "--cal", "{cal}", "--no-progress",
                               "--report", "{out}"], True),
    ("parity calibration", "cal", "", ["parity", "cone6", "--misalignment", "{in}"], False),
    ("diagnose session", "sess", "samples.csv", ["diagnose", "{in}", "--cal", "{sess_cal}",
                                                 "--out", "{out}"], True),
    ("diagnose flight", "imus", "samples.csv", ["diagnose", "{in}", "--cal", "{imus_cal}",
                                                "--report", "{out}"], True),
    ("in-flight calibration", "imus", "samples.csv", ["calibrate", "in-flight", "{in}",
                                                      "--out", "{out}"], True),
    ("tune calibration", "cal", "", ["tune", "--cal", "{in}", "--false-alarms-per-hour", "1",
                                     "--simulate-hours", "0", "--out", "{out}"], True),
]
_FAST_CASES = [c for c in DAMAGE_CASES if c[0] not in ("tune calibration",)]


def _damaged_run(case: tuple, how: tuple, io: dict[str, str], capsys) -> None:
    name, key, inner, argv, writes = case
    work = Path(io["d"]) / f"dmg_{uuid.uuid4().hex}"
    work.mkdir()
    src = Path(io[key])
    copy = work / src.name
    (shutil.copytree if src.is_dir() else shutil.copy)(src, copy)
    damage(copy / inner if inner else copy, how)
    out = work / ("out.json" if "--report" not in argv and name != "ingest csv" else "out")
    if "--report" in argv and name.startswith(("monitor-file", "replay")):
        out = work / "report.json"
    args = [a.format(**{**io, "in": str(copy), "out": str(out)}) for a in argv]
    before = sorted(p.name for p in work.iterdir())
    capsys.readouterr()
    with time_limit(LIMIT_S, (name, how)):
        rc = main(args)
    err = capsys.readouterr().err
    assert rc in (0, 2), (name, how, rc, err)
    assert "Traceback" not in err, err
    assert all(x.startswith("rimu: ") for x in err.splitlines()), (name, how, err)
    if rc == 2:
        assert len([x for x in err.splitlines() if x.startswith("rimu: error:")]) == 1, err
        assert sorted(p.name for p in work.iterdir()) == before, (name, how, "left a file")
    elif writes:
        assert out.exists(), (name, how, "exit 0 without its output")
        if out.suffix == ".json":
            json.loads(out.read_text(encoding="utf-8"))


@pytest.mark.parametrize("case", _FAST_CASES, ids=[c[0] for c in _FAST_CASES])
@settings(max_examples=4, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(how=DAMAGES)
def test_damaged_input_keeps_the_promise(case, how, inputs, capsys):
    _damaged_run(case, how, inputs, capsys)


@pytest.mark.slow
@pytest.mark.parametrize("case", DAMAGE_CASES, ids=[c[0] for c in DAMAGE_CASES])
@SLOW
@given(how=DAMAGES)
def test_damaged_input_keeps_the_promise_many(case, how, inputs, capsys):
    _damaged_run(case, how, inputs, capsys)
