"""Characterise the measured recordings: writes ``studies/findings.json`` and ``docs/img/*.png``.

Run from the repository root (the data folder is read, never copied)::

    PYTHONPATH=. python studies/make_findings.py [--data ../shared/data]

Every recording goes in through the ingest readers (:mod:`replay.ingest`), then through
the generic statistics of :mod:`replay.ingest.characterise`. The dataset-specific parts
here are only which files, which map, which IMU is the reference, which band is used for
a noise density, and the datasheet values the numbers are compared with.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from fdi.fileio import to_jsonable  # noqa: E402
from fdi.units import DPS  # noqa: E402
from replay.ingest import align_streams, read_any  # noqa: E402
from replay.ingest.characterise import (  # noqa: E402
    common_mode,
    noise_from_pairs,
    pair_report,
    static_report,
)
from replay.ingest.readers import merge_reads  # noqa: E402

FINDINGS_SCHEMA = "rimu.findings/1"
DATASHEET = {
    # InvenSense MPU-9250 product specification: rate noise spectral density
    # 0.01 °/s/√Hz, total RMS noise 0.1 °/s-rms (DLPF 92 Hz)
    "mpu9250": {"density_dps_rthz": 0.01, "total_rms_dps": 0.1},
    # Analog Devices ADIS16405: rate noise density 0.05 °/s/√Hz rms, angle random walk
    # 2.0 °/√h, in-run bias stability 0.007 °/s (1σ)
    "adis16405": {"density_dps_rthz": 0.05, "arw_deg_rth": 2.0,
                  "in_run_bias_dps": 0.007},
}
ADIS_MAP = """schema = "rimu.ingest-map/1"
format = "rda"
[time]
rate_hz = 100.0
[[imus]]
gyro = ["Gyro. X", "Gyro. Y", "Gyro. Z"]
gyro_unit = "deg/s"
accel = ["Accel. X", "Accel. Y", "Accel. Z"]
accel_unit = "g"
"""
ERLE = {"41": ("pxf_copter_22-12-2014_41.BIN", False),
        "83": ("pxf_copter_31-3-2015_83.BIN", True)}


def data_dir(arg: str | None = None) -> Path:
    """The shared data folder: ``--data``, ``RIMU_SHARED_DATA``, or ``../shared/data``."""
    if arg:
        return Path(arg)
    env = os.environ.get("RIMU_SHARED_DATA")
    return Path(env) if env else ROOT / ".." / "shared" / "data"


# -- the datasets -----------------------------------------------------------------------
def load_erle(data: Path, flight: str):
    """The ingested erle flight (41, or 83 salvaged: its log is cut at the end)."""
    name, salvage = ERLE[flight]
    read = read_any(data / "erle_pxf_dual_imu" / name, salvage=salvage)
    return align_streams(read)


def erle(data: Path, flight: str) -> dict[str, Any]:
    """Two IMUs in flight: IMU2 aligned onto IMU1, its lag, the residual."""
    f, rep = load_erle(data, flight)
    g = f.raw
    out = pair_report(f.t, g[:, :3], g[:, 3:])
    acc = f.aux.select("accel").values
    out["accel_mean_mps2"] = {"imu1": acc[:, :3].mean(axis=0).tolist(),
                              "imu2": acc[:, 3:].mean(axis=0).tolist()}
    out["max_rate_rps"] = float(np.abs(g).max())
    out["damage"] = rep["damage"]
    out["gaps"] = rep["time_base"]["gaps"]
    out["temperature_logged"] = any(i["temperature"] for i in rep["imus"])
    return out


def load_mpu4(data: Path):
    """The four MPU9250 .mat files as one flight (imu1..imu4)."""
    folder = data / "multi_imu_4x_mpu9250"
    reads = [read_any(folder / f"imu{k}_raw.mat") for k in (1, 2, 3, 4)]
    return align_streams(merge_reads(reads))


def mpu4(data: Path) -> dict[str, Any]:
    """Four resting MPU9250s: noise of each, what they share, what the parity keeps."""
    f, _ = load_mpu4(data)
    fs = f.sample_rate_hz
    x = f.raw
    per = [static_report(x[:, 3 * k:3 * k + 3], fs, band=(0.5, 20.0)) for k in range(4)]
    cm = common_mode(x)
    hat = np.sqrt(np.array([noise_from_pairs(x[:, [k, 3 + k, 6 + k, 9 + k]])
                            for k in range(3)]))          # axis k of each IMU
    acc = f.aux.select("accel").values.reshape(-1, 4, 3).mean(axis=0)
    from replay.ingest.characterise import excess_kurtosis
    return {
        "sample_rate_hz": fs, "samples": int(f.t.shape[0]),
        "imus": [{k: v for k, v in p.items() if k != "allan"} for p in per],
        "three_cornered_hat_rps": hat.T.tolist(),
        "common_mode": {"eigenvalues": cm["eigenvalues"].tolist(), "edge": cm["edge"],
                        "n_common": cm["n_common"],
                        "top_vector": cm["vectors"][:, 0].tolist(),
                        "kurtosis_top": excess_kurtosis(
                            (x - x.mean(0)) / x.std(0) @ cm["vectors"][:, :1]).to_dict(),
                        "kurtosis_parity": excess_kurtosis(cm["parity"]).to_dict()},
        "accel_norm_mps2": np.linalg.norm(acc, axis=1).tolist(),
        "_allan": [p["allan"][0] for p in per],          # x axis of each
    }


def px4(data: Path) -> dict[str, Any]:
    """The PX4 samples: what a handful of samples per IMU can say, raw (``sensor_gyro``,
    logged before PX4's calibration) and calibrated (``vehicle_imu``)."""
    out = {}
    for name in ("sample_log_small.ulg", "sample_logging_tagged_and_default_params.ulg"):
        res: dict[str, Any] = {}
        for topic in ("sensor_gyro", "vehicle_imu"):
            read = read_any(data / "px4_ulog" / name, px4_topic=topic)
            means = np.array([s.gyro.mean(axis=0) for s in read.streams])
            sds = np.array([s.gyro.std(axis=0, ddof=1) / np.sqrt(s.size)
                            for s in read.streams])
            res[topic] = {
                "samples": [s.size for s in read.streams],
                "device_ids": [s.device_id for s in read.streams],
                "mean_rps": means.tolist(),
                "diff_to_imu1_rps": (means - means[0]).tolist(),
                "diff_to_imu1_sd_rps": np.sqrt(sds**2 + sds[0] ** 2).tolist(),
            }
            if topic == "sensor_gyro":
                res["temperature_degc"] = [float(np.nanmean(s.temperature))
                                           if s.temperature is not None else None
                                           for s in read.streams]
        out[name] = res
    return out


def load_adis(data: Path, tmp: Path):
    """The ADIS16405 record (map written to ``tmp``)."""
    mp = tmp / "adis_map.toml"
    mp.write_text(ADIS_MAP, encoding="utf-8")
    return align_streams(read_any(data / "smac_adis16405" / "adis_16405_imu1.rda",
                                  map_path=mp))


def adis(data: Path, tmp: Path) -> dict[str, Any]:
    """One resting ADIS16405: noise against its datasheet (no second IMU: no parity)."""
    f, _ = load_adis(data, tmp)
    rep = static_report(f.raw, f.sample_rate_hz, band=(0.5, 10.0))
    out = {k: v for k, v in rep.items() if k != "allan"}
    out["_allan"] = rep["allan"]
    # where the z axis's narrow band sits in each 1000 s of the record
    import scipy.signal
    z = f.raw[:, 2]
    per = []
    for b in range(z.shape[0] // 100_000):
        seg = z[b * 100_000:(b + 1) * 100_000]
        fr, P = scipy.signal.welch(seg - seg.mean(), fs=f.sample_rate_hz, nperseg=1024)
        m = (fr > 15) & (fr < 25)
        per.append(float(fr[m][np.argmax(P[m])]))
    out["z_band_peak_hz_per_1000s"] = per
    fr, P = scipy.signal.welch(z - z.mean(), fs=f.sample_rate_hz, nperseg=1024)
    m = (fr > 17) & (fr < 23)
    floor = np.median(P[(fr > 5) & (fr < 15)])
    out["z_band_power_fraction"] = float((P[m] - floor).sum() * (fr[1] - fr[0])
                                         / z.var())
    out["accel_mean_g"] = (f.aux.select("accel").values.mean(axis=0) / 9.80665).tolist()
    return out


# -- plots ------------------------------------------------------------------------------
def _plots(res: dict[str, Any], data: Path, img: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    img.mkdir(parents=True, exist_ok=True)
    kw = {"dpi": 80}
    # 1: erle 41, a second of roll rate: IMU2 lags IMU1
    f, _ = load_erle(data, "41")
    i0 = int(np.argmax(np.abs(np.diff(f.raw[:, 0]))))
    s = slice(max(0, i0 - 25), i0 + 25)
    fig, ax = plt.subplots(figsize=(6, 3))
    ax.plot(f.t[s], f.raw[s, 0] / DPS, ".-", label="IMU (imu1) x")
    ax.plot(f.t[s], f.raw[s, 3] / DPS, ".-", label="IMU2 (imu2) x")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("rate (deg/s)")
    lag_ms = res["erle"]["41"]["time_offset_s"]["value"] * 1e3
    ax.set_title(f"flight 41: IMU2 lags by {lag_ms:.1f} ms")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(img / "erle41_lag.png", **kw)
    plt.close(fig)
    # 2: residual RMS before/after, both flights
    fig, axs = plt.subplots(1, 2, figsize=(7, 3), sharey=True)
    for ax, fl in zip(axs, ("41", "83"), strict=True):
        r = res["erle"][fl]
        xs = np.arange(3)
        for k, (key, lab) in enumerate((("rms_raw_rps", "raw difference"),
                                        ("rms_lag_rps", "lag removed"),
                                        ("rms_lag_aligned_rps", "lag + alignment"))):
            ax.bar(xs + 0.27 * (k - 1), np.array(r[key]) / DPS, 0.27, label=lab)
        ax.set_xticks(xs, ["x", "y", "z"])
        ax.set_title(f"flight {fl}")
    axs[0].set_ylabel("residual RMS (deg/s)")
    axs[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(img / "erle_residual_rms.png", **kw)
    plt.close(fig)
    # 3: Allan deviations, MPU9250 x4 and ADIS16405
    fig, axs = plt.subplots(1, 2, figsize=(8, 3.2))
    for k, a in enumerate(res["mpu4"]["_allan"]):
        axs[0].loglog(a["tau_s"], a["adev"] / DPS, label=f"imu{k + 1} x")
    tau = np.logspace(-1.5, 3, 20)
    n_ds = DATASHEET["mpu9250"]["density_dps_rthz"] / np.sqrt(2)
    axs[0].loglog(tau, n_ds / np.sqrt(tau), "k--", lw=0.8, label="datasheet density")
    axs[0].set_title("4 x MPU9250, static")
    for k, a in enumerate(res["adis"]["_allan"]):
        axs[1].loglog(a["tau_s"], a["adev"] / DPS, label="xyz"[k])
    n_ds = DATASHEET["adis16405"]["density_dps_rthz"] / np.sqrt(2)
    axs[1].loglog(tau, n_ds / np.sqrt(tau), "k--", lw=0.8, label="datasheet density")
    axs[1].axhline(DATASHEET["adis16405"]["in_run_bias_dps"], color="k", ls=":", lw=0.8,
                   label="datasheet in-run bias")
    axs[1].set_title("ADIS16405, static")
    for ax in axs:
        ax.set_xlabel("tau (s)")
        ax.set_ylabel("Allan deviation (deg/s)")
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(img / "allan_static.png", **kw)
    plt.close(fig)
    # 4: common mode of the four MPU9250s
    f, _ = load_mpu4(data)
    cm = res["mpu4"]["common_mode"]
    x = f.raw
    z = (x - x.mean(0)) / x.std(0) @ np.array(cm["top_vector"])
    fig, axs = plt.subplots(1, 2, figsize=(8, 3), gridspec_kw={"width_ratios": [1, 2]})
    axs[0].plot(np.arange(1, 13), cm["eigenvalues"], "o")
    axs[0].axhline(cm["edge"], color="k", ls="--", lw=0.8, label="independent-noise edge")
    axs[0].set_xlabel("component")
    axs[0].set_ylabel("eigenvalue")
    axs[0].legend(fontsize=7)
    axs[1].plot(f.t, z, lw=0.4)
    axs[1].set_xlabel("time (s)")
    axs[1].set_ylabel("common component (σ units)")
    fig.tight_layout()
    fig.savefig(img / "mpu4_common_mode.png", **kw)
    plt.close(fig)


def compute(data: Path, tmp: Path) -> dict[str, Any]:
    """All findings (with private ``_allan`` curves for the plots)."""
    return {"schema": FINDINGS_SCHEMA, "datasheet": DATASHEET,
            "erle": {fl: erle(data, fl) for fl in ERLE}, "mpu4": mpu4(data),
            "px4": px4(data), "adis": adis(data, tmp)}


def _public(res: Any) -> Any:
    if isinstance(res, dict):
        return {k: _public(v) for k, v in res.items()
                if not k.startswith("_") and k != "residual"}
    return res


def main(argv: list[str] | None = None) -> int:
    import tempfile

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", help="the shared data folder (default ../shared/data)")
    p.add_argument("--no-plots", action="store_true")
    args = p.parse_args(argv)
    data = data_dir(args.data)
    with tempfile.TemporaryDirectory() as tmp:
        res = compute(data, Path(tmp))
        if not args.no_plots:
            _plots(res, data, ROOT / "docs" / "img")
    out = ROOT / "studies" / "findings.json"
    out.write_text(json.dumps(to_jsonable(_public(res)), indent=1) + "\n", encoding="utf-8")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
