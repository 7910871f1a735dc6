"""fdi.progress: nothing for short work, at most one line a second off a terminal, readable
counts, and every CLI command's work shown once it has taken 3 s."""

import io
import itertools
import threading
import time

import pytest

from fdi import progress as P
from fdi.errors import ConfigError
from rimu.cli import main


@pytest.fixture(autouse=True)
def _progress_on(monkeypatch):
    monkeypatch.delenv("RIMU_PROGRESS", raising=False)      # conftest turns it off


class _Timed(io.StringIO):
    """A non-terminal stream that records when each line was written."""

    def __init__(self):
        super().__init__()
        self.times = []
        self.lock = threading.Lock()

    def write(self, s):
        with self.lock:
            self.times.extend(time.monotonic() for _ in range(s.count("\n")))
            return super().write(s)

    def isatty(self):
        return False


def _gaps(ts):
    return [b - a for a, b in itertools.pairwise(ts)]


def test_counts_are_written_as_people_write_them():
    # tune's bar printed "0.15000000000000002/8.0"
    assert P.fmt_amount(0.15000000000000002) == "0.15"
    assert P.fmt_amount(8.0) == "8" and P.fmt_amount(36000.4) == "36000"
    prog = P.Progress("tune", enabled=False)
    b = prog.bar(8.0, "simulated flight", unit="h")
    for _ in range(3):
        b.update(0.05)
    txt = b.text(time.monotonic())
    assert "0.15/8 h" in txt and "0.15000" not in txt, txt


def test_short_work_prints_nothing():
    s = _Timed()
    with P.Progress("x", stream=s, delay_s=3.0) as p:
        p.stage("a")
        b = p.bar(100, "items")
        for _ in range(100):
            b.update()
        time.sleep(0.3)
    assert s.getvalue() == ""


def test_a_busy_bar_prints_at_most_one_line_a_second_off_a_terminal():
    s = _Timed()
    t0 = time.monotonic()
    with P.Progress("x", stream=s, delay_s=0.0) as p:
        for k in range(6):
            p.stage(f"stage {k}")               # stages faster than one a second
            b = p.bar(1000, "items", unit="items")
            for _ in range(1000):
                b.update()
                time.sleep(0.0004)
    elapsed = time.monotonic() - t0
    lines = s.getvalue().splitlines()
    assert lines and all(ln.startswith("rimu: x: ") for ln in lines), lines
    assert "\r" not in s.getvalue()
    # one line a second at most: gaps between lines, and lines over the whole run
    assert all(g >= P.MIN_LINE_GAP_S - 0.05 for g in _gaps(s.times)), _gaps(s.times)
    assert len(lines) <= elapsed / P.MIN_LINE_GAP_S + 1, (len(lines), elapsed)


def test_a_long_stage_keeps_saying_it_runs(monkeypatch):
    monkeypatch.setattr(P, "LINE_EVERY_S", 1.0)
    s = _Timed()
    with P.Progress("calibrate", stream=s, delay_s=0.0) as p:
        p.stage("rate test")
        time.sleep(3.2)
    lines = s.getvalue().splitlines()
    assert lines[0].startswith("rimu: calibrate: rate test")
    assert 3 <= sum("rate test" in ln for ln in lines) <= 4, lines
    assert all(g >= P.MIN_LINE_GAP_S - 0.05 for g in _gaps(s.times)), _gaps(s.times)


def test_done_line_after_the_work(monkeypatch):
    s = _Timed()
    with P.Progress("calibrate", stream=s, delay_s=0.0) as p:
        p.stage("rate test")
        time.sleep(1.3)
    lines = s.getvalue().splitlines()
    assert len(lines) == 2 and lines[1].startswith("rimu: calibrate: done in"), lines


def test_terminal_line_redrawn_and_cleared():
    class Tty(io.StringIO):
        def isatty(self):
            return True

    s = Tty()
    with P.Progress("tune", stream=s, delay_s=0.0) as p:
        b = p.bar(8.0, "simulated flight", unit="h")
        for _ in range(4):
            b.update(0.5)
            time.sleep(0.3)
    out = s.getvalue()
    assert out.count("\r") >= 3 and "\n" not in out
    assert "/8 h" in out and out.endswith("\r")


