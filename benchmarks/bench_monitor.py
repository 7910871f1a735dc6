"""Speed of the streaming monitor against a bare matrix product measured in the same run.

Figures (min / median / max over ``--repeat`` repeats, BLAS limited to one thread with
threadpoolctl, the machine being shared):

- block: ``Monitor.run`` on an N-sample block, as samples/s and as a fraction of a bare
  ``V @ Y`` (Y: (n, N) contiguous, V the parity matrix) — target ≥ 0.2 on cone6; also on
  process CPU time (less sensitive to other jobs on a shared machine);
- step: ``Monitor.step`` latency per sample (median over ``--steps`` samples per repeat), as a
  multiple of a bare ``V @ y`` on one sample — target ≤ 5×;
- compile: a fresh Python process with an empty numba cache (first use compiles and caches
  the kernel) and a later process that loads it (``NUMBA_CACHE_DIR`` in a temporary folder);
- block breakdown (what bounds the block figure): the compiled kernel alone over the same rows
  into an output already written once, and the first write of a fresh output array of the
  same size (``np.empty`` + fill: page faults and memory bandwidth), per sample.

Run: ``python benchmarks/bench_monitor.py [--steps 20000] [--block 1000000] [--repeat 5]``.
Writes ``benchmarks/results/monitor.json``.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time

import numpy as np
from _common import RESULTS, ROOT, header, spread, write_results
from threadpoolctl import threadpool_limits

from fdi import state as S
from fdi.monitor import Monitor
from studies.synthetic import draw_truth, raw_samples, synthetic_calibration
from thresholds import compute_thresholds

FS = 100.0
_FIRST_USE = """
import time, numpy as np
t0 = time.perf_counter()
from fdi.monitor import Monitor
from studies.synthetic import synthetic_calibration
t1 = time.perf_counter()
cal = synthetic_calibration("cone6", seed=1)
mon = Monitor(cal)
t2 = time.perf_counter()
mon.step(0.0, np.ones(6))
mon.run(np.arange(4) / 100.0, np.ones((4, 6)) + np.arange(4)[:, None])
t3 = time.perf_counter()
print(t1 - t0, t2 - t1, t3 - t2)
"""


def flight(cal, N: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Healthy manoeuvring flight: rates up to 300 °/s, raw samples (N, n)."""
    rng = np.random.default_rng(seed)
    t = np.arange(N) / FS
    ph = rng.uniform(0, 2 * np.pi, 3)
    fr = rng.uniform(0.05, 0.5, 3)
    om = np.deg2rad(300.0) / np.sqrt(3) * np.sin(2 * np.pi * fr * t[:, None] + ph)
    return t, raw_samples(cal, om, seed=seed + 1, truth=draw_truth(cal, seed=seed + 2))


def bench_step(cal, th, steps: int, repeat: int) -> dict:
    """Median step latency per repeat, and the bare V @ y of the same samples, interleaved."""
    t, raw = flight(cal, steps + 2000)
    rows = list(raw)
    pc = time.perf_counter_ns
    med, base = [], []
    for _ in range(repeat):
        mon = Monitor(cal, th)
        for i in range(2000):                                   # warm-up (windows filled)
            mon.step(t[i], rows[i])
        V = mon.model.V
        lat = np.empty(steps)
        for k in range(steps):
            i = k + 2000
            ti, ri = float(t[i]), rows[i]
            a = pc()
            mon.step(ti, ri)
            lat[k] = pc() - a
        bl = np.empty(steps)
        for k in range(steps):
            ri = rows[k + 2000]
            a = pc()
            V @ ri
            bl[k] = pc() - a
        med.append(float(np.median(lat)) / 1e3)
        base.append(float(np.median(bl)) / 1e3)
    ratio = [m / b for m, b in zip(med, base, strict=True)]
    return {"steps": steps, "step_median_us": spread(med), "matvec_median_us": spread(base),
            "ratio": spread(ratio), "target_ratio_max": 5.0,
            "met": bool(np.median(ratio) <= 5.0)}


def bench_block(cal, th, N: int, repeat: int) -> dict:
    """Monitor.run throughput and bare V @ Y throughput, interleaved per repeat."""
    t, raw = flight(cal, N, seed=5)
    V = Monitor(cal, th).model.V
    Y = np.ascontiguousarray(raw.T)
    run_s, mv_s, ratio, cpu_ratio, kern, touch = [], [], [], [], [], []
    events = 0
    for _ in range(repeat):
        mon = Monitor(cal, th)
        a, ca = time.perf_counter(), time.process_time()
        res = mon.run(t, raw)
        run_s.append(time.perf_counter() - a)
        run_cpu = time.process_time() - ca
        events = len(res.events)
        a, ca = time.perf_counter(), time.process_time()
        V @ Y
        mv_s.append(time.perf_counter() - a)
        mv_cpu = time.process_time() - ca
        ratio.append(mv_s[-1] / run_s[-1])
        cpu_ratio.append(mv_cpu / run_cpu)
        kern.append(_kernel_alone(cal, th, t, raw) / N * 1e9)
        a = time.perf_counter()
        fresh = np.empty((N, mon._layout.width(False)))
        fresh.fill(0.0)
        touch.append((time.perf_counter() - a) / N * 1e9)
        del fresh
    return {"samples": N, "events": events,
            "run_samples_per_s": spread([N / s for s in run_s]),
            "matvec_samples_per_s": spread([N / s for s in mv_s]),
            "ratio_to_matvec": spread(ratio), "ratio_to_matvec_cpu_time": spread(cpu_ratio),
            "breakdown_ns_per_sample": {
                "run": spread([s / N * 1e9 for s in run_s]), "kernel_alone": spread(kern),
                "first_write_of_output": spread(touch),
                "output_bytes_per_sample": 8 * mon._layout.width(False),
                "matvec": spread([s / N * 1e9 for s in mv_s])},
            "target_ratio_min": 0.2, "met": bool(np.median(ratio) >= 0.2)}


