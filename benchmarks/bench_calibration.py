"""Benchmark: calibrate() on a tetrad-paper session (16 steps, 100 Hz, 57 600 × 4 samples).

Baselines measured in the same run on the same array: one ``np.mean(raw, axis=0)`` pass and
one ``np.linalg.lstsq`` of the per-sample model ``u = a·x + c`` (57 600 × 4 design, 4 sensors),
i.e. the least one could do with the data. Prints the figures and writes
``benchmarks/results/calibration.json``.

Run: ``python benchmarks/bench_calibration.py [--repeats 15]``
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np

from calibration.calibrate import calibrate
from calibration.presets import preset
from calibration.simulate import simulate_session


def _median_time(fn, repeats: int) -> float:
    fn()                                               # warm up
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=15)
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "calibration.json"))
    args = ap.parse_args()
    seq, truth, noise = preset("tetrad-paper")
    s = simulate_session(None, seq, truth, seed=0, noise=noise)
    raw = s.raw_gyro
    wt, we, _ = s.inputs()
    design = np.column_stack([wt + we, np.ones(raw.shape[0])])
    r = args.repeats
    t_full = _median_time(lambda: calibrate(s), r)
    t_noallan = _median_time(lambda: calibrate(s, allan=False), r)
    t_nodenoise = _median_time(lambda: calibrate(s, allan=False, denoise=False), r)
    t_mean = _median_time(lambda: np.mean(raw, axis=0), max(r, 50))
    t_lstsq = _median_time(lambda: np.linalg.lstsq(design, raw, rcond=None), r)
    res = {
        "schema": "rimu.benchmark/1",
        "name": "calibration",
        "session": {"preset": "tetrad-paper", "steps": len(s.steps), "samples": raw.shape[0],
                    "sensors": raw.shape[1], "sample_rate_hz": s.sample_rate_hz},
        "repeats": r,
        "calibrate_s": t_full,
        "calibrate_no_allan_s": t_noallan,
        "calibrate_no_allan_no_denoise_s": t_nodenoise,
        "baseline_mean_s": t_mean,
        "baseline_lstsq_s": t_lstsq,
        "ratio_to_mean": t_full / t_mean,
        "ratio_to_lstsq": t_full / t_lstsq,
        "machine": {"python": platform.python_version(), "numpy": np.__version__,
                    "processor": platform.machine()},
    }
    print(f"calibrate() tetrad-paper ({raw.shape[0]} samples x {raw.shape[1]} gyros, "
          f"{len(s.steps)} steps), median of {r}:")
    print(f"  full (denoise + Earth rate + Allan): {1e3 * t_full:8.1f} ms")
    print(f"  without Allan deviation:             {1e3 * t_noallan:8.1f} ms")
    print(f"  without Allan, without denoising:    {1e3 * t_nodenoise:8.1f} ms")
    print(f"baseline np.mean(raw, axis=0):         {1e3 * t_mean:8.3f} ms  "
          f"(calibrate = {t_full / t_mean:.0f} x)")
    print(f"baseline np.linalg.lstsq (N x 4, 4 rhs):{1e3 * t_lstsq:7.2f} ms  "
          f"(calibrate = {t_full / t_lstsq:.1f} x)")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(res, indent=1) + "\n", encoding="utf-8")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
