"""Speed of the in-flight calibration and the flight diagnosis on a 10-min two-IMU flight.

A simulated two-IMU flight at 50 Hz (``replay.imu_set``, 5 ms offset, a g-sensitivity and
a vibration line) is written as a CSV log in rimu's column naming (``time_ms``,
``imu1_gyr_x_rps``, ``imu1_acc_x_mps2``, ...); the benchmark times, over repeats:
``rimu ingest`` of that log into a flight folder, loading the folder, the in-flight fit with
its calibration file (``calibrate in-flight``) and ``diagnose``; the total is compared
with the 30 s target. The fit's cost is also given as a ratio to a bare
``numpy.linalg.lstsq`` of the same size (3N × 13, one IMU pair), measured in the same run,
so that numbers from different machines compare. Writes ``benchmarks/results/inflight.json``.

Run: ``python benchmarks/bench_inflight.py [--minutes 10] [--repeats 3]``
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from _common import RESULTS, header, spread, write_results

from calibration.inflight.calfile import calibration_from_fit
from calibration.inflight.diagnose import diagnose_flight
from calibration.inflight.fit import fit_inflight
from fdi.units import DPS, G0
from replay.flight_io import load_flight_dir
from replay.imu_set import ImuEffects, ImuSetSpec, simulate_imu_set

TARGET_S = 30.0


def _stats(x: list[float]) -> dict[str, float]:
    return spread(x, "_s")


def _write_csv_log(flight, path: Path) -> None:
    """The flight as a CSV log in rimu's column naming (what ``rimu ingest`` reads)."""
    cols = ["time_ms"]
    data = [np.round(flight.t * 1e3, 3)]
    acc = flight.aux.select("accel")
    for j, g in enumerate(dict.fromkeys(flight.imu)):
        for k, ax in enumerate("xyz"):
            cols.append(f"{g}_gyr_{ax}_rps")
            data.append(flight.raw[:, 3 * j + k])
        for k, ax in enumerate("xyz"):
            cols.append(f"{g}_acc_{ax}_mps2")
            data.append(acc.values[:, 3 * j + k])
    np.savetxt(path, np.column_stack(data), delimiter=",", header=",".join(cols),
               comments="", fmt="%.9g")


def _ingest(log: Path, out: Path) -> None:
    import contextlib
    import io

    from rimu.commands import ingest

    p = argparse.ArgumentParser()
    ingest.configure(p)
    with contextlib.redirect_stdout(io.StringIO()):
        ingest.run(p.parse_args([str(log), "--out", str(out)]))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default=str(RESULTS / "inflight.json"))
    args = ap.parse_args()
    eff = ImuEffects(g_sensitivity=0.05 * DPS / G0, vibration_hz=73.0, vibration=0.1 * DPS,
                     imus=(2,))
    spec = ImuSetSpec(imus=2, duration_s=60 * args.minutes, sample_rate_hz=50.0, seed=1,
                      time_offset_s=(0.0, 0.005), effects=eff)
    flight = simulate_imu_set(spec)
    N = flight.t.shape[0]
    times: dict[str, list[float]] = {"ingest": [], "load": [], "calibrate": [],
                                     "diagnose": [], "total": [], "lstsq": []}
    rng = np.random.default_rng(0)
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp) / "flight"
        log = Path(tmp) / "flight.csv"
        _write_csv_log(flight, log)
        for _ in range(args.repeats):
            z = time.perf_counter()
            _ingest(log, d)
            a = time.perf_counter()
            f = load_flight_dir(d)
            b = time.perf_counter()
            fit = fit_inflight(f)
            cal = calibration_from_fit(fit, f)
            cal.save(Path(tmp) / "cal.json")
            c = time.perf_counter()
            doc = diagnose_flight(f, cal)
            e = time.perf_counter()
            X = rng.standard_normal((3 * N, 13))
            y = rng.standard_normal(3 * N)
            g = time.perf_counter()
            np.linalg.lstsq(X, y, rcond=None)
            h = time.perf_counter()
            for k, v in (("ingest", a - z), ("load", b - a), ("calibrate", c - b),
                         ("diagnose", e - c), ("total", e - z), ("lstsq", h - g)):
                times[k].append(v)
    res = {k: _stats(v) for k, v in times.items()}
    ratio = res["calibrate"]["median_s"] / res["lstsq"]["median_s"]
    a2 = fit.alignments["imu2"]
    out = header("inflight") | {
           "flight": {"imus": 2, "sample_rate_hz": 50.0, "samples": N,
                      "minutes": args.minutes},
           "repeats": args.repeats, "stages": res, "target_s": TARGET_S,
           "within_target": res["total"]["max_s"] < TARGET_S,
           "calibrate_over_lstsq": ratio,
           "check": {"time_offset_ms": 1e3 * a2.time_offset_s,
                     "time_offset_ms_sd": 1e3 * a2.time_offset_sd_s,
                     "effects": [x["name"] for x in doc["effects"]]}}
    for k in ("ingest", "load", "calibrate", "diagnose", "total"):
        s = res[k]
        print(f"{k:9s} min {s['min_s']:6.2f} s  median {s['median_s']:6.2f} s  "
              f"max {s['max_s']:6.2f} s")
    print(f"bare lstsq (3N x 13) median {res['lstsq']['median_s'] * 1e3:.1f} ms; calibrate "
          f"is {ratio:.0f}x that; total {res['total']['median_s']:.2f} s "
          f"(target < {TARGET_S:g} s: {'yes' if out['within_target'] else 'NO'})")
    print(f"check: time offset {out['check']['time_offset_ms']:.3f} ± "
          f"{out['check']['time_offset_ms_sd']:.3f} ms; effects {out['check']['effects']}")
    write_results(out, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
