"""Speed and size of the exported C monitor (``rimu export c``) beside the Python monitor.

Per configuration (cone6 windows, cone6 windows + CUSUM, tetrad windows), on the same
healthy manoeuvring flight (rates up to 300 °/s), in the same run, interleaved per repeat:

- C: ``rimu_monitor_step`` over N samples (float64 module, ``cc -std=c99 -O2``, one ctypes
  call for the block, nothing copied out), ns per step;
- kernel: the per-sample cost of ``Monitor.run``'s compiled numba kernel alone over the
  same N rows (``fdi.kernel.advance`` into an output written once; the anchor of issue 20:
  the C step must cost at most 1.5× it), and ``Monitor.run`` as a whole per sample;
- step: ``Monitor.step`` latency (median over ``--steps`` samples; target: the C step at
  most 1/10 of it);
- sizes: ``sizeof(rimu_state)``, the const tables and the code (``.text``) of the module's
  object for x86-64 (``cc -O2``) and, when ``arm-none-eabi-gcc`` is installed, for a
  Cortex-M4F (float32 module, ``-mcpu=cortex-m4 -mthumb -mfloat-abi=hard
  -mfpu=fpv4-sp-d16 -O2``).

Run: ``python benchmarks/bench_export_c.py [--block 1000000] [--steps 20000] [--repeat 5]``.
Writes ``benchmarks/results/export_c.json``.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from _common import RESULTS, header, spread, write_results
from bench_monitor import _kernel_alone, flight
from threadpoolctl import threadpool_limits

from fdi.export import generate_c, write_c
from fdi.export.host import STRICT_FLAGS, CMonitor, compile_module
from fdi.monitor import Monitor
from studies.synthetic import synthetic_calibration
from thresholds import compute_thresholds

ARM_FLAGS = ("-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-O2", "-mcpu=cortex-m4",
             "-mthumb", "-mfloat-abi=hard", "-mfpu=fpv4-sp-d16", "-ffunction-sections",
             "-fdata-sections")


def sections(obj: Path, size: str = "size") -> dict[str, int]:
    """Bytes of .text (code), .rodata (the const tables) and .data/.bss of an object."""
    out = subprocess.run([size, "-A", str(obj)], capture_output=True, text=True,
                         check=True).stdout
    sec: dict[str, int] = {"text": 0, "rodata": 0, "data": 0, "bss": 0}
    for line in out.splitlines():
        parts = line.split()
        if len(parts) >= 2 and parts[0].startswith(".") and parts[1].isdigit():
            name = parts[0]
            for k in sec:
                if name == f".{k}" or name.startswith(f".{k}."):
                    sec[k] += int(parts[1])
    return sec


def object_sizes(folder: Path, cc: str, flags: tuple[str, ...], size: str) -> dict[str, Any]:
    """Sections of the module compiled by ``cc`` (the compiler's first line on failure)."""
    obj = folder / f"rimu_monitor_{Path(cc).name}.o"
    p = subprocess.run([cc, *flags, "-c", str(folder / "rimu_monitor.c"), "-o", str(obj)],
                       capture_output=True, text=True)
    if p.returncode != 0:
        return {"error": (p.stderr.strip().splitlines() or ["?"])[0]}
    return sections(obj, size)


def step_latency(cal, th, t: np.ndarray, raw: np.ndarray, steps: int) -> float:
    """Median ``Monitor.step`` latency (ns) after 2000 warm-up samples."""
    mon = Monitor(cal, th)
    rows = list(raw)
    for i in range(2000):
        mon.step(float(t[i]), rows[i])
    pc = time.perf_counter_ns
    lat = np.empty(steps)
    for k in range(steps):
        i = 2000 + k
        ti, ri = float(t[i]), rows[i]
        a = pc()
        mon.step(ti, ri)
        lat[k] = pc() - a
    return float(np.median(lat))


def bench_case(cfg: str, det: str, N: int, steps: int, repeat: int, work: Path) -> dict:
    cal = synthetic_calibration(cfg, seed=1)
    th = compute_thresholds(cal, detector=det)
    folder = work / f"{cfg}_{det}"
    mod = generate_c(cal, th, harness=True)
    write_c(mod, folder)
    lib = compile_module(folder)
    cmon = CMonitor.load(folder, lib, [s.name for s in cal.gyro.sensors])
    t, raw = flight(cal, max(N, steps + 2000), seed=5)
    t, raw = t[:N], raw[:N]
    res = Monitor(cal, th).run(t, raw)
    c_ns, k_ns, s_ns, r_ns = [], [], [], []
    for _ in range(repeat):
        cmon.reset()
        a = time.perf_counter()
        cmon.steps(t, raw)
        c_ns.append((time.perf_counter() - a) / N * 1e9)
        k_ns.append(_kernel_alone(cal, th, t, raw) / N * 1e9)
        mon = Monitor(cal, th)
        a = time.perf_counter()
        mon.run(t, raw)
        r_ns.append((time.perf_counter() - a) / N * 1e9)
        s_ns.append(step_latency(cal, th, *flight(cal, steps + 2000, seed=7), steps))
    sizes = {"state_bytes": cmon.state_bytes, "table_bytes": cmon.table_bytes,
             "x86_64_O2": object_sizes(folder, "cc", STRICT_FLAGS, "size")}
    arm = shutil.which("arm-none-eabi-gcc")
    if arm:
        f32 = work / f"{cfg}_{det}_f32"
        write_c(generate_c(cal, th, precision="float32"), f32)
        sizes["cortex_m4f_float32_O2"] = object_sizes(f32, arm, ARM_FLAGS,
                                                      shutil.which("arm-none-eabi-size")
                                                      or "size")
        sizes["cortex_m4f_flags"] = " ".join(ARM_FLAGS)
    ck = [c / k for c, k in zip(c_ns, k_ns, strict=True)]
    cs = [c / s for c, s in zip(c_ns, s_ns, strict=True)]
    return {"configuration": cfg, "detector": det, "sensors": cal.gyro.n,
            "scales": len(th.scales), "samples": N, "events_on_this_flight": len(res.events),
            "c_step_ns": spread(c_ns), "numba_kernel_ns_per_sample": spread(k_ns),
            "monitor_run_ns_per_sample": spread(r_ns),
            "monitor_step_ns": spread(s_ns),
            "c_over_kernel": spread(ck), "target_c_over_kernel_max": 1.5,
            "c_over_step": spread(cs), "target_c_over_step_max": 0.1,
            "met": bool(np.median(ck) <= 1.5 and np.median(cs) <= 0.1),
            "ops_per_step_bound": mod.ops_per_step, "sizes": sizes}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--block", type=int, default=1_000_000)
    ap.add_argument("--steps", type=int, default=20_000)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--out", default=str(RESULTS / "export_c.json"))
    args = ap.parse_args()
    cc = subprocess.run(["cc", "--version"], capture_output=True, text=True).stdout
    results = header("export_c", blas_threads=1, block=args.block, steps=args.steps,
                     repeat=args.repeat, compiler=cc.splitlines()[0] if cc else None,
                     flags=" ".join(STRICT_FLAGS), cases=[])
    with tempfile.TemporaryDirectory() as tmp, threadpool_limits(limits=1):
        for cfg, det in (("cone6", "windows"), ("cone6", "both"), ("tetrad", "windows")):
            r = bench_case(cfg, det, args.block, args.steps, args.repeat, Path(tmp))
            results["cases"].append(r)
            c, k, s = r["c_step_ns"], r["numba_kernel_ns_per_sample"], r["monitor_step_ns"]
            rn = r["monitor_run_ns_per_sample"]
            ck, cs = r["c_over_kernel"], r["c_over_step"]
            x86 = r["sizes"]["x86_64_O2"]
            arm = r["sizes"].get("cortex_m4f_float32_O2")
            print(f"{cfg:7s} {det:8s} C {c['min']:.0f}/{c['median']:.0f}/{c['max']:.0f} ns/step;"
                  f" numba kernel {k['median']:.0f} ns/sample (C ×{ck['min']:.2f}/"
                  f"{ck['median']:.2f}/{ck['max']:.2f}, target ≤1.5); Monitor.run "
                  f"{rn['median']:.0f} ns/sample; Monitor.step "
                  f"{s['median'] / 1e3:.2f} µs (C ×{cs['median']:.3f}, target ≤0.1): "
                  f"{'met' if r['met'] else 'NOT met'}")
            armtxt = ("" if not arm else f"; Cortex-M4F float32: {arm['error']}" if "error" in arm
                      else f"; Cortex-M4F float32 code {arm['text']} B, rodata "
                           f"{arm['rodata']} B")
            print(f"{'':16s} state {r['sizes']['state_bytes']} B, tables "
                  f"{r['sizes']['table_bytes']} B; x86-64 code {x86['text']} B, rodata "
                  f"{x86['rodata']} B{armtxt}")
    write_results(results, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
