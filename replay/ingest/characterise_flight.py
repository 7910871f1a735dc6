"""``rimu characterise DIR``: what the recording of a flight folder holds, IMU by IMU.

For each IMU group (any number of axes; one IMU or many; at rest or moving) and each axis,
on the samples every sensor sent (rad/s):

- **noise density** (Welch, one-sided, unit/√Hz) in the band 0.5 Hz … 0.45·fs, σ from 10
  blocks (:func:`replay.ingest.characterise.noise_density`);
- **Allan deviation** (allantools, overlapping, octave τ) and its **noise terms** fitted to
  the Allan variance (IEEE Std 952 model, weighted non-negative least squares)::

      σ²(τ) = N²/τ + (2 ln2/π)·B² + K²·τ/3

  N angle random walk (rad/s/√Hz, printed °/√h), B bias instability (rad/s, printed °/h),
  K rate random walk (rad/s/√s, printed °/h/√h); a term the fit sets to 0 is not seen.
  N is the Allan convention (σ(1 s) for white rate noise): the one-sided density / √2;
- **kurtosis and tail**: excess kurtosis (σ from blocks) and the fraction of samples beyond
  4 sd against the Gaussian 6.3e-5;
- **spectral lines** (:func:`replay.ingest.characterise.spectral_lines`, 1 % family-wise);
- **slow drift**: the linear trend over the record of each axis (fitted to 10-s means), as
  the change from the first to the last sample, with its HAC (Newey–West, statsmodels) sd,
  z and p-value (:func:`slow_drift`); a drift is *significant* at p < α/(number of axes)
  (Bonferroni);
- **shared modes** across all gyro axes (:func:`replay.ingest.characterise.common_mode`):
  eigenvalues of the correlation matrix above the Marchenko–Pastur edge are motion or a
  disturbance several sensors see together.

A moving recording (median rate magnitude above :data:`MOVING_RPS`) is characterised on the
rates as logged, which include the motion: the report says so (its Allan curve and drift
then describe the manoeuvres, not the sensor).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
from scipy import optimize, stats

from fdi.units import DPH, DPS
from replay.flight_data import Flight
from replay.ingest.characterise import (
    allan,
    common_mode,
    excess_kurtosis,
    noise_density,
    spectral_lines,
)

__all__ = ["CHARACTERISE_SCHEMA", "DRIFT_BLOCK_S", "MOVING_RPS", "allan_terms",
           "characterise_flight", "slow_drift", "text", "write_plots"]

CHARACTERISE_SCHEMA = "rimu.characterise/1"
MOVING_RPS = 0.05
"""Median rate magnitude (rad/s) above which a recording counts as moving."""
DRIFT_BLOCK_S = 10.0
"""Block (s) whose means the drift trend is fitted to."""
_GAUSS_4SD = 2 * stats.norm.sf(4.0)


def allan_terms(tau: np.ndarray, adev: np.ndarray, n_avg: np.ndarray | None = None
                ) -> dict[str, float]:
    """Noise terms N, B, K (SI) fitted to an Allan deviation curve (module docstring).

    Weighted by the Allan variance's own sd (≈ σ²·sqrt(2/dof), dof ≈ averaging intervals).
    """
    tau = np.asarray(tau, float)
    av = np.asarray(adev, float) ** 2
    dof = np.asarray(n_avg, float) if n_avg is not None else np.full(tau.shape, 10.0)
    w = 1.0 / (av * np.sqrt(2.0 / np.maximum(dof, 1.0)))
    A = np.column_stack([1.0 / tau, np.full(tau.shape, 2 * math.log(2) / math.pi),
                         tau / 3.0])
    coef, _ = optimize.nnls(A * w[:, None], av * w)
    return {"N": float(np.sqrt(coef[0])), "B": float(np.sqrt(coef[1])),
            "K": float(np.sqrt(coef[2]))}


def slow_drift(t: np.ndarray, x: np.ndarray, *, block_s: float = DRIFT_BLOCK_S
               ) -> dict[str, Any]:
    """Linear trend of each column of ``x`` (N, k) over ``t``: the change from the first
    to the last sample, with its sd, z and p.

    Fitted on means over ``block_s`` blocks (the sample noise averaged out), with a HAC
    (Newey–West, statsmodels) covariance of ``ceil(4·(n/100)^(2/9))`` block lags (at least
    2): the null hypothesis is a constant bias plus noise correlated over up to that many
    blocks; a wander slower than that reads as drift.
    """
    import statsmodels.api as sm

    dt = float(np.median(np.diff(t))) if t.shape[0] > 1 else 1.0
    q = max(1, round(block_s / dt))
    nb = t.shape[0] // q
    if nb < 8:
        q, nb = 1, t.shape[0]
    tb = t[:nb * q].reshape(nb, q).mean(axis=1)
    xb = x[:nb * q].reshape(nb, q, -1).mean(axis=1)
    tt = (tb - t[0]) / max(float(t[-1] - t[0]), 1e-12)
    X = sm.add_constant(tt)
    lag = max(2, math.ceil(4 * (nb / 100) ** (2 / 9)))
    ch, sd, z, p = [], [], [], []
    for k in range(x.shape[1]):
        r = sm.OLS(xb[:, k], X).fit(cov_type="HAC", cov_kwds={"maxlags": lag})
        b, s = float(r.params[1]), float(r.bse[1])
        ch.append(b)
        sd.append(s)
        z.append(b / s if s > 0 else math.inf)
        p.append(float(2 * stats.norm.sf(abs(b / s))) if s > 0 else 0.0)
    return {"change": ch, "change_sd": sd, "z": z, "p_value": p, "block_s": q * dt,
            "hac_lags": lag}


def _imu_report(t: np.ndarray, x: np.ndarray, fs: float, names: list[str],
                alpha_each: float) -> dict[str, Any]:
    xs = x - x.mean(axis=0)
    band = (0.5, 0.45 * fs)
    dens = noise_density(xs, fs, band, blocks=10, nperseg=min(1024, x.shape[0] // 8))
    al = [allan(xs[:, k], fs) for k in range(x.shape[1])]
    terms = []
    for a in al:
        n_avg = x.shape[0] / (np.asarray(a["tau_s"]) * fs)
        terms.append(allan_terms(a["tau_s"], a["adev"], n_avg))
    kurt = excess_kurtosis(xs, 10)
    sd = xs.std(axis=0)
    tail = [float(np.mean(np.abs(xs[:, k]) > 4 * sd[k])) for k in range(x.shape[1])]
    dr = slow_drift(t, x)
    return {
        "axes": names, "mean_dps": (x.mean(axis=0) / DPS).tolist(),
        "std_dps": (sd / DPS).tolist(),
        "density_dps_rthz": (np.asarray(dens.value) / DPS).tolist(),
        "density_dps_rthz_sd": (np.asarray(dens.sd) / DPS).tolist(), "band_hz": list(band),
        "allan": [{"tau_s": np.asarray(a["tau_s"]).tolist(),
                   "adev_dps": (np.asarray(a["adev"]) / DPS).tolist(),
                   "min_dps": a["min"] / DPS, "tau_min_s": a["tau_min_s"]} for a in al],
        "arw_deg_rth": [tm["N"] / DPS * 60.0 for tm in terms],
        "bias_instability_dph": [tm["B"] / DPH for tm in terms],
        "rate_random_walk_dph_rth": [tm["K"] / DPH * 60.0 for tm in terms],
        "excess_kurtosis": np.asarray(kurt.value).tolist(),
        "excess_kurtosis_sd": np.asarray(kurt.sd).tolist(),
        "tail_beyond_4sd": tail, "tail_gaussian": _GAUSS_4SD,
        "lines": spectral_lines(xs, fs, nperseg=min(1024, x.shape[0] // 8))[:8],
        "drift_dps": (np.asarray(dr["change"]) / DPS).tolist(),
        "drift_dps_sd": (np.asarray(dr["change_sd"]) / DPS).tolist(),
        "drift_z": dr["z"], "drift_p": dr["p_value"],
        "drift_significant": [p < alpha_each for p in dr["p_value"]],
        "drift_hac_lags": dr["hac_lags"], "drift_block_s": dr["block_s"]}


def characterise_flight(flight: Flight, *, alpha: float = 0.01) -> dict[str, Any]:
    """The report of a flight folder's recording (module docstring); JSON-ready."""
    ok = flight.valid.all(axis=1) & np.all(np.isfinite(flight.raw), axis=1)
    t, x = flight.t[ok], np.asarray(flight.raw, float)[ok]
    fs = float(flight.sample_rate_hz)
    groups = flight.imu_groups() if flight.imu else {"set": list(range(flight.n))}
    per = max(flight.n, 1)
    rate = np.linalg.norm(x[:, :min(3, flight.n)], axis=1)
    moving = bool(np.median(np.abs(rate - np.median(rate))) > MOVING_RPS
                  or np.median(rate) > MOVING_RPS + np.max(np.abs(np.median(x, axis=0))))
    imus = {g: _imu_report(t, x[:, idx], fs, [flight.sensor_names[i] for i in idx],
                           alpha / per) for g, idx in groups.items()}
    shared: dict[str, Any] = {}
    if len(groups) >= 2:
        cm = common_mode(x)
        k = int(cm["n_common"])
        comp = cm["parity"]
        shared = {"eigenvalues": np.asarray(cm["eigenvalues"]).tolist(), "edge": cm["edge"],
                  "n_shared": k,
                  "vectors": np.asarray(cm["vectors"])[:, :k].T.tolist(),
                  "axes": list(flight.sensor_names),
                  "parity_excess_kurtosis": (stats.kurtosis(comp, axis=0).tolist()
                                             if comp.shape[1] else [])}
    return {"schema": CHARACTERISE_SCHEMA, "source": flight.source, "samples": int(t.shape[0]),
            "duration_s": float(t[-1] - t[0]) if t.size else 0.0, "sample_rate_hz": fs,
            "moving": moving, "alpha": alpha, "imus": imus, "shared": shared,
            "units": {"density": "deg/s/sqrt(Hz)", "arw": "deg/sqrt(h)",
                      "bias_instability": "deg/h", "rate_random_walk": "deg/h/sqrt(h)",
                      "drift": "deg/s change over the record"}}


