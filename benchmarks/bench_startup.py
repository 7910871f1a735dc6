"""Start-up cost of the CLI: ``rimu --version`` and ``rimu COMMAND --help`` as whole
processes, as ratios to a bare ``python -c pass`` measured in the same run.

Each case is a fresh process (``sys.executable -m rimu ...``, the project from this clone);
the cases are interleaved and repeated (``--repeat``), and the CPU time of each child
(user + system, from ``resource.getrusage(RUSAGE_CHILDREN)``) is the figure: the machine is
shared, so wall time is given for reference only. The ratio of a case is its median CPU
time over the median of the bare interpreter; issue 19 asks for at most 10.

Usage: ``python benchmarks/bench_startup.py [--repeat 7]``.
Writes ``benchmarks/results/startup.json``.
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import time

from _common import ROOT, header, spread, write_results

LIMIT = 10.0
"""Largest ratio to the bare interpreter that issue 19 allows."""


def cases() -> dict[str, list[str]]:
    """Name → argv of every process timed (the bare interpreter first)."""
    from rimu.cli import COMMANDS, SIMULATE

    out = {"python -c pass": ["-c", "pass"], "rimu --version": ["-m", "rimu", "--version"]}
    for c in COMMANDS:
        out[f"rimu {c} --help"] = ["-m", "rimu", c, "--help"]
    for c in SIMULATE:
        out[f"rimu simulate {c} --help"] = ["-m", "rimu", "simulate", c, "--help"]
    return out


def run_once(argv: list[str], env: dict[str, str]) -> tuple[float, float]:
    """(CPU s, wall s) of one child process."""
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run([sys.executable, *argv], env=env, check=True, stdout=subprocess.DEVNULL,
                   stderr=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime), wall


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeat", type=int, default=7)
    a = p.parse_args(argv)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    todo = cases()
    cpu: dict[str, list[float]] = {k: [] for k in todo}
    wall: dict[str, list[float]] = {k: [] for k in todo}
    for v in todo.values():                         # warm the file cache once
        run_once(v, env)
    for _ in range(a.repeat):
        for k, v in todo.items():                   # interleaved: load changes hit all alike
            c, w = run_once(v, env)
            cpu[k].append(c)
            wall[k].append(w)
    res = header("startup", repeat=a.repeat, python=sys.executable, limit_ratio=LIMIT)
    base = spread(cpu["python -c pass"])["median"]
    base_w = spread(wall["python -c pass"])["median"]
    rows = {}
    for k in todo:
        c, w = spread(cpu[k], "_cpu_s"), spread(wall[k], "_wall_s")
        rows[k] = {**c, **w, "ratio_cpu": c["median_cpu_s"] / base,
                   "ratio_wall": w["median_wall_s"] / base_w}
        print(f"{k:34s} cpu {1e3 * c['median_cpu_s']:7.1f} ms  x{rows[k]['ratio_cpu']:5.1f}"
              f"   wall {1e3 * w['median_wall_s']:7.1f} ms  x{rows[k]['ratio_wall']:5.1f}")
    res["cases"] = rows
    worst = max((k for k in rows if k != "python -c pass"), key=lambda k: rows[k]["ratio_cpu"])
    res["worst"] = {"case": worst, "ratio_cpu": rows[worst]["ratio_cpu"]}
    res["holds"] = rows[worst]["ratio_cpu"] <= LIMIT
    print(f"worst: {worst} x{rows[worst]['ratio_cpu']:.1f} (limit x{LIMIT:g}): "
          + ("holds" if res["holds"] else "DOES NOT HOLD"))
    write_results(res)
    return 0


if __name__ == "__main__":
    sys.exit(main())
