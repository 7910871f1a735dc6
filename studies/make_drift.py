"""Recompute docs/drift.md's numbers and figure (writes drift.json and img/drift.png).

What makes the held-out alarms of the 4×MPU9250 static set, and what the parity drift
model predicts, from ``../shared/data`` (``RIMU_SHARED_DATA`` overrides); nothing of the
recording is written but counts and fitted numbers. Run from the repository root::

    python studies/make_drift.py            # diagnosis and figure, about 2 min
    python studies/make_drift.py --holdout  # plus studies.field.holdout_static before and
                                         # after (about 6 more min)
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fdi.fileio import to_jsonable  # noqa: E402

DATA = Path(os.environ.get("RIMU_SHARED_DATA", ROOT / ".." / "shared" / "data"))
MPU = DATA / "multi_imu_4x_mpu9250"
KNOCK_MS2 = 0.5
"""An accelerometer channel this far from its median (about 15-25 sd) marks a knock."""
NEAR_S = 1.0
"""An exceedance within this time of a knock is counted as the knock's."""
DPH = 180.0 / np.pi * 3600.0


def knocks(fs: float, n: int) -> np.ndarray:
    """(N,) True within NEAR_S of a sample where some accelerometer axis jumps."""
    import scipy.io

    f = np.hstack([np.asarray(scipy.io.loadmat(MPU / f"imu{k}_raw.mat")[f"imu{k}_raw"][0, 0]
                              ["fb"], float) for k in range(1, 5)])[:n]
    hit = np.abs(f - np.median(f, axis=0)).max(axis=1) > KNOCK_MS2
    k = int(NEAR_S * fs)
    return np.convolve(hit.astype(float), np.ones(2 * k + 1), "same") > 0