def text(doc: dict[str, Any]) -> str:
    """Readable summary of :func:`characterise_flight`."""
    lines = [f"characterisation of {doc['source']}: {doc['samples']} samples, "
             f"{doc['duration_s']:.1f} s at {doc['sample_rate_hz']:.4g} Hz"
             + ("; MOVING: the statistics include the motion" if doc["moving"] else
                "; at rest")]
    for g, r in doc["imus"].items():
        lines.append(f"  {g} ({', '.join(r['axes'])}):")

        def row(label: str, vals: list[float], fmt: str, sds: list[float] | None = None
                ) -> str:
            if sds is None:
                return f"    {label:<26s}" + "  ".join(fmt.format(v) for v in vals)
            return f"    {label:<26s}" + "  ".join(
                (fmt + " ± {:.2g}").format(v, s) for v, s in zip(vals, sds, strict=True))

        lines.append(row("mean [deg/s]", r["mean_dps"], "{:+.4f}"))
        lines.append(row("sd [deg/s]", r["std_dps"], "{:.4f}"))
        lines.append(row("density [deg/s/rtHz]", r["density_dps_rthz"], "{:.4f}",
                         r["density_dps_rthz_sd"]))
        lines.append(row("ARW N [deg/rt-h]", r["arw_deg_rth"], "{:.3g}"))
        lines.append(row("bias instab. B [deg/h]", r["bias_instability_dph"], "{:.3g}"))
        lines.append(row("rate RW K [deg/h/rt-h]", r["rate_random_walk_dph_rth"], "{:.3g}"))
        lines.append(row("excess kurtosis", r["excess_kurtosis"], "{:.2f}",
                         r["excess_kurtosis_sd"]))
        lines.append(row("beyond 4 sd (Gauss 6e-5)", r["tail_beyond_4sd"], "{:.2g}"))
        lines.append(row("drift over record [deg/s]", r["drift_dps"], "{:+.4f}",
                         r["drift_dps_sd"]))
        sig = [f"{a} ({d:+.4f} deg/s, z {z:+.1f}, p {p:.2g})" for a, d, z, p, s in zip(
            r["axes"], r["drift_dps"], r["drift_z"], r["drift_p"], r["drift_significant"],
            strict=True) if s]
        lines.append("    slow drift: " + ("; ".join(sig) if sig else
                                            "none significant") +
                     f" (alpha {doc['alpha']:g} over all axes; trend of {r['drift_block_s']:.3g}-s "
                     f"means, HAC over {r['drift_hac_lags']} of them)")
        if r["lines"]:
            lines.append("    lines: " + ", ".join(f"{ln['f_hz']:.2f} Hz "
                                                   f"({ln['ratio']:.1f}x floor)"
                                                   for ln in r["lines"]))
    sh = doc.get("shared") or {}
    if sh:
        lines.append(f"  shared modes: {sh['n_shared']} eigenvalue(s) of the correlation "
                     f"matrix above the independent-noise edge {sh['edge']:.3f} (largest "
                     + ", ".join(f"{v:.3f}" for v in sh["eigenvalues"][:3]) + ")")
        for k, v in enumerate(sh["vectors"]):
            top = sorted(zip(sh["axes"], v, strict=True), key=lambda a: -abs(a[1]))[:3]
            lines.append(f"    mode {k + 1}: mostly " + ", ".join(
                f"{a} ({w:+.2f})" for a, w in top))
    return "\n".join(lines)