def test_a_failure_ends_without_a_done_line():
    s = _Timed()
    with pytest.raises(RuntimeError), P.Progress("x", stream=s, delay_s=0.0) as p:
        p.stage("a")
        time.sleep(1.2)
        raise RuntimeError("boom")
    assert "done" not in s.getvalue()


def test_nothing_before_a_stage_and_a_stage_after_three_seconds(monkeypatch, capsys,
                                                               tmp_path):
    """The CLI runs each command in a progress session: nothing is shown before its first
    stage (a refusal stays one line, however slow the start); a stage that runs past 3 s is
    said, and then how long the work took; ``RIMU_PROGRESS=0`` silences it."""
    import rimu.commands.characterise as ch
    from fdi.progress import current

    def slow(args):
        time.sleep(2.0)                 # imports, input checks (not counted): nothing shown
        current().stage("long work")
        time.sleep(4.6)
        return 0

    monkeypatch.setattr(ch, "run", slow)
    assert main(["characterise", str(tmp_path)]) == 0
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 2 and err[0].startswith("rimu: characterise: long work"), err
    assert err[-1].startswith("rimu: characterise: done in"), err

    def refused(args):
        time.sleep(3.5)                 # a slow start, then a refusal: one line
        raise ConfigError("bad input")

    monkeypatch.setattr(ch, "run", refused)
    assert main(["characterise", str(tmp_path)]) == 2
    assert capsys.readouterr().err.splitlines() == ["rimu: error: bad input"]
    monkeypatch.setattr(ch, "run", lambda args: current().stage("x") or time.sleep(1.2))
    monkeypatch.setenv("RIMU_PROGRESS_DELAY_S", "0")
    monkeypatch.setenv("RIMU_PROGRESS", "0")
    assert main(["characterise", str(tmp_path)]) == 0
    assert capsys.readouterr().err == ""


def test_command_stages_named(monkeypatch, capsys, tmp_path):
    """A real command names its stages (delay set to 0 to see them on a short run)."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parents[1] / "replay"))
    from test_logio import CAL

    from replay.flight import simulate_flight
    from replay.flight_io import save_flight_dir

    f = simulate_flight(CAL, 2.0, seed=3)
    save_flight_dir(f, tmp_path / "f")
    monkeypatch.setenv("RIMU_PROGRESS_DELAY_S", "0")
    assert main(["characterise", str(tmp_path / "f")]) == 0
    err = capsys.readouterr().err
    assert "rimu: characterise: reading the flight folder" in err, err
    cal = tmp_path / "cal.json"
    CAL.save(cal)
    assert main(["monitor-file", str(tmp_path / "f"), "--cal", str(cal)]) == 0
    err = capsys.readouterr().err
    assert "rimu: monitor-file: monitoring 200 samples" in err, err


def test_live_monitor_on_a_quiet_bus_says_it_is_waiting(monkeypatch):
    """``rimu monitor`` on a bus that gives nothing says "waiting" every few seconds (with
    frames, it says how many and the last sample time instead)."""
    import sys
    import uuid
    from pathlib import Path

    import can

    sys.path.insert(0, str(Path(__file__).parents[1] / "replay"))
    from test_logio import CAL

    import replay.live as live
    from fdi.monitor import Monitor
    from replay.logio import resolve_map

    monkeypatch.setattr(live, "STATUS_EVERY_S", 1.0)
    db, cmap = resolve_map(CAL)
    ch = f"rimu-test-{uuid.uuid4().hex}"
    s = _Timed()
    with can.Bus(interface="virtual", channel=ch, ignore_config=True,
                 preserve_timestamps=True) as rx, \
            P.session("monitor", stream=s, delay_s=0.0):
        live.run_live(rx, live.StreamDecoder(db, cmap, CAL.sample_rate_hz), Monitor(CAL),
                      duration_s=2.6)
    lines = s.getvalue().splitlines()
    assert sum("waiting: no frame received in" in ln for ln in lines) >= 2, lines
    assert all(g >= P.MIN_LINE_GAP_S - 0.05 for g in _gaps(s.times))
