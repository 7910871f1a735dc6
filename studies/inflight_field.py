"""Every multi-IMU flight of ../shared/data through ``rimu calibrate in-flight`` (defaults).

``python studies/inflight_field.py [--json OUT]``: ingests each recording (ArduPilot logs as
they are, the Xsens DOT paths with ``docs/examples/xsens_dot.toml``), calibrates it with the
defaults and prints, per recording: accepted or the refusal, which parameters were
estimated and which held at the prior, the residual RMS before (raw difference to the
reference after the bias) and after, the time offsets, and the noisy-axis findings.
Recordings that are absent are skipped with a line saying so.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

MAP = ROOT / "docs" / "examples" / "xsens_dot.toml"


def shared() -> Path:
    env = os.environ.get("RIMU_SHARED_DATA")
    return Path(env) if env else ROOT / ".." / "shared" / "data"


def recordings() -> list[tuple[str, list[Path], list[str]]]:
    """(name, files, extra ingest arguments) of every multi-IMU flight."""
    out = []
    erle = shared() / "erle_pxf_dual_imu"
    for name, f, extra in (("erle 41", "pxf_copter_22-12-2014_41.BIN", []),
                           ("erle 83", "pxf_copter_31-3-2015_83.BIN", ["--salvage"])):
        out.append((name, [erle / f], extra))
    xs = shared() / "ansfl_4x_xsens_dot"
    for kind in ("Horizontal", "Vertical"):
        for p in sorted((xs / kind).glob("path_*"), key=lambda q: int(q.name.split("_")[1])):
            out.append((f"xsens {kind[0]}{p.name.split('_')[1]}",
                        [p / f"IMU_{k}.csv" for k in range(1, 5)], ["--map", str(MAP)]))
    return out


def ingest(files: list[Path], extra: list[str], out: Path) -> None:
    from rimu.cli import main

    rc = main(["ingest", *map(str, files), *extra, "--out", str(out)])
    if rc:
        raise RuntimeError(f"ingest of {files[0]} returned {rc}")


def measure(folder: Path) -> dict[str, object]:
    """Calibrate a flight folder with the defaults; the table's row."""
    from calibration.inflight.fit import ESTIMATED, fit_inflight, imu_rates
    from fdi.errors import RimuError
    from replay.flight_io import load_flight_dir

    flight = load_flight_dir(folder)
    try:
        fit = fit_inflight(flight)
    except RimuError as exc:
        return {"accepted": False, "refusal": str(exc)}
    rates = imu_rates(flight)
    row: dict[str, object] = {"accepted": True, "imus": {}, "findings":
                              [x.text() for x in fit.findings]}
    for g, a in fit.alignments.items():
        u = fit.used & np.all(np.isfinite(a.residual), axis=1)
        d = rates[g][u] - rates[fit.reference][u]
        before = np.degrees(np.sqrt(np.mean((d - d.mean(axis=0)) ** 2, axis=0)))
        after = np.degrees(np.sqrt(np.mean(a.residual[u] ** 2, axis=0)))
        row["imus"][g] = {
            "estimated": [p.name for p in a.parameters if p.status == ESTIMATED],
            "held": a.held(),
            "mounting_identity": bool(np.allclose(a.mounting, np.eye(3))),
            "rms_before_dps": before.round(3).tolist(),
            "rms_after_dps": after.round(3).tolist(),
            "time_offset_ms": round(1e3 * a.time_offset_s, 3),
            "time_offset_sd_ms": round(1e3 * a.time_offset_sd_s, 3)}
    return row


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)
    table = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, files, extra in recordings():
            if not all(f.is_file() for f in files):
                print(f"{name}: skipped ({files[0]} not found)")
                continue
            d = Path(tmp) / name.replace(" ", "_")
            ingest(files, extra, d)
            row = table[name] = measure(d)
            if not row["accepted"]:
                print(f"{name}: REFUSED: {row['refusal']}")
                continue
            print(f"{name}: accepted")
            for g, r in row["imus"].items():
                print(f"  {g}: estimated {len(r['estimated'])}, held "
                      f"{', '.join(r['held']) or 'none'}; rms before {r['rms_before_dps']} "
                      f"after {r['rms_after_dps']} deg/s; tau {r['time_offset_ms']:+.2f} ± "
                      f"{r['time_offset_sd_ms']:.2f} ms"
                      + ("" if r["mounting_identity"] else "; mounting not identity"))
            for x in row["findings"]:
                print(f"  finding: {x}")
    if args.json:
        args.json.write_text(json.dumps(table, indent=1) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
