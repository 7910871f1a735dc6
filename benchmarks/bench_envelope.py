"""Benchmark: the envelope tracker (fdi.envelope) on a two-IMU stream.

Ten minutes of a simulated two-IMU set at 200 Hz (six calibrated gyro axes, two
accelerometer triads), fed to :class:`fdi.envelope.EnvelopeTracker` whole and in blocks of
1, 10 and 100 samples, as the monitor does online. Prints samples per second and the time
per ``update`` call; min/median/max over the repeats. Writes
``benchmarks/results/envelope.json``.

Run: ``python benchmarks/bench_envelope.py [--repeats 5] [--duration 600]``
"""

from __future__ import annotations

import argparse

import numpy as np
from _common import header, print_results, timed, write_results

from fdi.envelope import EnvelopeTracker
from fdi.units import DPS, G0

FS = 200.0


def _stream(duration_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(0)
    n = int(duration_s * FS)
    t = np.arange(n) / FS
    w = np.column_stack([np.sin(0.7 * t), 0.5 * np.cos(0.3 * t), 0.2 * np.sin(t)])
    rates = np.hstack([w, w]) + rng.normal(0, 0.5 * DPS, (n, 6))
    acc = np.zeros((n, 2, 3))
    acc[:, :, 2] = G0
    acc += rng.normal(0, 0.5, acc.shape)
    return t, rates, acc


def _feed(t, rates, acc, block: int) -> None:
    tr = EnvelopeTracker(H=np.vstack([np.eye(3), np.eye(3)]), groups=[(0, 1, 2), (3, 4, 5)])
    for i in range(0, t.size, block):
        tr.update(t[i:i + block], rates[i:i + block], acc[i:i + block])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--duration", type=float, default=600.0)
    a = ap.parse_args()
    t, rates, acc = _stream(a.duration)
    res = header("envelope", samples=int(t.size), sample_rate_hz=FS, sensors=6)
    for block in (t.size, 100, 10, 1):
        reps = a.repeats if block >= 10 else 1
        n = t.size if block >= 10 else min(t.size, int(60 * FS))   # block 1: one minute
        s = timed(lambda b=block, n=n: _feed(t[:n], rates[:n], acc[:n], b), reps)
        name = "whole" if block == t.size else f"block_{block}"
        res[f"{name}_samples_per_s"] = n / s["median"]
        res[f"{name}_us_per_update"] = 1e6 * s["median"] / max(1, -(-n // block))
        res[f"{name}_s"] = s
    print_results(res)
    write_results(res)


if __name__ == "__main__":
    main()
