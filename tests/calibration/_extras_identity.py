"""Write a representative set of calibrations (every writer of ``Calibration.extra``) into a
directory, for a byte-for-byte comparison of two versions of the writers.

Not a test (it needs minutes and ../shared/data): run it on two commits and compare::

    PYTHONPATH=$PWD python tests/calibration/_extras_identity.py OUT_DIR

Each calibration is written as the CLI writes it (``NAME.json``) and its fingerprint beside
it (``NAME.fingerprint``); ``diff -r`` of two output directories is the check.
"""

from __future__ import annotations

import contextlib
import io
import os
import sys
from pathlib import Path

SHARED = Path(os.environ.get("RIMU_SHARED_DATA",
                             Path(__file__).resolve().parents[2] / ".." / "shared" / "data"))


def _cli(*argv: str) -> None:
    from rimu.cli import main

    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        rc = main([*argv])
    if rc != 0:
        raise SystemExit(f"rimu {' '.join(argv)}: exit {rc}")


def _fingerprint(path: Path) -> None:
    from fdi.calfile import load_calibration

    path.with_suffix(".fingerprint").write_text(load_calibration(path).fingerprint() + "\n")


def _save(cal, path: Path) -> None:
    cal.save(path)
    _fingerprint(path)


def turntable(out: Path) -> None:
    """Simulated sessions: white and coloured noise, gyros and accelerometers, both bias
    methods, the checked path with an effect refit."""
    cases = {
        "tetrad": (["--preset", "tetrad-paper", "--seed", "1"], []),
        "tetrad_turns": (["--preset", "tetrad-paper", "--seed", "2"],
                         ["--bias-method", "turns", "--noise-model", "white"]),
        "tetrad_coloured": (["--preset", "tetrad-paper", "--seed", "3",
                             "--bias-instability-dph", "0.05", "--bias-correlation-s", "300"],
                            []),
        "cone_accel": (["--preset", "cone-paper", "--seed", "4"], []),
        "cone_coloured": (["--preset", "cone-paper", "--seed", "5",
                           "--bias-instability-dph", "20", "--bias-correlation-s", "100"], []),
        "cone_effect": (["--preset", "cone-paper", "--seed", "6",
                         "--effect", "g_sensitivity=200"],
                        ["--effects", "g_sensitivity"]),
    }
    for name, (sim, cal) in cases.items():
        s = out / f"session_{name}"
        _cli("simulate", "calibration", "--out", str(s), *sim)
        (out / f"truth_{name}.json").write_text((s / "truth.json").read_text())
        _cli("calibrate", "turntable", str(s), "--out", str(out / f"{name}.json"), *cal)
        _fingerprint(out / f"{name}.json")
        if name == "cone_effect":
            _cli("diagnose", str(s), "--cal", str(out / f"{name}.json"),
                 "--out", str(out / "cone_effect_refit.json"))
            _fingerprint(out / "cone_effect_refit.json")


def presets(out: Path) -> None:
    from calibration.presets import preset

    for name in ("tetrad-paper", "cone-paper"):
        _save(preset(name)[1], out / f"preset_{name}.json")


def ferraris(out: Path) -> None:
    csv = SHARED / "imucal" / "annotated_session.csv"
    _cli("calibrate", "ferraris", str(csv), "--sample-rate-hz", "204.8", "--gravity", "9.81",
         "--out", str(out / "ferraris.json"))
    _fingerprint(out / "ferraris.json")
    _cli("calibrate", "ferraris", str(csv), "--sample-rate-hz", "204.8",
         "--latitude-deg", "49.6", "--out", str(out / "ferraris_lat.json"))
    _fingerprint(out / "ferraris_lat.json")


def inflight(out: Path) -> None:
    d = SHARED / "erle_pxf_dual_imu"
    for name, log in (("41", "pxf_copter_22-12-2014_41.BIN"),
                      ("83", "pxf_copter_31-3-2015_83.BIN")):
        f = out / f"flight_{name}"
        _cli("ingest", str(d / log), "--salvage", "--out", str(f))
        _cli("calibrate", "in-flight", str(f), "--out", str(out / f"inflight_{name}.json"))
        _fingerprint(out / f"inflight_{name}.json")


def static(out: Path) -> None:
    p = SHARED / "multi_imu_4x_mpu9250"
    f = out / "mpu4"
    _cli("ingest", *(str(p / f"imu{k}_raw.mat") for k in range(1, 5)), "--out", str(f))
    _cli("calibrate", "static", str(f), "--out", str(out / "static_mpu4.json"))
    _fingerprint(out / "static_mpu4.json")


def main(out: Path, kinds: list[str]) -> None:
    out.mkdir(parents=True, exist_ok=True)
    for k in kinds or ["presets", "ferraris", "turntable", "inflight", "static"]:
        globals()[k](out)
        print(k, "done", flush=True)


if __name__ == "__main__":
    main(Path(sys.argv[1]), sys.argv[2:])
