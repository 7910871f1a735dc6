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

Usage: ``python benchmarks/bench_replay.py [--hours 1] [--repeat 2] [--formats blf,log]``.
Writes ``benchmarks/results/replay.json``.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import tempfile
import time
from pathlib import Path

import can
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fdi.calfile import Calibration, SensorCal, SensorSet  # noqa: E402
from fdi.geometry import load_configuration  # noqa: E402
from fdi.monitor import Monitor  # noqa: E402
from fdi.units import DPH, DPS  # noqa: E402
from replay.faults import parse_fault  # noqa: E402
from replay.flight import simulate_flight  # noqa: E402
from replay.logio import read_frames, read_log, write_flight_log  # noqa: E402
from replay.report import build_report  # noqa: E402

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


def bare(path: Path) -> tuple[float, int]:
    t0 = time.perf_counter()
    n = 0
    for _ in can.LogReader(str(path)):
        n += 1
    return time.perf_counter() - t0, n


def replay(path: Path, cal: Calibration, rrd: Path | None) -> dict[str, float]:
    t0 = time.perf_counter()
    flight, frames = read_log(path, cal, progress=False)
    t1 = time.perf_counter()
    mon = Monitor(cal)
    res = mon.run(flight.t, flight.raw, flight.valid)
    t2 = time.perf_counter()
    build_report(res, flight, cal, frames=frames)
    t3 = time.perf_counter()
    out = {"read_decode_s": t1 - t0, "monitor_s": t2 - t1, "report_s": t3 - t2,
           "total_s": t3 - t0, "frames": frames["read"], "balanced": frames["balanced"],
           "events": len(res.events)}
    if rrd is not None:
        from replay.rerun_log import record

        tim = record(res, flight, cal, path=rrd, thresholds=mon.thresholds)
        t4 = time.perf_counter()
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
        tb, n = bare(log)
        t0 = time.perf_counter()
        frames, acct = read_frames(log, progress=False)
        s = decode_frames(frames, db, cmap, acct, sample_rate_hz=83.0)
        tr = time.perf_counter() - t0
        best_b, best_r = min(best_b, tb), min(best_r, tr)
        acct_d = acct.to_dict()
    return {"frames": n, "bare_s": best_b, "decode_s": best_r,
            "decode_frames_per_s": n / best_r, "ratio": best_r / best_b,
            "samples": int(s.t.size), "accounting": acct_d}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=1.0)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--formats", default="blf,log")
    args = ap.parse_args()
    cal = make_cal()
    results: dict = {"hours": args.hours, "sample_rate_hz": 100.0, "sensors": 6,
                     "python": platform.python_version(), "can": can.__version__,
                     "machine": platform.machine(), "formats": {}}
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
            best = {"bare_s": np.inf, "replay_s": np.inf, "replay_rrd_s": np.inf}
            detail: dict = {}
            for r in range(args.repeat):
                tb, n = bare(path)
                rp = replay(path, cal, None)
                rr_ = replay(path, cal, d / "hour.rrd")
                best["bare_s"] = min(best["bare_s"], tb)
                if rp["total_s"] < best["replay_s"]:
                    best["replay_s"], detail["replay"] = rp["total_s"], rp
                if rr_["total_s"] < best["replay_rrd_s"]:
                    best["replay_rrd_s"], detail["replay_rrd"] = rr_["total_s"], rr_
                print(f"  run {r + 1}: bare {tb:.2f} s, replay {rp['total_s']:.2f} s, "
                      f"with rrd {rr_['total_s']:.2f} s (rerun {rr_['rerun_s']:.2f} s)")
            res = {"frames": n, "file_bytes": path.stat().st_size, "write_s": tw, **best,
                   "ratio_replay": best["replay_s"] / best["bare_s"],
                   "ratio_replay_rrd": best["replay_rrd_s"] / best["bare_s"],
                   "rerun_s": detail["replay_rrd"]["rerun_s"],
                   "rerun_faster_than_replay": detail["replay_rrd"]["rerun_s"]
                   < best["replay_s"], **{k: v for k, v in detail.items()}}
            results["formats"][fmt] = res
            print(f"  {fmt}: {n} frames; bare {best['bare_s']:.2f} s, replay "
                  f"{best['replay_s']:.2f} s ({res['ratio_replay']:.2f}x, target < 1.5), "
                  f"with --rrd {best['replay_rrd_s']:.2f} s ({res['ratio_replay_rrd']:.2f}x, "
                  f"target < 2); rerun {res['rerun_s']:.2f} s for {flight.t.size} samples")
    c = comma()
    if c is not None:
        results["comma2k19"] = c
        print(f"comma2k19: {c['frames']} frames decoded at {c['decode_frames_per_s']:.0f} "
              f"frames/s ({c['ratio']:.2f}x the bare reader); accounting {c['accounting']}")
    out = ROOT / "benchmarks" / "results" / "replay.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(results, indent=1) + "\n", encoding="utf-8")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
