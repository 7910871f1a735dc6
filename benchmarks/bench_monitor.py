"""Speed of the streaming monitor: per-step latency and block throughput.

Each figure is also given as a ratio to a bare numpy matrix-vector product measured in the
same run (``V @ y`` for one sample; ``V @ Y`` for a block), so that numbers from different
machines compare. Writes ``benchmarks/results/monitor.json``.

Run: ``python benchmarks/bench_monitor.py [--steps 20000] [--block 1000000]``
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np

from fdi.monitor import Monitor
from thresholds import compute_thresholds, draw_truth, raw_samples, synthetic_calibration

FS = 100.0


def flight(cal, N: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    t = np.arange(N) / FS
    ph = rng.uniform(0, 2 * np.pi, 3)
    fr = rng.uniform(0.05, 0.5, 3)
    om = np.deg2rad(300.0) / np.sqrt(3) * np.sin(2 * np.pi * fr * t[:, None] + ph)
    return t, raw_samples(cal, om, seed=seed + 1, truth=draw_truth(cal, seed=seed + 2))


def bench_step(cal, th, steps: int) -> dict:
    t, raw = flight(cal, steps + 2000)
    rows = list(raw)                                # one (n,) float64 array per sample
    mon = Monitor(cal, th)
    for i in range(2000):                           # warm-up
        mon.step(t[i], rows[i])
    lat = np.empty(steps)
    pc = time.perf_counter_ns
    for k in range(steps):
        i = k + 2000
        ti, ri = float(t[i]), rows[i]
        a = pc()
        mon.step(ti, ri)
        lat[k] = pc() - a
    V = mon.model.V
    base = np.empty(steps)
    for k in range(steps):
        ri = rows[k]
        a = pc()
        V @ ri
        base[k] = pc() - a
    med, p99, bmed = np.median(lat) / 1e3, np.percentile(lat, 99) / 1e3, np.median(base) / 1e3
    return {"steps": steps, "median_us": med, "p99_us": p99, "matvec_median_us": bmed,
            "median_ratio": med / bmed, "p99_ratio": p99 / bmed}


def bench_block(cal, th, N: int, repeats: int = 5) -> dict:
    t, raw = flight(cal, N, seed=5)
    best = np.inf
    for _ in range(repeats):
        mon = Monitor(cal, th)
        a = time.perf_counter()
        res = mon.run(t, raw)
        best = min(best, time.perf_counter() - a)
    assert res.omega.shape == (N, 3)
    V = Monitor(cal, th).model.V
    raw_t = np.ascontiguousarray(raw.T)
    bbest = np.inf
    for _ in range(repeats):
        a = time.perf_counter()
        V @ raw_t
        bbest = min(bbest, time.perf_counter() - a)
    sps, bsps = N / best, N / bbest
    return {"samples": N, "samples_per_s": sps, "matvec_samples_per_s": bsps,
            "ratio_to_matvec": sps / bsps, "events": len(res.events)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=20_000)
    ap.add_argument("--block", type=int, default=1_000_000)
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "monitor.json"))
    args = ap.parse_args()
    results = {"schema": "rimu.benchmark/1", "benchmark": "monitor",
               "machine": {"python": platform.python_version(), "numpy": np.__version__,
                           "processor": platform.processor() or platform.machine()},
               "cases": []}
    for cfg, det in (("cone6", "windows"), ("cone6", "both"), ("tetrad", "windows")):
        cal = synthetic_calibration(cfg, seed=1)
        th = compute_thresholds(cal, detector=det)
        s = bench_step(cal, th, args.steps)
        b = bench_block(cal, th, args.block)
        case = {"configuration": cfg, "detector": det, "scales": len(th.scales),
                "step": s, "block": b}
        results["cases"].append(case)
        print(f"{cfg:7s} {det:8s} step median {s['median_us']:6.2f} µs "
              f"(×{s['median_ratio']:.1f} matvec {s['matvec_median_us']:.2f} µs), "
              f"p99 {s['p99_us']:6.2f} µs (×{s['p99_ratio']:.1f}) | block "
              f"{b['samples_per_s'] / 1e6:5.2f} M samples/s (matvec "
              f"{b['matvec_samples_per_s'] / 1e6:6.1f} M/s, ratio {b['ratio_to_matvec']:.3f})")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(results, indent=1) + "\n", encoding="utf-8")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
