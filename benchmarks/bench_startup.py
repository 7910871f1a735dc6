"""Start-up cost of the CLI: ``rimu --version`` and ``rimu COMMAND --help`` as whole
processes, as ratios to a bare ``python -c pass`` measured in the same run.

Each case is a fresh process (``sys.executable -m rimu ...``, the project from this clone);
the cases are interleaved and repeated (``--repeat``), and the CPU time of each child
(user + system, from ``resource.getrusage(RUSAGE_CHILDREN)``) is the figure: the machine is
shared, so wall time is given for reference only. The ratio of a case is its median CPU
time over the median of the bare interpreter; issue 19 asks for at most 10.

Also, when erle flight 41 is found (``../shared/data`` or ``--log``): ``rimu ingest`` of it
against a bare pymavlink pass over its IMU messages (``recv_match`` of IMU/IMU2/IMU3,
touching ``TimeMS`` and ``GyrX``), both as whole processes; issue 19 asks for at most 1.6.

Usage: ``python benchmarks/bench_startup.py [--repeat 7] [--log FILE]``.
Writes ``benchmarks/results/startup.json``.
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _common import ROOT, header, spread, write_results

LIMIT = 10.0
"""Largest ratio to the bare interpreter that issue 19 allows."""
INGEST_LIMIT = 1.6
"""Largest ratio of ``rimu ingest`` to a bare pymavlink pass (whole processes)."""
FLIGHT41 = "erle_pxf_dual_imu/pxf_copter_22-12-2014_41.BIN"
BARE = """import sys
from pymavlink.DFReader import DFReader_binary
r = DFReader_binary(sys.argv[1])
while True:
    m = r.recv_match(type=["IMU", "IMU2", "IMU3"])
    if m is None:
        break
    m.TimeMS, m.GyrX
"""


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


def _ingest(log: Path, env: dict[str, str], repeat: int) -> dict:
    """``rimu ingest LOG`` against the bare pymavlink pass, CPU of whole processes."""
    tmp = Path(tempfile.mkdtemp(prefix="bench_startup_"))
    try:
        bare = ["-c", BARE, str(log)]
        cpu_b, cpu_i = [], []
        for k in range(repeat + 1):
            out = tmp / f"f{k}"
            b, _ = run_once(bare, env)
            i, _ = run_once(["-m", "rimu", "ingest", str(log), "--out", str(out)], env)
            shutil.rmtree(out, ignore_errors=True)
            if k:                                   # the first pair warms the caches
                cpu_b.append(b)
                cpu_i.append(i)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    sb, si = spread(cpu_b, "_cpu_s"), spread(cpu_i, "_cpu_s")
    ratio = si["median_cpu_s"] / sb["median_cpu_s"]
    print(f"ingest {log.name}: cpu {si['median_cpu_s']:.3f} s, bare pymavlink "
          f"{sb['median_cpu_s']:.3f} s: x{ratio:.2f} (limit x{INGEST_LIMIT:g})")
    return {"log": str(log), "bare_pymavlink": sb, "rimu_ingest": si, "ratio_cpu": ratio,
            "limit_ratio": INGEST_LIMIT, "holds": ratio <= INGEST_LIMIT}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeat", type=int, default=7)
    p.add_argument("--log", help="the ArduPilot log for the ingest comparison "
                                 "(default: erle flight 41 in ../shared/data)")
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
    log = Path(a.log) if a.log else Path(os.environ.get(
        "RIMU_SHARED_DATA", ROOT / ".." / "shared" / "data")) / FLIGHT41
    if log.exists():
        res["ingest"] = _ingest(log, env, a.repeat)
    else:
        print(f"ingest: {log} not found, skipped")
    worst = max((k for k in rows if k != "python -c pass"), key=lambda k: rows[k]["ratio_cpu"])
    res["worst"] = {"case": worst, "ratio_cpu": rows[worst]["ratio_cpu"]}
    res["holds"] = rows[worst]["ratio_cpu"] <= LIMIT
    print(f"worst: {worst} x{rows[worst]['ratio_cpu']:.1f} (limit x{LIMIT:g}): "
          + ("holds" if res["holds"] else "DOES NOT HOLD"))
    write_results(res)
    return 0


if __name__ == "__main__":
    sys.exit(main())