def diagnose(t: np.ndarray, y: np.ndarray, names: tuple[str, ...]) -> dict:
    """Per direction, at 10/h with the calibration before the change: where the windows
    exceed their thresholds (near a knock or not, per scale), and the drift numbers."""
    from calibration.tails import whitened_parity
    from fdi.monitor import Monitor
    from studies.field import alarm_episodes
    from studies.realnoise import (
        MPU9250_CROSS_AXIS,
        MPU9250_SCALE_FACTOR_TOLERANCE,
        static_calibration,
    )
    from thresholds.tune import tune

    t = t - t[0]
    fs = (t.size - 1) / float(t[-1])
    k = t.size // 2
    near = knocks(fs, t.size)
    out = {"sample_rate_hz": fs, "knock_fraction": float(near.mean()),
           "knock_samples": int(near.sum()), "directions": []}
    for name, a, b in (("tune first half, count second", slice(0, k), slice(k, None)),
                       ("tune second half, count first", slice(k, None), slice(0, k))):
        cal = static_calibration(y[a], fs, names, drift_bias_sd=True, bias_prediction=True,
                                 scale_factor_tolerance=MPU9250_SCALE_FACTOR_TOLERANCE,
                                 cross_axis=MPU9250_CROSS_AXIS, drift=True)
        s = cal.gyro
        thr = tune(replace_drift(cal), false_alarms_per_hour=10.0).thresholds
        res = Monitor(replace_drift(cal), thr).run(t[b] - t[b][0], y[b])
        with np.errstate(invalid="ignore"):
            ratio = res.statistics / res.thresholds
        over = np.nan_to_num(ratio) > 1.0
        nb = near[b]
        eps = []
        for e in alarm_episodes(res.events):
            i = int(np.searchsorted(res.t, e.t))
            first = np.flatnonzero(over[i])
            eps.append({"t_s": float(e.t + t[b][0]), "near_knock": bool(nb[i]),
                        "first_scale": int(thr.scales[first[0]]) if first.size else None})
        # the drift: the whitened parity of the other half about this half's biases
        z, _ = whitened_parity(y[b] - s.biases, s.H, s.noise_covariance)
        m = 128
        blk = z[: z.shape[0] // m * m].reshape(-1, m, z.shape[1]).mean(axis=1)
        d2 = np.sum(blk * blk, axis=1) - z.shape[1] / m
        g = z.mean(axis=0)
        rel = relative_means(y, fs)
        out["directions"].append({
            "direction": name, "episodes": eps,
            "exceedance_samples_per_scale": over.sum(axis=0).tolist(),
            "exceedance_samples_near_knocks": (over & nb[:, None]).sum(axis=0).tolist(),
            "scales": list(thr.scales), "time_in_alarm": float(over.any(axis=1).mean()),
            "drift_model": s.drift.to_dict(),
            "predicted_offset_variance": s.drift.offset_variance(),
            "other_half_mean_offset_sq": float(g @ g),
            "other_half_3s_offset_sq_mean": float(d2.mean()),
            "other_half_3s_offset_sq_max": float(d2.max()),
            "relative_channel_shift_dph": (
                (rel[b].mean(axis=0) - rel[a].mean(axis=0)) * DPH).tolist()})
    return out


def replace_drift(cal):
    """The calibration without its drift model (the thresholds before the change)."""
    from dataclasses import replace

    return replace(cal, sets={k: replace(s, drift=None) for k, s in cal.sets.items()})


def relative_means(y: np.ndarray, fs: float) -> np.ndarray:
    """Each channel minus the mean of the four IMUs' same axis (N, 12), rad/s."""
    rel = np.empty_like(y)
    for a in range(3):
        cols = [3 * j + a for j in range(4)]
        rel[:, cols] = y[:, cols] - y[:, cols].mean(axis=1, keepdims=True)
    return rel


def figure(t: np.ndarray, y: np.ndarray, names: tuple[str, ...], diag: dict,
           path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = t - t[0]
    fs = diag["sample_rate_hz"]
    rel = relative_means(y, fs)
    B = int(60 * fs)
    nb = t.size // B
    bm = np.array([rel[i * B:(i + 1) * B].mean(axis=0) for i in range(nb)]) * DPH
    bm -= bm.mean(axis=0)
    tc = (np.arange(nb) + 0.5) * B / fs
    fig, ax = plt.subplots(1, 2, figsize=(12, 4.2))
    for c in np.argsort(-np.ptp(bm, axis=0))[:5]:
        ax[0].plot(tc, bm[:, c], "o-", ms=3, label=names[c])
    ax[0].axvline(t[t.size // 2], color="k", lw=0.8, ls=":")
    ax[0].set_xlabel("time (s)")
    ax[0].set_ylabel("60-s mean, minus the other IMUs' same axis (deg/h)")
    ax[0].set_title("relative bias drift (5 largest channels)")
    ax[0].legend(fontsize=7)
    for d, col in zip(diag["directions"], ("C0", "C3"), strict=True):
        m = d["drift_model"]
        tau = np.array(m["tau_s"])
        ex = np.array(m["excess"])
        ok = ex > 0
        lab = "first half" if "first half, count" in d["direction"] else "second half"
        ax[1].loglog(tau[ok], ex[ok], "o-", color=col, label=f"calibrated on the {lab}")
        th = 1.5 * m["span_s"] + m["span_s"] / 2
        ax[1].loglog([tau[-1], th], [ex[-1], ex[-1] * th / tau[-1]], "--", color=col)
        ax[1].plot([th], [d["other_half_mean_offset_sq"] / 2], "x", color=col, ms=9)
    ax[1].set_xlabel("tau (s)")
    ax[1].set_ylabel("excess Allan variance, tr, whitened")
    ax[1].set_title("e(tau); dashed: random walk to tau_h; x: half-mean offset / 2")
    ax[1].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=90)


def main() -> None:
    from studies.realnoise import load_mpu9250_static

    if not (MPU / "imu1_raw.mat").exists():
        sys.exit(f"real data absent: {MPU}")
    t, y, names = load_mpu9250_static(MPU)
    t0 = time.perf_counter()
    out = {"schema": "rimu.doc-drift/1", "diagnosis": diagnose(t, y, names)}
    out["timing_s"] = {"diagnosis": time.perf_counter() - t0}
    figure(t, y, names, out["diagnosis"], ROOT / "docs" / "img" / "drift.png")
    if "--holdout" in sys.argv:
        from studies.field import holdout_static

        t1 = time.perf_counter()
        out["holdout_before"] = holdout_static(t, y, names, tails=False, drift=False)
        out["holdout_after"] = holdout_static(t, y, names)
        out["timing_s"]["holdout"] = time.perf_counter() - t1
    (ROOT / "studies" / "drift.json").write_text(
        json.dumps(to_jsonable(out), indent=1, allow_nan=False) + "\n", encoding="utf-8")
    print("wrote studies/drift.json, docs/img/drift.png")


if __name__ == "__main__":
    main()