_AXIS_COLOURS = {"x": "tab:blue", "y": "tab:orange", "z": "tab:green"}
_ALLAN_CI = 0.683
"""Confidence of the Allan deviation bands (1 sigma), allantools' chi-square interval."""


def _axis_colour(name: str, k: int) -> str:
    """One colour per axis family: the name's last letter (``imu1.x``, ``gx``) when it is
    x, y or z, else the k-th of three."""
    last = name.strip()[-1:].lower()
    return _AXIS_COLOURS.get(last, list(_AXIS_COLOURS.values())[k % 3])


def write_plots(doc: dict[str, Any], flight: Flight, out: Path) -> list[Path]:
    """PNG plots of the report into ``out``.

    - ``allan.png``: one panel per IMU, one colour per axis family (x, y, z): the Allan
      deviation with its 68 % confidence band (allantools' chi-square interval for white
      rate noise, ``edf_simple``) and, dashed, the fitted noise terms
      σ(τ)² = N²/τ + B²·2ln2/π + K²τ/3 with N, B, K in the legend;
    - ``drift.png``: one panel per IMU, the 10-s means of each axis minus their average,
      with the fitted linear drift and its z.
    """
    import allantools
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    paths = []
    imus = list(doc["imus"].items())
    n_samples = int(doc.get("samples", flight.t.shape[0]))
    fs = float(doc.get("sample_rate_hz", flight.sample_rate_hz))
    fig, axes = plt.subplots(1, len(imus), figsize=(4.2 * len(imus) + 1.5, 4.6),
                             squeeze=False, sharey=True)
    for ax, (g, r) in zip(axes[0], imus, strict=True):
        for k, (a, al) in enumerate(zip(r["axes"], r["allan"], strict=True)):
            c = _axis_colour(a, k)
            tau = np.asarray(al["tau_s"], float)
            dev = np.asarray(al["adev_dps"], float)
            lo, hi = np.empty_like(dev), np.empty_like(dev)
            for j, (tj, dj) in enumerate(zip(tau, dev, strict=True)):
                m = max(1, round(tj * fs))
                edf = allantools.edf_simple(n_samples, m, 0)
                lo[j], hi[j] = allantools.confidence_interval(dj, ci=_ALLAN_CI, edf=edf)
            ax.fill_between(tau, lo, hi, color=c, alpha=0.25, lw=0)
            ax.loglog(tau, dev, color=c, lw=1.2, label=a)
            n_ = r["arw_deg_rth"][k] / 60.0                     # deg/s/sqrt(Hz)
            b_ = r["bias_instability_dph"][k] / 3600.0          # deg/s
            k_ = r["rate_random_walk_dph_rth"][k] / 3600.0 / 60.0
            fit = np.sqrt(n_ ** 2 / tau + b_ ** 2 * 2 * math.log(2) / math.pi
                          + k_ ** 2 * tau / 3.0)
            ax.loglog(tau, fit, color=c, lw=0.9, ls="--",
                      label=f"fit: N {r['arw_deg_rth'][k]:.3g} deg/rt-h, "
                            f"B {r['bias_instability_dph'][k]:.3g} deg/h, "
                            f"K {r['rate_random_walk_dph_rth'][k]:.3g} deg/h/rt-h")
        ax.set_xlabel("tau [s]")
        ax.set_title(f"{g}", fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=6, loc="lower left")
    axes[0][0].set_ylabel("Allan deviation [deg/s] (band: 68 % confidence)")
    fig.suptitle("Allan deviation and fitted noise terms (dashed)", fontsize=10)
    p = out / "allan.png"
    fig.tight_layout()
    fig.savefig(p, dpi=110)
    plt.close(fig)
    paths.append(p)
    ok = flight.valid.all(axis=1)
    t, x = flight.t[ok], flight.raw[ok]
    q = max(1, round(10 * flight.sample_rate_hz))
    nb = t.shape[0] // q
    if nb >= 2:
        groups = flight.imu_groups() if flight.imu else {"set": list(range(flight.n))}
        fig, axes = plt.subplots(len(groups), 1, figsize=(8, 2.4 * len(groups) + 0.8),
                                 squeeze=False, sharex=True)
        tb = t[:nb * q].reshape(nb, q).mean(axis=1)
        for ax, (g, idx) in zip(axes[:, 0], groups.items(), strict=True):
            r = doc["imus"].get(g, {})
            for k, i in enumerate(idx):
                nm = flight.sensor_names[i]
                c = _axis_colour(nm, k)
                xb = x[:nb * q, i].reshape(nb, q).mean(axis=1) / DPS
                xb = xb - xb.mean()
                ch = r.get("drift_dps", [None] * len(idx))[k]
                z = r.get("drift_z", [None] * len(idx))[k]
                ax.plot(tb, xb, color=c, lw=1,
                        label=nm if ch is None else f"{nm}: {ch:+.3g} deg/s (z {z:+.1f})")
                if ch is not None:
                    ax.plot(tb[[0, -1]], [-ch / 2, ch / 2], color=c, lw=0.8, ls="--")
            ax.set_ylabel(f"{g} [deg/s]")
            ax.grid(True, alpha=0.3)
            ax.legend(fontsize=7, loc="upper left", ncol=3)
        axes[-1][0].set_xlabel("t [s]")
        fig.suptitle("slow drift: 10-s means minus their average; dashed: the fitted "
                     "linear change", fontsize=10)
        p = out / "drift.png"
        fig.tight_layout()
        fig.savefig(p, dpi=110)
        plt.close(fig)
        paths.append(p)
    return paths
