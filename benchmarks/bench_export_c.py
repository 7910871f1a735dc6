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

On the target (``--target``, or ``--target-only``; needs ``arm-none-eabi-gcc``, newlib and
``qemu-system-arm``, :mod:`fdi.export.target`): per configuration (cone6 windows, cone6
windows + CUSUM, tetrad, four triads of 12 sensors, a 16-sensor array, float32; cone6
float64), a 2000-sample 300 °/s flight with a step fault from the middle run under QEMU's
Cortex-M4F (mps2-an386, ``-icount shift=0``): instructions per ``rimu_monitor_step``
(mean and worst, 40-instruction resolution), the program's stack high-water (its ``main``
holds the ``rimu_answer``), ``sizeof(rimu_answer)`` and ``sizeof(rimu_state)`` (RAM), and
the module's flash (``.text`` + ``.rodata`` of its Cortex-M4F object); the answers checked
bit-identical to the host build.

Run: ``python benchmarks/bench_export_c.py [--block 1000000] [--steps 20000] [--repeat 5]
[--target | --target-only]``. Writes ``benchmarks/results/export_c.json`` (or
``export_c_target.json`` with ``--target-only``).
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


def _config(name: str, tmp: Path):
    """cone6 / tetrad, or four triads (12 sensors, IMUs 1° apart) and a 16-sensor array
    (single axes on a spiral) as configuration files."""
    import math
    import warnings

    if name in ("cone6", "tetrad"):
        return synthetic_calibration(name, seed=1)
    lines = ['schema = "rimu.configuration/1"', f'name = "{name}"']
    if name == "triads4":
        rng = np.random.default_rng(0)
        for j in range(4):
            ax = rng.standard_normal(3)
            ax /= np.linalg.norm(ax)
            a = math.radians(1.0) * (j > 0)
            K = np.array([[0, -ax[2], ax[1]], [ax[2], 0, -ax[0]], [-ax[1], ax[0], 0]])
            R = np.eye(3) + math.sin(a) * K + (1 - math.cos(a)) * K @ K
            for k, axis in enumerate(R.T):
                x, y, z = (float(v) for v in axis)
                lines += ["[[sensors]]", f'name = "imu{j + 1}.{"xyz"[k]}"',
                          f"axis = [{x!r}, {y!r}, {z!r}]"]
    else:
        for k in range(16):
            z = 1 - 2 * (k + 0.5) / 16
            r, phi = math.sqrt(1 - z * z), k * math.pi * (3 - math.sqrt(5))
            lines += ["[[sensors]]", f'name = "g{k + 1}"',
                      f"axis = [{r * math.cos(phi)!r}, {r * math.sin(phi)!r}, {z!r}]"]
    p = tmp / f"{name}.toml"
    p.write_text("\n".join(lines) + "\n")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return synthetic_calibration(str(p), seed=1, misalignment_rad=0.0)


TARGET_CASES = (("cone6", "windows", "float32"), ("cone6", "both", "float32"),
                ("tetrad", "windows", "float32"), ("triads4", "windows", "float32"),
                ("array16", "windows", "float32"), ("cone6", "windows", "float64"))


def bench_target(cfg: str, det: str, precision: str, N: int, tmp: Path) -> dict:
    """One configuration on the Cortex-M4F under QEMU (module docstring)."""
    from fdi.export.target import build_target, run_target

    cal = _config(cfg, tmp)
    th = compute_thresholds(cal, detector=det)
    t, raw = flight(cal, N, seed=3)
    sd = float(cal.gyro.noise_sd[0]) / float(cal.gyro.scale_factors[0])
    raw[N // 2:, 1] += 25 * sd                          # a step on sensor 2
    mod = generate_c(cal, th, precision=precision, harness=True)
    folder = tmp / f"target_{cfg}_{det}_{precision}"
    write_c(mod, folder)
    names = [s.name for s in cal.gyro.sensors]
    host = CMonitor.load(folder, compile_module(folder), names)
    h = host.run(t, raw)
    run = run_target(build_target(folder, t, raw), names, float32=precision == "float32",
                     parity_len=host.P, K=host.K)
    same = all(np.array_equal(np.ascontiguousarray(getattr(h, f), float).view(np.uint64),
                              np.ascontiguousarray(getattr(run.result, f), float)
                              .view(np.uint64))
               for f in ("omega", "omega_sd", "parity", "statistics", "thresholds",
                         "protection_level"))
    same &= [(e.t, e.type, e.sensor, e.reason) for e in h.events] == \
        [(e.t, e.type, e.sensor, e.reason) for e in run.result.events]
    sec = sections(folder / "rimu_monitor.arm.o", shutil.which("arm-none-eabi-size") or "size")
    return {"configuration": cfg, "detector": det, "precision": precision,
            "sensors": cal.gyro.n, "sets_carried": mod.sets, "depth": mod.depth,
            "samples": N, "events": len(h.events),
            "instructions_per_step_mean": round(run.instructions_mean, 1),
            "instructions_per_step_worst": run.instructions_worst,
            "stack_high_water_bytes": run.stack_bytes, "answer_bytes": run.answer_bytes,
            "state_bytes": run.state_bytes, "flash_text_bytes": sec["text"],
            "flash_rodata_bytes": sec["rodata"],
            "flash_bytes": sec["text"] + sec["rodata"],
            "ram_bytes": run.state_bytes + run.stack_bytes,
            "bit_identical_to_host": bool(same), "table_crc_ok": run.crc_ok}


def run_targets(N: int, tmp: Path) -> list[dict]:
    from fdi.export.target import ARM_FLAGS as TARGET_FLAGS
    from fdi.export.target import find_toolchain

    why = find_toolchain()
    if why:
        print(f"target: skipped ({why})")
        return []
    out = []
    print(f"Cortex-M4F under QEMU mps2-an386 ({' '.join(TARGET_FLAGS)}):")
    for cfg, det, prec in TARGET_CASES:
        r = bench_target(cfg, det, prec, N, tmp)
        out.append(r)
        print(f"  {cfg:8s} {det:8s} {prec}: {r['sensors']} sensors, {r['sets_carried']} sets; "
              f"{r['instructions_per_step_mean']:.0f} instructions/step mean, "
              f"{r['instructions_per_step_worst']:.0f} worst; stack {r['stack_high_water_bytes']}"
              f" B (answer {r['answer_bytes']} B), state {r['state_bytes']} B; flash "
              f"{r['flash_bytes']} B (code {r['flash_text_bytes']}, tables "
              f"{r['flash_rodata_bytes']}); bit-identical to the host: "
              f"{r['bit_identical_to_host']}")
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--block", type=int, default=1_000_000)
    ap.add_argument("--steps", type=int, default=20_000)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--out", default=None)
    ap.add_argument("--target", action="store_true", help="also run on the Cortex-M4F (QEMU)")
    ap.add_argument("--target-only", action="store_true", help="only the Cortex-M4F part")
    ap.add_argument("--target-samples", type=int, default=2000)
    args = ap.parse_args()
    if args.target_only:
        results = header("export_c_target", samples=args.target_samples, cases=[])
        with tempfile.TemporaryDirectory() as tmp:
            results["target"] = run_targets(args.target_samples, Path(tmp))
        write_results(results, args.out or str(RESULTS / "export_c_target.json"))
        return 0
    args.out = args.out or str(RESULTS / "export_c.json")
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
        if args.target:
            results["target"] = run_targets(args.target_samples, Path(tmp))
    write_results(results, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
