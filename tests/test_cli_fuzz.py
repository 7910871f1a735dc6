"""Fuzz every command's numeric options with hypothesis: NaN, inf, negative, zero, huge, text.

- Parsing: every numeric option of every registered command (found by walking the parser,
  so commands added later are covered) either parses or is refused with exit 2 and one
  stderr line — never another exception.
- Running: the commands that run quickly on small inputs (replay, monitor-file, monitor on a
  virtual bus, simulate flight, simulate calibration) are run with one fuzzed option on
  top of valid ones: exit 0 or 2, one stderr line on 2, no traceback, no hang.

The default run tries a few examples per option (about 10 s in all); ``--slow`` 20 more per
option. Valid values that only make the work long (a 2 h simulated flight, a session with
a table rate of 1e-6 °/s) are not run: they are work, not faults (the limits that bound
them are tested by the parse test and tests/test_cli_hardening.py).
"""

from __future__ import annotations

import argparse
import time
import uuid

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from replay.flight import save_flight_dir, simulate_flight
from replay.logio import write_flight_log
from rimu import argtypes
from rimu.cli import build_parser, main
from thresholds.synthetic import synthetic_calibration

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
    return {"d": str(d), "cal": str(d / "cal.json"), "log": str(d / "f.log"),
            "flight": str(d / "flight")}


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
    }[cmd]


RUN_OPTIONS = [(c, o) for p, o in OPTIONS for c in [" ".join(p)]
               if c in ("replay", "monitor-file", "monitor", "simulate flight",
                        "simulate calibration")]
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


def _run(cmd: str, opt: str, value: str, io: dict[str, str], capsys) -> None:
    if _too_slow(cmd, opt, value):
        return
    argv = [*_base(cmd, io), opt, value]
    capsys.readouterr()
    t0 = time.monotonic()
    rc = main(argv)
    err = capsys.readouterr().err
    assert time.monotonic() - t0 < 60, ("too slow", argv)
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
