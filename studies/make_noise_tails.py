"""Recompute the held-out false-alarm tables of docs/noise-tails.md (writes noise_tails.json).

Reads the measured recordings in place from ``../shared/data`` (``RIMU_SHARED_DATA``
overrides); nothing of them is written here but counts and fitted numbers. Run from the
repository root::

    python studies/make_noise_tails.py
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests" / "calibration"))

from _erle import FLIGHTS, SHARED, read_erle  # noqa: E402

from fdi.fileio import to_jsonable  # noqa: E402
from studies.realnoise import load_mpu9250_static  # noqa: E402
from studies.tails_holdout import flight_holdout, static_holdout_tails  # noqa: E402

TARGETS = (1.0, 100.0, 1000.0)


def _table(name: str, rep: dict) -> list[str]:
    rows = []
    for way in rep["ways"]:
        for target, rec in way["results"]["tune"].items():
            b, a = rec["before"], rec["after"]
            lo, hi = a["ci95_per_hour"]
            rows.append(
                f"| {name} | {way['fit']} | {float(target):g} | {a['expected_at_target']:.2f} | "
                f"{b['alarms']} ({b['per_hour']:.0f}/h) | {a['alarms']} ({a['per_hour']:.0f}/h, "
                f"{lo:.0f}–{hi:.0f}) | {'yes' if a['resolvable'] else 'no'} | "
                f"{b['detectable_dps_best']:.2f} / {a['detectable_dps_best']:.2f} | "
                f"{100 * b['time_in_alarm_fraction']:.2f} / "
                f"{100 * a['time_in_alarm_fraction']:.2f} |")
    return rows


def main() -> int:
    out = {}
    for name in FLIGHTS:
        out[f"flight {name}"] = flight_holdout(read_erle(name), targets=TARGETS)
    t, y, names = load_mpu9250_static(SHARED / "multi_imu_4x_mpu9250")
    out["4xMPU9250 static"] = static_holdout_tails(t, y, names, targets=TARGETS)
    (ROOT / "studies" / "noise_tails.json").write_text(
        json.dumps(to_jsonable(out), indent=1) + "\n", encoding="utf-8")
    print("| recording | fitted on | target /h | expected at target | before: alarms | "
          "after: alarms (95 % interval /h) | resolvable | detectable °/s before / after | "
          "time in alarm % before / after |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for name, rep in out.items():
        print("\n".join(_table(name, rep)))
    for name, rep in out.items():
        for way in rep["ways"]:
            print(name, way["fit"], "tail model:", [
                (m["scale"], "G" if m["gaussian"] else "x", round(m["excess_kurtosis"], 1),
                 None if m["gpd_shape"] is None else round(m["gpd_shape"], 2))
                for m in way["tail_model"]])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
