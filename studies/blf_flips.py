"""What one flipped byte costs in a BLF log read by :class:`replay.blf.ResyncBLFReader`.

A simulated flight (``rimu simulate flight``, cone6 synthetic calibration, python-can's
BLF writer with its default 128 KiB containers) is written compressed (zlib, python-can's
default level) and uncompressed (``compression_level=0``). One byte at a time is XORed
with a seeded random non-zero value, at seeded random positions of each kind of byte
(file and container headers, object bytes of the uncompressed file, compressed bytes),
and the file is read again (a damaged compressed byte is searched for and repaired when
one byte value makes the zlib stream whole, :mod:`replay.blf_repair`). A frame is *lost*
when the pristine (timestamp, id, data) is not read back; a frame read that is not in the
pristine file is *altered* (left to the frame CRC and counters downstream). Losses are
given as a fraction of the frames one container holds; how many flips were repaired and
the seconds the reader spent in its repair search (locating and trying; the pristine
file's whole read takes ``read_s``) are given too.

Run: ``python -m studies.blf_flips [--flips 200] [--duration 30] [--out studies/blf_flips.json]``
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import struct
import tempfile
import time
from collections import Counter
from pathlib import Path
from typing import Any

import can
import numpy as np

from replay.blf import ResyncBLFReader

CONTAINER_BYTES = can.BLFWriter.max_container_size


class _TimedReader(ResyncBLFReader):
    """The reader, with the seconds spent in its repair search added up."""

    search_s = 0.0

    def _repair(self, *args: Any, **kwargs: Any) -> Any:
        t0 = time.perf_counter()
        try:
            return super()._repair(*args, **kwargs)
        finally:
            self.search_s += time.perf_counter() - t0


def _frames(path: Path) -> tuple[Counter, int, bool, float]:
    """(frames as (time after the file's start time, id, data), damage records, whether
    a damaged byte was repaired, seconds spent in the repair search): a damaged start
    time in the file header shifts every frame, it does not lose one."""
    r = _TimedReader(path)
    c = Counter(
        (round(m.timestamp - r.start_timestamp, 4), m.arbitration_id, bytes(m.data)) for m in r
    )
    repaired = any(d["kind"] == "repaired" for d in r.damage)
    return c, r.n_damage, repaired, r.search_s


def write_logs(d: Path, duration_s: float, seed: int) -> tuple[Path, Path, int]:
    """(compressed BLF, uncompressed BLF, object size in bytes) of a simulated flight."""
    from rimu.cli import main
    from studies.synthetic import synthetic_calibration

    cal = synthetic_calibration("cone6", seed=3, raw_unit="LSB")
    cal.save(d / "cal.json")
    comp = d / "flight.blf"
    with contextlib.redirect_stdout(io.StringIO()):
        code = main(
            [
                "simulate",
                "flight",
                "--cal",
                str(d / "cal.json"),
                "--duration",
                str(duration_s),
                "--seed",
                str(seed),
                "--out",
                str(comp),
            ]
        )
    if code != 0:
        raise SystemExit("simulate flight failed")
    plain = d / "plain.blf"
    with can.BLFReader(str(comp)) as r, can.BLFWriter(str(plain), compression_level=0) as w:
        for m in r:
            w.on_message_received(m)
    return comp, plain, 48


def _containers(raw: bytes) -> list[tuple[int, int]]:
    """(start, size) of each container of a pristine file."""
    out = []
    pos = struct.unpack_from("<L", raw, 4)[0]
    while pos + 16 <= len(raw):
        size = struct.unpack_from("<L", raw, pos + 8)[0]
        out.append((pos, size))
        pos += size + size % 4
    return out


def positions(raw: bytes) -> dict[str, np.ndarray]:
    """Byte positions of each kind: header (file and container headers), body (inside
    containers)."""
    head = list(range(struct.unpack_from("<L", raw, 4)[0]))
    body = []
    for pos, size in _containers(raw):
        head += range(pos, pos + 32)
        body += range(pos + 32, pos + size)
    return {"header": np.array(head), "body": np.array(body)}


def run(flips: int, duration_s: float, seed: int) -> dict:
    rng = np.random.default_rng(seed)
    out: dict = {"flips_per_kind": flips, "duration_s": duration_s, "seed": seed}
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        comp, plain, obj = write_logs(d, duration_s, seed)
        per_container = CONTAINER_BYTES / obj
        out["frames_per_container"] = per_container
        for name, path, body_kind in (
            ("compressed", comp, "compressed"),
            ("uncompressed", plain, "object"),
        ):
            raw = path.read_bytes()
            t0 = time.perf_counter()
            truth, nd, _, _ = _frames(path)
            t_read = time.perf_counter() - t0
            if nd:
                raise SystemExit(f"pristine {name} file has damage records")
            out[name] = {
                "frames": sum(truth.values()),
                "bytes": len(raw),
                "containers": len(_containers(raw)),
                "read_s": t_read,
            }
            for kind, pos in positions(raw).items():
                label = "header" if kind == "header" else body_kind
                lost, altered, silent, worst = [], [], 0, {}
                repaired, seconds = [], []
                for p in rng.choice(pos, size=flips, replace=True):
                    bad = bytearray(raw)
                    x = int(rng.integers(1, 256))
                    bad[p] ^= x
                    q = d / "bad.blf"
                    q.write_bytes(bytes(bad))
                    got, ndam, fixed, dt = _frames(q)
                    repaired.append(fixed)
                    seconds.append(dt)
                    n_lost = sum((truth - got).values())
                    if not lost or n_lost > max(lost):
                        worst = {"byte": int(p), "xor": x, "lost_frames": int(n_lost)}
                    lost.append(n_lost)
                    altered.append(sum((got - truth).values()))
                    if n_lost > altered[-1] and ndam == 0:
                        silent += 1
                frac = np.array(lost) / per_container
                out[name][label] = {
                    "n": flips,
                    "lost_fraction_median": float(np.median(frac)),
                    "lost_fraction_p95": float(np.percentile(frac, 95)),
                    "lost_fraction_max": float(frac.max()),
                    "lost_frames_max": int(max(lost)),
                    "over_2pct": int((frac > 0.02).sum()),
                    "altered_frames_max": int(max(altered)),
                    "dropped_without_damage_record": int(silent),
                    "worst": worst,
                    "repaired": int(sum(repaired)),
                    "search_s_median": float(np.median(seconds)),
                    "search_s_max": float(max(seconds)),
                    "search_s_median_repaired": (
                        float(np.median([t for t, f in zip(seconds, repaired, strict=True) if f]))
                        if any(repaired)
                        else None
                    ),
                    "search_s_max_repaired": (
                        float(max(t for t, f in zip(seconds, repaired, strict=True) if f))
                        if any(repaired)
                        else None
                    ),
                }
                print(name, label, json.dumps(out[name][label]), flush=True)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--flips", type=int, default=200)
    ap.add_argument("--duration", type=float, default=30.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args()
    res = run(a.flips, a.duration, a.seed)
    if a.out:
        a.out.write_text(json.dumps(res, indent=1) + "\n")


if __name__ == "__main__":
    main()
