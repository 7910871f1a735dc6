"""Throughput of an evaluation campaign: serial, and Dask LocalClusters of 1 and 2 workers.

A campaign of N runs (default 1000) of 60-s simulated cone6 flights at 100 Hz, every fault
kind (``rimu evaluate``'s design). The same campaign runs serially in this process and on
LocalClusters of 1 and 2 single-threaded worker processes; each configuration is repeated
and reported as min / median / max wall time, as runs per second, and as a ratio to the
serial run of the same benchmark. Checks that every configuration gives the same
``evaluation.json`` numbers. Writes ``benchmarks/results/evaluate.json``.

Run: ``python benchmarks/bench_evaluate.py [--runs 1000] [--repeats 1]``
"""

from __future__ import annotations

import argparse
import json
import time

from _common import RESULTS, header, spread, write_results

from replay.threshold_choice import select
from studies.synthetic import synthetic_calibration
from thresholds.evaluate import design, execute, simulation_task, summarise


def _timed(fn, repeats: int) -> tuple[list[float], object]:
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return times, out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=1000)
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--out", default=str(RESULTS / "evaluate.json"))
    a = ap.parse_args()
    cal = synthetic_calibration("cone6")
    thr = select(cal, false_alarms_per_hour=10.0).thresholds
    specs = design(cal, thr, runs=a.runs, seed=0, duration_s=a.duration,
                   onset_s=a.duration / 2)
    task = simulation_task(cal, thr)
    configs = {"serial": dict(scheduler="serial"),
               "dask_local_1_worker": dict(scheduler="local", workers=1),
               "dask_local_2_workers": dict(scheduler="local", workers=2)}
    res: dict[str, dict] = {}
    ref = None
    for name, kw in configs.items():
        times, results = _timed(lambda kw=kw: execute(task, specs, batch=10, **kw), a.repeats)
        ev = json.dumps(summarise(results, thr, n_sensors=6), sort_keys=True)
        ref = ref or ev
        w = spread(times)
        res[name] = {"wall_s": w, "runs_per_s_median": a.runs / w["median"],
                     "identical_to_serial": ev == ref}
        print(f"{name:22s} {w['min']:7.1f} / {w['median']:7.1f} / {w['max']:7.1f} s "
              f"(min/median/max)  {a.runs / w['median']:6.1f} runs/s  "
              f"same numbers: {ev == ref}", flush=True)
    base = res["serial"]["wall_s"]["median"]
    for v in res.values():
        v["ratio_to_serial"] = v["wall_s"]["median"] / base
    doc = header("evaluate", runs=a.runs, flight_s=a.duration, repeats=a.repeats,
                 configuration="cone6, 100 Hz, every fault kind", results=res)
    print(f"under 10 minutes: {max(v['wall_s']['max'] for v in res.values()) < 600}")
    write_results(doc, a.out)


if __name__ == "__main__":
    main()
