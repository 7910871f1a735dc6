"""PNG plots of a calibration (``rimu calibrate turntable ... --plot DIR``), matplotlib Agg
backend.

- ``residual_steps_<kind>.png``: mean and RMS of the residuals of every step, per sensor;
- ``earth_rate_fit.png``: the (wavelet-denoised) compensated gyro outputs of the outer-axis
  steps with the fitted Earth-rate modulation (seed 000 Fig. 3);
- ``allan_<kind>.png``: Allan deviation of the residuals.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from calibration.calibrate import outer_axis_fit
from calibration.session import Session
from fdi.calfile import Calibration
from fdi.errors import ConfigError
from fdi.units import DPH, DPS, MG

__all__ = ["write_plots"]

_UNIT = {"gyro": ("deg/h", DPH), "accel": ("mg", MG)}


def write_plots(session: Session, cal: Calibration, directory: str | Path) -> list[Path]:
    """Write the plots into ``directory`` (created); returns the files written."""
    d = Path(directory)
    try:
        d.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"{d}: cannot create plot directory ({exc.strerror})") from None
    out: list[Path] = []
    steps = cal.extras.residual_steps
    for kind, s in cal.sets.items():
        rows = steps.get(kind, ())
        if not rows:
            continue
        uname, uf = _UNIT[kind]
        k = np.array([r.step for r in rows])
        mean = np.array([r.mean for r in rows]) / uf
        rms = np.array([r.rms for r in rows]) / uf
        fig, ax = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
        for i, c in enumerate(s.sensors):
            ax[0].plot(k, mean[:, i], "o-", ms=3, label=c.name)
            ax[1].plot(k, rms[:, i], "o-", ms=3, label=c.name)
        ax[0].axhline(0, color="k", lw=0.5)
        ax[0].set_ylabel(f"residual mean ({uname})")
        ax[1].set_ylabel(f"residual rms ({uname})")
        ax[1].set_xlabel("step")
        ax[0].legend(ncol=min(s.n, 6), fontsize=8)
        ax[0].set_title(f"{kind}: residuals per step (compensated output − model)")
        fig.tight_layout()
        p = d / f"residual_steps_{kind}.png"
        fig.savefig(p, dpi=100)
        plt.close(fig)
        out.append(p)
        if s.allan is not None:
            fig, ax = plt.subplots(figsize=(7, 5))
            for i, c in enumerate(s.sensors):
                ax.loglog(s.allan.tau_s, s.allan.adev[:, i] / uf, "o-", ms=3, label=c.name)
            ax.set_xlabel("tau (s)")
            ax.set_ylabel(f"Allan deviation ({uname})")
            ax.grid(True, which="both", lw=0.3)
            ax.legend(fontsize=8)
            ax.set_title(f"{kind}: Allan deviation of the calibration residuals")
            fig.tight_layout()
            p = d / f"allan_{kind}.png"
            fig.savefig(p, dpi=100)
            plt.close(fig)
            out.append(p)
    fit = outer_axis_fit(session, cal,
                         denoise=cal.extras.method.part("denoise") != "none")
    if fit is not None and fit.y.size:
        g = cal.gyro
        m = np.isin(session.step, fit.steps)
        t = session.t[m]
        fig, axes = plt.subplots(g.n, 1, figsize=(10, 2.0 * g.n), sharex=True)
        axes = np.atleast_1d(axes)
        for i, c in enumerate(g.sensors):
            axes[i].plot(t, fit.y[:, i] / DPS, ",", color="0.3", label="denoised output")
            axes[i].plot(t, fit.fitted[:, i] / DPS, "r-", lw=1, label="Earth-rate fit")
            axes[i].set_ylabel(f"{c.name} (deg/s)")
        axes[0].set_title(f"outer-axis steps {fit.steps[0]}-{fit.steps[-1]}: Earth rate "
                          f"{fit.rate_dph:.3f} ± {fit.rate_dph_sd:.3f} deg/h")
        axes[0].legend(fontsize=8, loc="upper right")
        axes[-1].set_xlabel("time (s)")
        fig.tight_layout()
        p = d / "earth_rate_fit.png"
        fig.savefig(p, dpi=100)
        plt.close(fig)
        out.append(p)
    return out
