"""Figures of docs/inflight.md: the in-flight residual of erle flight 41 over time and the
spread of error/σ over simulated flights.

Run from the repository root: ``python studies/make_inflight_plots.py`` (reads the erle log
from ``../shared/data``; ``RIMU_SHARED_DATA`` overrides that folder). Writes
``docs/inflight_erle41.png`` and ``docs/inflight_mc.png``.
"""

from __future__ import annotations

import os
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from calibration.inflight.fit import decompose, fit_inflight
from fdi.units import DPS
from replay.imu_set import ImuSetSpec, simulate_imu_set

DOCS = Path(__file__).resolve().parents[1] / "docs"
SHARED = Path(os.environ.get("RIMU_SHARED_DATA", DOCS.parent / ".." / "shared" / "data"))


def erle41() -> None:
    from replay.ingest import align_streams, read_any

    log = SHARED / "erle_pxf_dual_imu" / "pxf_copter_22-12-2014_41.BIN"
    if not log.is_file():
        print(f"skipped: {log} not found")
        return
    f, _ = align_streams(read_any(log, salvage=True))
    fit = fit_inflight(f)
    a = fit.alignments["imu2"]
    raw = f.raw[:, 3:] - f.raw[:, :3]
    fig, ax = plt.subplots(2, 1, figsize=(9, 5.5), sharex=True)
    for k, c in enumerate("xyz"):
        ax[0].plot(f.t, raw[:, k] / DPS, lw=0.5, label=f"imu2.{c} - imu1.{c}")
        ax[1].plot(f.t, a.residual[:, k] / DPS, lw=0.5, label=f"{c}")
    for axx in ax:
        for s in fit.left_out:
            axx.axvspan(s.t0_s, s.t1_s, color="0.85", lw=0)
        axx.set_ylabel("deg/s")
        axx.legend(loc="upper right", fontsize=7, ncol=3)
    ax[0].set_ylim(-60, 60)
    ax[1].set_ylim(-10, 10)
    ax[0].set_title("erle flight 41: IMU2 - IMU1 (grey: segments left out)")
    ax[1].set_title(f"after the in-flight fit (time offset {1e3 * a.time_offset_s:+.2f} ± "
                    f"{1e3 * a.time_offset_sd_s:.2f} ms, scale "
                    + "/".join(f"{100 * (d - 1):+.1f}" for d in np.diag(a.A)) + " %)")
    ax[1].set_xlabel("time (s)")
    fig.tight_layout()
    fig.savefig(DOCS / "inflight_erle41.png", dpi=110)
    print(f"wrote {DOCS / 'inflight_erle41.png'}")


def monte_carlo(seeds: int = 30) -> None:
    z: dict[str, list[float]] = {"rotation": [], "time offset": []}
    for s in range(seeds):
        f = simulate_imu_set(ImuSetSpec(imus=2, duration_s=60, seed=s,
                                        time_offset_s=(0.0, 0.005)))
        a = fit_inflight(f).alignments["imu2"]
        tr = f.truth["relative_to_reference"]["imu2"]
        est, sd = decompose(a.A, a.A_cov)["rotation"]
        z["rotation"] += list((est - decompose(np.array(tr["A"]))["rotation"][0]) / sd)
        z["time offset"].append((a.time_offset_s - tr["time_offset_s"]) / a.time_offset_sd_s)
    fig, ax = plt.subplots(1, 2, figsize=(8, 3))
    x = np.linspace(-4, 4, 200)
    for axx, (name, v) in zip(ax, z.items(), strict=True):
        axx.hist(v, bins=np.linspace(-4, 4, 17), density=True, color="0.6")
        axx.plot(x, np.exp(-x**2 / 2) / np.sqrt(2 * np.pi), "k-", lw=1)
        axx.set_title(f"{name}: error/σ, sd {np.std(v):.2f} (n={len(v)})", fontsize=9)
    fig.suptitle(f"{seeds} simulated two-IMU flights, 60 s at 50 Hz, 5 ms offset", fontsize=9)
    fig.tight_layout()
    fig.savefig(DOCS / "inflight_mc.png", dpi=110)
    print(f"wrote {DOCS / 'inflight_mc.png'}")


if __name__ == "__main__":
    erle41()
    monte_carlo()
