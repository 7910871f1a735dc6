"""Ingest speed: ``rimu ingest`` of a real ArduPilot flight, as a ratio to pymavlink's
bare read of the same file.

Timed, interleaved and repeated (min / median / max over ``--repeat``; the machine is
shared, so CPU time of the process is the figure, wall time is given for reference):

- ``bare``: ``DFReader_binary(path)`` then ``recv_match(type=["IMU", "IMU2", "IMU3"])``
  until ``None``, touching ``TimeMS`` and ``GyrX`` of every message — the least any reader
  built on pymavlink does;
- ``read``: :func:`replay.ingest.ardupilot.read_ardupilot` (the above plus the damage check
  from pymavlink's index and the column arrays);
- ``ingest``: read + :func:`replay.ingest.align_streams` + ``save_flight_dir`` + the
  report: what ``rimu ingest`` does apart from printing.

The log is erle flight 41 (ArduCopter, IMU + IMU2 at 50 Hz, 6,944 pairs, 1.9 MB) from
``../shared/data`` (or ``--log``). Also timed: the ingest of a written 10 min two-IMU
50 Hz DataFlash log (30,000 pairs; the size of the issue's end-to-end budget of 30 s for
ingest + in-flight calibration + diagnose), through ``rimu ingest`` itself.

Usage: ``python benchmarks/bench_ingest.py [--repeat 5] [--log FILE] [--minutes 10]``.
Writes ``benchmarks/results/ingest.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

from _common import ROOT, header, spread, write_results

from replay.flight_io import save_flight_dir
from replay.ingest import align_streams
from replay.ingest.ardupilot import read_ardupilot

DATA = Path(os.environ.get("RIMU_SHARED_DATA", ROOT / ".." / "shared" / "data"))
LOG = DATA / "erle_pxf_dual_imu" / "pxf_copter_22-12-2014_41.BIN"


def _timed(fn):
    c0, w0 = time.process_time(), time.perf_counter()
    out = fn()
    return time.process_time() - c0, time.perf_counter() - w0, out


def bare(path: Path) -> int:
    """pymavlink alone: index the file, visit every IMU message."""
    from pymavlink import DFReader

    r = DFReader.DFReader_binary(str(path))
    n = 0
    while True:
        m = r.recv_match(type=["IMU", "IMU2", "IMU3"])
        if m is None:
            return n
        _ = (m.TimeMS if "TimeMS" in m.fmt.columns else m.TimeUS, m.GyrX)
        n += 1


def ingest(path: Path, out: Path) -> int:
    """What ``rimu ingest`` does: read, align, write the folder and the report."""
    read = read_ardupilot(path)
    flight, report = align_streams(read)
    save_flight_dir(flight, out)
    (out / "ingest_report.json").write_text(json.dumps(report, default=str))
    return int(flight.t.shape[0])


def written_log(minutes: float, repeat: int) -> dict:
    """``rimu ingest`` of a written two-IMU 50 Hz DataFlash log of ``minutes``."""
    sys.path.insert(0, str(ROOT / "tests" / "replay" / "ingest"))
    from ingest_helpers import small_imu_data, write_dataflash

    from rimu.cli import main as rimu

    n = int(minutes * 60 * 50)
    t, g, a = small_imu_data(n=n, k=2)
    walls = []
    with tempfile.TemporaryDirectory() as tmp:
        log = Path(tmp) / "ten.BIN"
        write_dataflash(log, t, g, a)
        for _ in range(repeat):
            w0 = time.perf_counter()
            rc = rimu(["ingest", str(log), "--out", str(Path(tmp) / "f")])
            walls.append(time.perf_counter() - w0)
            if rc != 0:
                raise SystemExit(f"rimu ingest failed ({rc})")
        size = log.stat().st_size
    print(f"written {minutes:g} min two-IMU 50 Hz log ({n} pairs, {size / 1e6:.1f} MB): "
          f"rimu ingest {min(walls):.2f} s wall (best of {repeat})")
    return {"minutes": minutes, "pairs": n, "bytes": size, "wall_s": _stats(walls)}


def _stats(xs: list[float]) -> dict[str, float]:
    return spread(xs)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeat", type=int, default=5)
    p.add_argument("--log", type=Path, default=LOG)
    p.add_argument("--minutes", type=float, default=10.0,
                   help="length of the written two-IMU 50 Hz log (default 10)")
    args = p.parse_args(argv)
    if not args.log.is_file():
        print(f"no log at {args.log}: give --log or RIMU_SHARED_DATA", file=sys.stderr)
        return 2
    runs: dict[str, dict[str, list[float]]] = {k: {"cpu": [], "wall": []}
                                               for k in ("bare", "read", "ingest")}
    counts = {}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(args.repeat):
            for name, fn in (("bare", lambda: bare(args.log)),
                             ("read", lambda: read_ardupilot(args.log)),
                             ("ingest", lambda: ingest(args.log, Path(tmp) / "f"))):
                c, w, out = _timed(fn)
                runs[name]["cpu"].append(c)
                runs[name]["wall"].append(w)
                counts[name] = out if isinstance(out, int) else sum(s.size for s in out.streams)
            print(f"run {r + 1}: cpu (wall) s: bare {runs['bare']['cpu'][-1]:.3f} "
                  f"({runs['bare']['wall'][-1]:.3f}), read {runs['read']['cpu'][-1]:.3f} "
                  f"({runs['read']['wall'][-1]:.3f}), ingest {runs['ingest']['cpu'][-1]:.3f} "
                  f"({runs['ingest']['wall'][-1]:.3f})")
    res = header("ingest") | {
        "log": str(args.log), "log_bytes": args.log.stat().st_size, "imu_messages": counts["bare"],
        "flight_samples": counts["ingest"], "repeat": args.repeat,
        "seconds": {k: {"cpu": _stats(v["cpu"]), "wall": _stats(v["wall"])}
                    for k, v in runs.items()},
        "ratio_read_to_bare_cpu": min(runs["read"]["cpu"]) / min(runs["bare"]["cpu"]),
        "ratio_ingest_to_bare_cpu": min(runs["ingest"]["cpu"]) / min(runs["bare"]["cpu"]),
        "ratio_ingest_to_bare_wall": (min(runs["ingest"]["wall"])
                                      / min(runs["bare"]["wall"])),
        "runs": runs,
    }
    res["written_log"] = written_log(args.minutes, max(1, args.repeat // 2))
    print(f"{counts['bare']} IMU messages; read {res['ratio_read_to_bare_cpu']:.2f}x bare, "
          f"ingest {res['ratio_ingest_to_bare_cpu']:.2f}x bare (cpu, best of "
          f"{args.repeat}; wall {res['ratio_ingest_to_bare_wall']:.2f}x)")
    write_results(res)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
