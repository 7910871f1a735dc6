"""What every benchmark script writes beside its figures: the machine, the load, the spread of
repeated timings and the JSON file.

The scripts in ``benchmarks/`` are run as programs (``python benchmarks/bench_x.py``), so this
module is imported as ``_common`` from the scripts' own folder.
"""

from __future__ import annotations

import json
import os
import platform
import sys
import time
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["RESULTS", "ROOT", "header", "load_average", "machine", "print_results",
           "spread", "timed", "timings", "write_results"]

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
SCHEMA = "rimu.benchmark/2"

if str(ROOT) not in sys.path:                   # the scripts import the project from the clone
    sys.path.insert(0, str(ROOT))


def machine(**extra: Any) -> dict[str, Any]:
    """Python, numpy, processor, platform and CPU count, plus ``extra`` (library versions)."""
    return {"python": platform.python_version(), "numpy": np.__version__,
            "processor": platform.processor() or platform.machine(),
            "platform": platform.platform(), "cpus": os.cpu_count(), **extra}


def load_average() -> list[float]:
    """The 1, 5 and 15 minute load averages (the machine is shared: read figures with it)."""
    return [float(x) for x in os.getloadavg()]


def spread(x: Iterable[float], suffix: str = "") -> dict[str, float]:
    """min / median / max of repeated figures, keys ``min``, ``median``, ``max`` + suffix."""
    a = np.asarray(list(x), float)
    return {"min" + suffix: float(a.min()), "median" + suffix: float(np.median(a)),
            "max" + suffix: float(a.max())}


def timings(fn: Any, repeats: int) -> list[float]:
    """Wall times (s) of ``repeats`` calls of ``fn()`` after one warm-up call."""
    fn()
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return ts


def timed(fn: Any, repeats: int) -> dict[str, float]:
    """min / median / max wall time (s) of ``repeats`` calls after one warm-up."""
    return spread(timings(fn, repeats))


def header(benchmark: str, **extra: Any) -> dict[str, Any]:
    """The opening fields of a results file: schema, benchmark name, UTC date, load average
    at the start, machine; ``extra`` fields follow."""
    return {"schema": SCHEMA, "benchmark": benchmark,
            "date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            "load_average": load_average(), "machine": machine(), **extra}


_HEADER_KEYS = ("schema", "benchmark", "date_utc", "load_average", "machine")


def print_results(results: dict[str, Any]) -> None:
    """Print every figure of ``results`` but the header's, one ``key: value`` a line."""
    for key, v in results.items():
        if key not in _HEADER_KEYS:
            print(f"{key}: {v}")


def write_results(results: dict[str, Any], path: str | Path | None = None) -> Path:
    """Write ``results`` as indented JSON (default ``benchmarks/results/<benchmark>.json``),
    with the load average at the end of the run; prints and returns the path."""
    out = Path(path) if path is not None else RESULTS / f"{results['benchmark']}.json"
    results["load_average_end"] = load_average()
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(results, indent=1, default=str) + "\n", encoding="utf-8")
    la = results["load_average_end"]
    print(f"load average {la[0]:.2f} {la[1]:.2f} {la[2]:.2f}; wrote {out}")
    return out
