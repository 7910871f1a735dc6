"""Recompute the timing-jitter section of docs/noise-tails.md (writes timing_jitter.json).

Per erle flight (41; 83 read with salvage): the fitted timing jitter of imu2, the excess
kurtosis and GPD shape of the normalised single-sample statistic, the detectable sizes
``rimu tune`` states at 1, 100 and 1000 false alarms per hour and the held-out alarm counts
(:func:`studies.tails_holdout.flight_holdout`, split in time, both ways), each before
(no jitter term, tails of the bare statistic) and after (jitter term, tails relative to the
monitor's inflation). Reads the recordings in place from ``../shared/data``. Run from the
repository root::

    python studies/make_timing_jitter.py
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests" / "calibration"))

from _erle import FLIGHTS, SHARED, read_erle  # noqa: E402

from calibration.inflight.calfile import calibration_from_fit  # noqa: E402
from calibration.inflight.fit import fit_inflight  # noqa: E402
from fdi.fileio import to_jsonable  # noqa: E402
from studies.tails_holdout import flight_holdout  # noqa: E402
from thresholds.tune import detectable_sizes, tune  # noqa: E402

TARGETS = (1.0, 100.0, 1000.0)


def whole_flight(flight, jitter: bool) -> dict:
    """Fit on the whole flight: τ, the tail summary at w = 1, tune's detectable sizes."""
    fit = fit_inflight(flight)
    a = fit.alignments["imu2"]
    cal = calibration_from_fit(fit, flight, jitter=jitter)
    r1 = cal.gyro.tails.scales[0]
    sizes = {}
    for R in TARGETS:
        thr = tune(cal, false_alarms_per_hour=R).thresholds
        d = detectable_sizes(cal, thr, draws=500)
        best = min(d, key=lambda x: x.size_unit_value)
        sizes[str(R)] = {"scale1_dps": d[0].size_unit_value, "best_dps": best.size_unit_value,
                         "best_scale": best.scale}
    return {"timing_jitter_ms": a.timing_jitter_s * 1e3,
            "timing_jitter_ms_sd": a.timing_jitter_sd_s * 1e3,
            "excess_kurtosis_w1": r1.excess_kurtosis,
            "gpd_shape_w1": None if r1.gpd is None else r1.gpd.shape,
            "gpd_shape_sd_w1": None if r1.gpd is None else r1.gpd.shape_sd,
            "tails": [{"scale": s.scale, "excess_kurtosis": s.excess_kurtosis,
                       "gpd_shape": None if s.gpd is None else s.gpd.shape}
                      for s in cal.gyro.tails.scales],
            "detectable": sizes}


def main() -> None:
    if not (SHARED / "erle_pxf_dual_imu").is_dir():
        raise SystemExit(f"no data at {SHARED}")
    out = {}
    for name in ("41", "83"):
        flight = read_erle(name)
        rec = {"file": FLIGHTS[name]}
        for label, jit in (("before", False), ("after", True)):
            rec[label] = whole_flight(flight, jit)
            rec[label]["holdout"] = flight_holdout(flight, targets=TARGETS, jitter=jit)
            print(name, label, json.dumps(to_jsonable({k: v for k, v in rec[label].items()
                                                       if k not in ("holdout", "tails")})),
                  flush=True)
        out[name] = rec
    path = ROOT / "studies" / "timing_jitter.json"
    path.write_text(json.dumps(to_jsonable(out), indent=1) + "\n")
    for name, rec in out.items():
        for label in ("before", "after"):
            for way in rec[label]["holdout"]["ways"]:
                for R, r in way["results"]["tune"].items():
                    a = r["after"]
                    print(f"| {name} | {label} | {way['fit']} | {float(R):g} | {a['alarms']} | "
                          f"{a['per_hour']:.0f} | {a['ci95_per_hour'][0]:.0f}–"
                          f"{a['ci95_per_hour'][1]:.0f} | {a['expected_at_target']:.2f} |")


if __name__ == "__main__":
    main()
