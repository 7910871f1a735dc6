"""Replay speed: a one-hour 100 Hz six-sensor CAN log, as a ratio to python-can's bare reader.

For each format (.blf, .log) the script generates the log once into a temporary directory
(a simulated cone6 flight through the shipped DBC), then times, interleaved and repeated
(best of ``--repeat``; the machine is shared):

- ``bare``: ``for m in can.LogReader(path): pass`` — the baseline;
- ``replay``: ``read_log`` (read every frame, check, decode, assemble) + ``Monitor.run`` +
  ``build_report`` — what ``rimu replay`` does apart from printing;
- ``replay_rrd``: the same plus the rerun recording written to a file.

Targets: replay < 1.5× bare, replay with --rrd < 2× bare; the rerun recording of the hour
must take less time than the replay itself. Also the decode rate on the real comma2k19
log (frames/s, and as a ratio to the bare reader on that file).

Ratios are given on process CPU time (``time.process_time``, all threads of the process:
rerun's encoder threads count) — the machine is shared by several jobs, so wall-clock time
swings by ±50 % from run to run — and, for reference, on wall time.

Usage: ``python benchmarks/bench_replay.py [--hours 1] [--repeat 2] [--formats blf,log]``.
Writes ``benchmarks/results/replay.json``.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import can
import numpy as np
from _common import ROOT, header, machine, spread, write_results

from fdi.calfile import Calibration, SensorCal, SensorSet
from fdi.geometry import load_configuration
from fdi.monitor import Monitor
from fdi.units import DPH, DPS
from replay.can_read import read_frames
from replay.can_write import write_flight_log
from replay.faults import parse_fault
from replay.flight import simulate_flight
from replay.logio import read_log
from replay.report import build_report

COMMA = ROOT / ".." / "shared" / "data" / "comma2k19_can"


def make_cal() -> Calibration:
    """cone6, 0.01 °/s per-sample noise, raw in mV (as the replay tests)."""
    cfg = load_configuration("cone6")
    rng = np.random.default_rng(0)
    sf, err = 0.01 * DPS, 2e-4
    sens = []
    for i in range(cfg.n):
        h = cfg.H[i] + 1e-3 * rng.standard_normal(3)
        sens.append(SensorCal(
            name=cfg.sensor_names[i], axis=h / np.linalg.norm(h), axis_nominal=cfg.H[i],
            scale_factor=sf * (1 + 0.01 * i), scale_factor_sd=err * sf,
            bias=10 * DPH * rng.standard_normal(), bias_sd=(1 + i) * DPH,
            input_error_cov=np.diag([1.0, 2.0, 3.0]) * err ** 2,
            misalignment_sd=np.full(2, err), raw_unit="mV",
            scale_factor_unit="mV/(deg/s)", bias_unit="deg/h"))
    cov = (0.01 * DPS) ** 2 * np.eye(cfg.n)
    return Calibration(cfg.name, {"gyro": SensorSet("gyro", tuple(sens), cov)}, 100.0)


def bare(path: Path) -> tuple[float, float, int]:
    """(cpu s, wall s, frames) of python-can's bare LogReader iteration."""
    c0, t0 = time.process_time(), time.perf_counter()
    n = 0
    for _ in can.LogReader(str(path)):
        n += 1
    return time.process_time() - c0, time.perf_counter() - t0, n


def replay(path: Path, cal: Calibration, rrd: Path | None) -> dict[str, float]:
    c0 = time.process_time()
    t0 = time.perf_counter()
    flight, frames = read_log(path, cal, progress=False)
    t1 = time.perf_counter()
    mon = Monitor(cal)
    res = mon.run(flight.t, flight.raw, flight.valid)
    t2 = time.perf_counter()
    build_report(res, flight, cal, frames=frames)
    t3 = time.perf_counter()
    out = {"read_decode_s": t1 - t0, "monitor_s": t2 - t1, "report_s": t3 - t2,
           "total_s": t3 - t0, "cpu_s": time.process_time() - c0, "frames": frames["read"],
           "balanced": frames["balanced"], "events": len(res.events)}
    if rrd is not None:
        from replay.rerun_log import record

        c3 = time.process_time()
        tim = record(res, flight, cal, path=rrd, thresholds=mon.thresholds)
        t4 = time.perf_counter()
        out["rerun_cpu_s"] = time.process_time() - c3
        out["cpu_s"] = time.process_time() - c0
        out["rerun_s"] = t4 - t3
        out["rerun_log_s"] = tim["log_s"]
        out["rerun_flush_s"] = tim["flush_s"]
        out["rrd_bytes"] = rrd.stat().st_size
        out["total_s"] = t4 - t0
    return out


