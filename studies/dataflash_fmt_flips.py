"""What one flipped byte inside a DataFlash FMT definition costs (issue 30).

The FMT records (type 128, 89 bytes each) of a real ArduPilot ``.BIN`` are located; one
byte of one of them is XORed with a seeded random non-zero value and the log is read again
with ``read_ardupilot(..., salvage=True)``. A pristine IMU sample (stream, time, gyro x, y,
z) not read back is lost; a refused log loses every sample. Besides the loss, the study
counts the flips that were said (a damage record or a warning) and those that altered
samples silently.

Run: ``python -m studies.dataflash_fmt_flips LOG.BIN [--flips 200] [--seed 1]``
"""

from __future__ import annotations

import argparse
import json
import tempfile
from collections import Counter
from pathlib import Path

import numpy as np

from fdi.errors import RimuError
from replay.ingest.ardupilot import read_ardupilot

FMT_HEAD = b"\xa3\x95\x80"
FMT_LEN = 89


def fmt_records(data: bytes) -> list[int]:
    """Start of every FMT record of a pristine log (sync bytes, id 128, a printable
    upper-case name)."""
    out, k = [], data.find(FMT_HEAD)
    while k >= 0:
        name = data[k + 5 : k + 9].rstrip(b"\0")
        if name and name.isalnum() and name.upper() == name:
            out.append(k)
        k = data.find(FMT_HEAD, k + 1)
    return out


def samples(path: Path) -> tuple[Counter, bool, int]:
    """(IMU samples, whether the flip was said, streams) of a log; a refusal reads none."""
    try:
        read = read_ardupilot(path, salvage=True)
    except RimuError:
        return Counter(), True, 0
    c = Counter()
    for s in read.streams:
        for t, g in zip(s.t, s.gyro, strict=True):
            c[(s.source, round(float(t), 6), *np.round(g, 7))] += 1
    said = read.damage is not None or bool(read.meta.get("warnings"))
    return c, said, len(read.streams)


def run(log: Path, flips: int, seed: int) -> dict:
    data = log.read_bytes()
    truth, _, n_streams = samples(log)
    recs = fmt_records(data)
    pos = np.concatenate([np.arange(k, k + FMT_LEN) for k in recs])
    rng = np.random.default_rng(seed)
    lost, silent, refused = [], 0, 0
    with tempfile.TemporaryDirectory() as tmp:
        q = Path(tmp) / "flip.BIN"
        for p in rng.choice(pos, size=flips, replace=True):
            bad = bytearray(data)
            bad[p] ^= int(rng.integers(1, 256))
            q.write_bytes(bytes(bad))
            got, said, n = samples(q)
            refused += n == 0
            n_lost = sum((truth - got).values())
            lost.append(n_lost)
            if (n_lost or got != truth) and not said:
                silent += 1
    lost_a = np.array(lost)
    total = sum(truth.values())
    return {
        "log": log.name,
        "flips": flips,
        "seed": seed,
        "fmt_records": len(recs),
        "imu_samples": total,
        "imu_streams": n_streams,
        "flips_losing_nothing": int((lost_a == 0).sum()),
        "lost_median": float(np.median(lost_a)),
        "lost_p95": float(np.percentile(lost_a, 95)),
        "lost_max": int(lost_a.max()),
        "lost_fraction_max": float(lost_a.max() / total),
        "refused": int(refused),
        "changed_without_a_word": int(silent),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log", type=Path)
    ap.add_argument("--flips", type=int, default=200)
    ap.add_argument("--seed", type=int, default=1)
    a = ap.parse_args()
    print(json.dumps(run(a.log, a.flips, a.seed), indent=1))


if __name__ == "__main__":
    main()