def _kernel_alone(cal, th, t: np.ndarray, raw: np.ndarray) -> float:
    """Seconds of the compiled kernel alone over the rows, into an output written once
    before (no page faults), without the monitor's per-row bookkeeping (health, capability,
    ω̂ sd columns) and result assembly."""
    mon = Monitor(cal, th)
    out = np.empty((t.shape[0], mon._layout.width(False)))
    out.fill(0.0)                                            # written once: no page faults
    c = mon._state.counters
    c[S.HAS_VALID], c[S.HAS_PARITY], c[S.PHASE] = 0, 0, S.PHASE_HEALTH
    a = time.perf_counter()
    stop, _ = mon._kernel(t, raw, mon._no_correction, mon._all_valid, 0, t.shape[0], out)
    s = time.perf_counter() - a
    return s if stop == t.shape[0] else float("nan")        # an event would end it early


def bench_compile() -> dict:
    """Import, set-up and first step+run in a fresh process (empty numba cache), then in a
    later process (cache filled)."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    out = {}
    with tempfile.TemporaryDirectory() as cache:
        env["NUMBA_CACHE_DIR"] = cache
        for name in ("fresh_cache", "cached"):
            a = time.perf_counter()
            p = subprocess.run([sys.executable, "-c", _FIRST_USE], env=env, check=True,
                               capture_output=True, text=True)
            wall = time.perf_counter() - a
            imp, setup, first = (float(x) for x in p.stdout.split())
            out[name] = {"process_wall_s": wall, "import_s": imp, "monitor_setup_s": setup,
                         "first_step_and_run_s": first}
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=20_000)
    ap.add_argument("--block", type=int, default=1_000_000)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--out", default=str(RESULTS / "monitor.json"))
    args = ap.parse_args()
    results = header("monitor", blas_threads=1, steps=args.steps, block=args.block,
                     repeat=args.repeat, compile=bench_compile(), cases=[])
    c = results["compile"]
    print(f"compile: fresh cache first step+run {c['fresh_cache']['first_step_and_run_s']:.2f} s "
          f"(process {c['fresh_cache']['process_wall_s']:.2f} s); cached "
          f"{c['cached']['first_step_and_run_s']:.3f} s (process "
          f"{c['cached']['process_wall_s']:.2f} s)")
    with threadpool_limits(limits=1):
        for cfg, det in (("cone6", "windows"), ("cone6", "both"), ("tetrad", "windows")):
            cal = synthetic_calibration(cfg, seed=1)
            th = compute_thresholds(cal, detector=det)
            s = bench_step(cal, th, args.steps, args.repeat)
            b = bench_block(cal, th, args.block, args.repeat)
            results["cases"].append({"configuration": cfg, "detector": det,
                                     "scales": len(th.scales), "step": s, "block": b})
            sm, sb, sr = s["step_median_us"], s["matvec_median_us"], s["ratio"]
            br, bm, bq = b["run_samples_per_s"], b["matvec_samples_per_s"], b["ratio_to_matvec"]
            print(f"{cfg:7s} {det:8s} step {sm['min']:.2f}/{sm['median']:.2f}/{sm['max']:.2f} µs"
                  f" = ×{sr['min']:.1f}/{sr['median']:.1f}/{sr['max']:.1f} of V@y "
                  f"({sb['median']:.2f} µs) [target ≤5: {'met' if s['met'] else 'NOT met'}]")
            print(f"{'':16s} run {br['min'] / 1e6:.2f}/{br['median'] / 1e6:.2f}/"
                  f"{br['max'] / 1e6:.2f} M/s = {bq['min']:.3f}/{bq['median']:.3f}/"
                  f"{bq['max']:.3f} of V@Y ({bm['median'] / 1e6:.1f} M/s; on CPU time "
                  f"{b['ratio_to_matvec_cpu_time']['median']:.3f}) "
                  f"[target ≥0.2: {'met' if b['met'] else 'NOT met'}]")
            bd = b["breakdown_ns_per_sample"]
            print(f"{'':16s} per sample (median): run {bd['run']['median']:.0f} ns; measured "
                  f"apart: kernel alone {bd['kernel_alone']['median']:.0f} ns, first write of "
                  f"a fresh {bd['output_bytes_per_sample']}-byte output row "
                  f"{bd['first_write_of_output']['median']:.0f} ns; V@Y "
                  f"{bd['matvec']['median']:.1f} ns")
    write_results(results, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