def comma() -> dict[str, float] | None:
    log = COMMA / "rav4_2018-08-02--08-34-47_seg40.candump.log"
    dbc = COMMA / "toyota_2017_kinematics_excerpt.dbc"
    if not log.is_file():
        return None
    from replay.accounting import FrameAccounting  # noqa: F401
    from replay.assemble import decode_frames
    from replay.channel_map import ChannelMap, SensorChannel
    from replay.frames import load_dbc

    cmap = ChannelMap((SensorChannel("yaw_rate", "KINEMATICS", "YAW_RATE", "deg/s",
                                     channel=0),), time_tolerance_s=0.002)
    db = load_dbc(dbc)
    best_b, best_r, acct_d = np.inf, np.inf, None
    for _ in range(3):
        cb, _, n = bare(log)
        c0 = time.process_time()
        frames, acct = read_frames(log, progress=False)
        s = decode_frames(frames, db, cmap, acct, sample_rate_hz=83.0)
        cr = time.process_time() - c0
        best_b, best_r = min(best_b, cb), min(best_r, cr)
        acct_d = acct.to_dict()
    return {"frames": n, "bare_cpu_s": best_b, "decode_cpu_s": best_r,
            "decode_frames_per_s": n / best_r, "ratio_cpu": best_r / best_b,
            "samples": int(s.t.size), "accounting": acct_d}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=1.0)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--formats", default="blf,log")
    args = ap.parse_args()
    cal = make_cal()
    results: dict = header("replay", hours=args.hours, sample_rate_hz=100.0, sensors=6,
                           formats={})
    results["machine"] = machine(can=can.__version__)
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        t0 = time.perf_counter()
        flight = simulate_flight(cal, 3600.0 * args.hours, seed=1,
                                 faults=(parse_fault("step:3:20sigma:1800", cal),))
        results["simulate_s"] = time.perf_counter() - t0
        print(f"simulated {flight.t.size} samples in {results['simulate_s']:.1f} s")
        for fmt in args.formats.split(","):
            path = d / f"hour.{fmt}"
            t0 = time.perf_counter()
            write_flight_log(flight, path)
            tw = time.perf_counter() - t0
            print(f"{fmt}: wrote {path.stat().st_size / 1e6:.1f} MB in {tw:.1f} s")
            runs = []
            for r in range(args.repeat):
                cb, tb, n = bare(path)
                rp = replay(path, cal, None)
                rr_ = replay(path, cal, d / "hour.rrd")
                runs.append({"bare_cpu_s": cb, "bare_wall_s": tb, "replay": rp,
                             "replay_rrd": rr_})
                print(f"  run {r + 1}: cpu (wall) s: bare {cb:.2f} ({tb:.2f}), replay "
                      f"{rp['cpu_s']:.2f} ({rp['total_s']:.2f}), with rrd {rr_['cpu_s']:.2f} "
                      f"({rr_['total_s']:.2f}; rerun {rr_['rerun_cpu_s']:.2f} "
                      f"({rr_['rerun_s']:.2f}))")
            bc = min(x["bare_cpu_s"] for x in runs)
            bw = min(x["bare_wall_s"] for x in runs)
            rc = min(x["replay"]["cpu_s"] for x in runs)
            rw = min(x["replay"]["total_s"] for x in runs)
            qc = min(x["replay_rrd"]["cpu_s"] for x in runs)
            qw = min(x["replay_rrd"]["total_s"] for x in runs)
            rerun_c = min(x["replay_rrd"]["rerun_cpu_s"] for x in runs)
            rerun_w = min(x["replay_rrd"]["rerun_s"] for x in runs)
            res = {"frames": n, "file_bytes": path.stat().st_size, "write_s": tw,
                   "bare_cpu_s": bc, "bare_wall_s": bw, "replay_cpu_s": rc, "replay_wall_s": rw,
                   "replay_rrd_cpu_s": qc, "replay_rrd_wall_s": qw,
                   "ratio_replay_cpu": rc / bc, "ratio_replay_rrd_cpu": qc / bc,
                   "ratio_replay_wall": rw / bw, "ratio_replay_rrd_wall": qw / bw,
                   "rerun_cpu_s": rerun_c, "rerun_wall_s": rerun_w,
                   "rerun_faster_than_replay": rerun_w < rw,
                   "replay_cpu_s_spread": spread(x["replay"]["cpu_s"] for x in runs),
                   "bare_cpu_s_spread": spread(x["bare_cpu_s"] for x in runs), "runs": runs}
            results["formats"][fmt] = res
            print(f"  {fmt}: {n} frames; replay {rc / bc:.2f}x bare (cpu; wall "
                  f"{rw / bw:.2f}x; target < 1.5), with --rrd {qc / bc:.2f}x (wall "
                  f"{qw / bw:.2f}x; target < 2); rerun recording {rerun_w:.2f} s wall for "
                  f"{flight.t.size} samples vs replay {rw:.2f} s")
            path.unlink()
    c = comma()
    if c is not None:
        results["comma2k19"] = c
        print(f"comma2k19: {c['frames']} frames decoded at {c['decode_frames_per_s']:.0f} "
              f"frames/s (cpu; {c['ratio_cpu']:.2f}x the bare reader); accounting "
              f"{c['accounting']}")
    write_results(results)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
