"""``rimu demo``: the whole chain on built-in defaults, no downloads.

1. simulate a turntable calibration session of the six-sensor MEMS cone (seed 001 preset),
2. calibrate it and compare with the truth sidecar,
3. compute detection thresholds for 1e-3 false alarms per hour,
4. simulate a manoeuvring flight with two successive sensor faults and write it as a CAN log,
5. replay the log through the monitor, print events and the report, draw ``replay.png``
   (rates with the unverified spans shaded, statistic against threshold per window, the
   events and the injected faults: :mod:`replay.plots`, no display needed),
6. write a rerun recording of the replay.
"""

from __future__ import annotations

import argparse
import json
import logging
import time
from pathlib import Path

from rimu.argtypes import SEED_MAX, bounded_float, nonnegative_int
from rimu.optional import available

MAX_DURATION_S = 3600.0
"""Longest demo flight (s): one hour is already a 130 MB BLF log."""
FAULTS = ("step:3:8sigma:20", "ramp:5:0.5sigma/s:35")
"""The demo's two faults (onsets 20 s and 35 s)."""
MIN_DURATION_S = 40.0
"""Shortest demo flight (s): both faults start within it, 5 s before its end at least."""

HELP = "run the whole chain on a simulated cone of six MEMS sensors (no downloads)"


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", default="rimu-demo", help="output directory (default: rimu-demo)")
    p.add_argument("--seed", type=nonnegative_int(SEED_MAX), default=7,
                   help="random seed (default 7)")
    p.add_argument("--duration", default=60.0,
                   type=bounded_float(MIN_DURATION_S, MAX_DURATION_S, name="duration in s"),
                   help=f"flight duration in seconds (default 60, {MIN_DURATION_S:g} to "
                        f"{MAX_DURATION_S:g}: the faults start at 20 s and 35 s)")
    p.add_argument("--no-rrd", action="store_true", help="skip the rerun recording")


def _say(step: int, text: str) -> None:
    print(f"\n[{step}/6] {text}", flush=True)


def run(args: argparse.Namespace) -> int:
    from rimu.outputs import atomic_dir, output_dir

    final = output_dir(args.out, "--out")
    t0 = time.perf_counter()
    with atomic_dir(final) as out:
        _demo(args, out, final)
    print(f"\ndone in {time.perf_counter() - t0:.1f} s; outputs in {final}/")
    return 0


def _demo(args: argparse.Namespace, out: Path, final: Path) -> None:
    """The six steps, writing into ``out`` (a temporary folder renamed to ``final``)."""
    from calibration.calibrate import calibrate
    from calibration.compare import compare, format_comparison
    from calibration.presets import preset
    from calibration.simulate import save_simulation, simulate_session
    from fdi.calfile import load_calibration
    from fdi.monitor import Monitor
    from replay.can_write import write_flight_log
    from replay.faults import parse_fault
    from replay.flight import simulate_flight
    from replay.logio import read_log
    from replay.plots import plot_run, scale_labels
    from replay.report import RunningReport, format_summary
    from thresholds import compute_thresholds

    _say(1, "simulating a cone6 turntable session (seed 001 Tables 1-2, preset cone-paper)")
    p = preset("cone-paper")
    session = simulate_session(p.config, p.sequence, p.truth, seed=args.seed,
                               accel_config=p.accel_config, noise=p.noise)
    sess_dir = out / "session"
    save_simulation(session, p.truth, sess_dir)
    print(f"  {session.t.size} samples, {len(session.steps)} steps -> {final / 'session'}")

    _say(2, "calibrating (rate test, multi-position test, Earth rate removed)")
    cal = calibrate(session)
    if isinstance(cal.extra, dict):
        cal.extra["source"] = str(final / "session")
    cal_path = out / "cal.json"
    cal.save(cal_path)
    cal = load_calibration(cal_path)
    print(format_comparison(compare(cal, p.truth)))
    print(f"  -> {final / 'cal.json'}")

    _say(3, "thresholds for 1e-3 false alarms per hour")
    thr = compute_thresholds(cal, false_alarms_per_hour=1e-3)
    thr_path = out / "thresholds.json"
    thr.save(thr_path)
    print(f"  {len(thr.scales)} dyadic scales -> {final / 'thresholds.json'}")

    _say(4, "simulating a flight with two successive faults, written as a CAN log")
    specs = list(FAULTS)
    faults = [parse_fault(s, cal) for s in specs]
    flight = simulate_flight(cal, args.duration, seed=args.seed, faults=faults)
    log_path = out / "flight.blf"
    write_flight_log(flight, log_path)
    print(f"  {flight.t.size} samples, faults {', '.join(specs)} -> {final / 'flight.blf'}")

    _say(5, "replaying the log through the monitor")
    replayed, frames = read_log(log_path, cal, progress=False)
    mon = Monitor(cal, thr)
    result = mon.run(replayed.t, replayed.raw, replayed.valid, parity=True)
    acc = RunningReport()
    om = replayed.omega_true
    acc.update(result, om if om is not None and len(om) == len(result.t) else None)
    report = acc.build(replayed, cal, frames=frames)
    report["source"] = str(final / "flight.blf")
    names = [c.name for c in cal.gyro.sensors]
    for e in report["events"]:
        k = e["sensor"]
        who = (f"{k} ({names[k - 1]})" if isinstance(k, int) and 1 <= k <= len(names) else
               "- (not isolated)" if k is None else k)
        print(f"  t={e['t']:8.2f} s  sensor {who}  {e['type']:9s} {e['reason']}")
    print(format_summary(report))
    rep_path = out / "report.json"
    rep_path.write_text(json.dumps(report, indent=1, allow_nan=False) + "\n", encoding="utf-8")
    print(f"  -> {final / 'report.json'}")
    if available("matplotlib"):
        plot_run(acc.trace, out / "replay.png", report=report,
                 scale_names=scale_labels(thr, result.statistics.shape[1]),
                 title=f"rimu demo: faults {', '.join(specs)}")
        print(f"  -> {final / 'replay.png'}  (rates, statistic / threshold per window, events)")
    else:                           # the core path needs no extra: the figure is the one left out
        logging.getLogger("rimu").warning(
            'replay.png not drawn: matplotlib is missing (the "plots" extra: '
            'pip install "rimu[plots]")')

    _say(6, "rerun recording")
    if args.no_rrd:
        print("  skipped (--no-rrd)")
    else:
        from replay.rerun_log import record

        rrd = out / "replay.rrd"
        record(result, replayed, cal, path=rrd, thresholds=thr)
        print(f"  -> {final / 'replay.rrd'}  (open with: rerun {final / 'replay.rrd'}; "
              f"without a display: rerun {final / 'replay.rrd'} --web-viewer, then a browser "
              "at the address it prints)")
