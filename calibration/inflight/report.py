"""PNG plots of an in-flight calibration or a flight diagnosis (``--report DIR``).

- ``residual.png``: per IMU other than the reference, the 1-s RMS over time of the raw
  difference to the reference (no calibration) and of the residual the calibration leaves
  (its gains, biases and time offset applied exactly, :func:`.diagnose.shifted_residual`);
  the segments left out are shaded.
- ``offset.png``: the time offset of each independently fitted piece of the flight with its
  sd, against the whole-flight offset and the sd reported (:mod:`.offset_check`); the sign
  convention in the title.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from calibration.inflight.offset_check import SIGN_CONVENTION
from calibration.inflight.segments import find_segments, keep_mask
from fdi.calfile import Calibration
from fdi.units import DPS, MS
from replay.flight_data import Flight

__all__ = ["write_flight_plots"]


def _rms_1s(t: np.ndarray, x: np.ndarray, fs: float) -> tuple[np.ndarray, np.ndarray]:
    q = max(1, round(fs))
    nb = t.shape[0] // q
    tb = t[:nb * q].reshape(nb, q).mean(axis=1)
    b = x[:nb * q].reshape(nb, q, -1) ** 2
    n = np.sum(np.isfinite(b), axis=1)
    s = np.nansum(b, axis=1)
    xb = np.sqrt(np.divide(s, n, out=np.full(s.shape, np.nan), where=n > 0))
    return tb, xb


def write_flight_plots(flight: Flight, cal: Calibration, out: Path) -> list[Path]:
    """Write the plots of the module docstring into ``out``; returns their paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from calibration.inflight.diagnose import shifted_residual

    out.mkdir(parents=True, exist_ok=True)
    segs = find_segments(flight)
    ref, res, groups, _, _, _, _ = shifted_residual(flight, cal, keep_mask(flight.t, segs))
    fs = float(flight.sample_rate_hz)
    paths = []
    fig, axes = plt.subplots(len(res), 1, figsize=(8, 2.8 * len(res)), squeeze=False)
    for ax, (g, r) in zip(axes[:, 0], res.items(), strict=True):
        raw = flight.raw[:, groups[g]] - flight.raw[:, groups[ref]]
        tb, before = _rms_1s(flight.t, raw, fs)
        _, after = _rms_1s(flight.t, r, fs)
        for k, a in enumerate("xyz"):
            ax.semilogy(tb, before[:, k] / DPS, lw=0.8, alpha=0.5, label=f"{a} raw difference")
            ax.semilogy(tb, after[:, k] / DPS, lw=1.0, label=f"{a} calibration residual")
        for s in segs:
            ax.axvspan(s.t0_s, s.t1_s, color="0.85", zorder=0)
        ax.set_ylabel("1-s RMS [deg/s]")
        ax.set_title(f"{g} against {ref} (grey: left out)")
        ax.legend(fontsize=6, ncol=2)
        ax.grid(True, which="both", alpha=0.3)
    axes[-1, 0].set_xlabel("t [s]")
    fig.tight_layout()
    p = out / "residual.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    paths.append(p)
    inflight = cal.extras.inflight
    imus = inflight.imus if inflight is not None else {}
    checks = {g: r.check for g, r in imus.items() if r.check is not None}
    if checks:
        fig, axes = plt.subplots(len(checks), 1, figsize=(8, 2.8 * len(checks)),
                                 squeeze=False)
        for ax, (g, chk) in zip(axes[:, 0], checks.items(), strict=True):
            tau, sd = imus[g].time_offset_s / MS, imus[g].time_offset_sd_s / MS
            good = [q for q in chk.pieces if q.offset_s is not None]
            mid = [(q.t0_s + q.t1_s) / 2 for q in good]
            half = [(q.t1_s - q.t0_s) / 2 for q in good]
            ax.errorbar(mid, [q.offset_s / MS for q in good], yerr=[q.sd_s / MS for q in good],
                        xerr=half, fmt="o", ms=3, label="independently fitted pieces")
            ax.axhline(tau, color="k", lw=1, label=f"whole flight {tau:+.2f} ± {sd:.2f} ms")
            ax.axhspan(tau - sd, tau + sd, color="0.8", alpha=0.6)
            c = chk.consistency
            ttl = f"{g}: time offset" + (f", chi2/dof {c.chi2_dof:.2f} (p={c.p_value:.2g})"
                                         if c else "")
            ax.set_title(ttl, fontsize=9)
            ax.set_ylabel("offset [ms]")
            ax.legend(fontsize=7)
            ax.grid(True, alpha=0.3)
        axes[-1, 0].set_xlabel("t [s]")
        fig.suptitle(SIGN_CONVENTION, fontsize=7)
        fig.tight_layout()
        p = out / "offset.png"
        fig.savefig(p, dpi=110)
        plt.close(fig)
        paths.append(p)
    return paths
