"""``rimu diagnose --report DIR``: a Markdown page with PNG plots (matplotlib, Agg).

Plots: per-step residual means with their σ, before and after the refit; the residual
against the regressor of each claimed effect, before and after (binned means); the
residual spectrum (Welch) before and after.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import scipy.signal

from calibration.diagnose.context import kind_data
from calibration.diagnose.library import get_candidate, model_effects
from calibration.diagnose.metrics import RESIDUAL_UNITS
from calibration.diagnose.run import Diagnosis
from calibration.session import Session
from fdi.calfile import Calibration
from fdi.units import input_unit_factor

__all__ = ["write_report"]


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _step_means(d, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    m, s = [], []
    for k in d.steps:
        rk = r[d.step == k]
        m.append(rk.mean(axis=0))
        s.append(rk.std(axis=0, ddof=1) / np.sqrt(rk.shape[0]))
    return np.array(m), np.array(s)


def write_report(session: Session, cal: Calibration, diag: Diagnosis,
                 directory: str | Path) -> Path:
    """Write ``DIR/diagnosis.md`` and its PNGs; returns the page's path."""
    plt = _plt()
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    before = model_effects(kind_data(session, cal), cal.effects)
    after = model_effects(kind_data(session, diag.calibration), diag.calibration.effects)
    lines = ["# Diagnosis", "", f"Session `{session.source}`, level α = {diag.alpha:g}.", ""]
    lines += _effect_lines(diag.effects)
    lines.append("")
    lines += _holdout_lines(diag.holdout)
    lines.append("Unexplained structure: " + ("yes, " + "; ".join(
        f"{u['kind']} {u['sensor']} ({u['test']})" for u in diag.unexplained_detail)
        if diag.unexplained else "none") + ".")
    lines.append("")
    for kind, d in before.items():
        f = input_unit_factor(RESIDUAL_UNITS[kind])
        unit = RESIDUAL_UNITS[kind]
        rb, ra = d.y / f, after[kind].y / f
        lines += _rms_table(kind, d, diag)
        lines += _plot_step_means(plt, out, kind, d, rb, ra, unit)
        lines += _plot_spectrum(plt, out, kind, d, rb, ra, unit)
        for e in diag.effects:
            if e["kind"] == kind:
                lines += _plot_effect(plt, out, kind, d, rb, ra, unit, e)
    page = out / "diagnosis.md"
    page.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return page


def _effect_lines(effects: list[dict[str, Any]]) -> list[str]:
    """The table of the claimed effects and their bound notes, or "No effect found."

    Parameters
    ----------
    effects : list of dict
        :attr:`Diagnosis.effects`.

    Returns
    -------
    list of str
    """
    if not effects:
        return ["No effect found."]
    lines = ["| effect | sensor | estimate | σ | unit | p |", "|---|---|---|---|---|---|"]
    lines += [f"| {e['name']} | {e['kind']} {e['sensors'][0]} | {e['estimate']:.4g} | "
              f"{e['estimate_sd']:.2g} | {e['unit']} | {e['p_value']:.2g} |"
              for e in effects]
    notes = [f"- {e['name']} on {e['kind']} {e['sensors'][0]}: {e['bound_note']}"
             for e in effects if e.get("bound_note")]
    return lines + (["", *notes] if notes else [])


def _holdout_lines(h: dict[str, Any] | None) -> list[str]:
    """The held-out check's sentence and a blank line; nothing when it was not run.

    Parameters
    ----------
    h : dict or None
        :attr:`Diagnosis.holdout`.

    Returns
    -------
    list of str
    """
    if not h:
        return []
    w = h.get("worst")
    verdict = ("passed" if h["passed"] else "failed: " + "; ".join(
        f"{f['kind']} {f['sensor']} fold {f['fold']} p {f['p_value']:.2g}"
        for f in h["failed"]))
    worst = f" (worst p {w['p_value']:.2g})" if w and h["passed"] else ""
    return [f"Held-out check (each of {h.get('folds_tested', 0)} sensor-folds refitted "
            f"without its steps and predicted, limit p < {h['threshold']:.2g}): "
            + verdict + worst + ".", ""]


def _rms_table(kind: str, d: Any, diag: Diagnosis) -> list[str]:
    """The section heading of one kind and its table of residual rms and step χ²/dof.

    Parameters
    ----------
    kind : str
    d : KindData
        Its data (:func:`calibration.diagnose.context.kind_data`).
    diag : Diagnosis

    Returns
    -------
    list of str
    """
    eb, ea = diag.error_before, diag.error_after
    lines = [f"## {kind}", "", "| sensor | rms before | rms after | step χ²/dof before | "
             "after |", "|---|---|---|---|---|"]
    lines += [f"| {d.names[i]} | {eb['residual_rms'][kind][i]:.4g} | "
              f"{ea['residual_rms'][kind][i]:.4g} | {eb['step_chi2_dof'][kind][i]:.2f} | "
              f"{ea['step_chi2_dof'][kind][i]:.2f} |" for i in range(d.n)]
    return [*lines, ""]


def _plot_step_means(plt: Any, out: Path, kind: str, d: Any, rb: np.ndarray, ra: np.ndarray,
                     unit: str) -> list[str]:
    """Plot the per-step residual means ± σ before and after; the page's lines for it.

    Parameters
    ----------
    plt : module
        matplotlib.pyplot.
    out : Path
        The report's directory.
    kind : str
    d : KindData
    rb, ra : ndarray, shape (N, n)
        Residuals before and after (``unit``).
    unit : str

    Returns
    -------
    list of str
    """
    fig, axes = plt.subplots(d.n, 1, figsize=(8, 1.6 * d.n + 1), sharex=True,
                             squeeze=False)
    mb, sb = _step_means(d, rb)
    ma, sa = _step_means(d, ra)
    x = np.arange(len(d.steps))
    for i, ax in enumerate(axes[:, 0]):
        ax.errorbar(x - 0.1, mb[:, i], sb[:, i], fmt="o", ms=3, label="before")
        ax.errorbar(x + 0.1, ma[:, i], sa[:, i], fmt="s", ms=3, label="after")
        ax.axhline(0, color="0.6", lw=0.5)
        ax.set_ylabel(f"{d.names[i]} [{unit}]")
    axes[-1, 0].set_xticks(x, [str(k) for k in d.steps])
    axes[-1, 0].set_xlabel("step")
    axes[0, 0].legend(fontsize=7)
    fig.suptitle(f"{kind}: per-step residual means ± σ")
    p = out / f"{kind}_step_means.png"
    fig.savefig(p, dpi=90)
    plt.close(fig)
    return [f"![per-step means]({p.name})", ""]


def _plot_spectrum(plt: Any, out: Path, kind: str, d: Any, rb: np.ndarray, ra: np.ndarray,
                   unit: str) -> list[str]:
    """Plot the residual spectra (Welch) before and after; the page's lines for it.

    Parameters
    ----------
    plt, out, kind, d, rb, ra, unit
        As :func:`_plot_step_means`.

    Returns
    -------
    list of str
    """
    fig, ax = plt.subplots(figsize=(8, 3.5))
    for i in range(d.n):
        fb_, Pb = scipy.signal.welch(rb[:, i], fs=d.sample_rate_hz, nperseg=4096)
        _, Pa = scipy.signal.welch(ra[:, i], fs=d.sample_rate_hz, nperseg=4096)
        ax.loglog(fb_[1:], np.sqrt(Pb[1:]), lw=0.8, label=f"{d.names[i]} before")
        ax.loglog(fb_[1:], np.sqrt(Pa[1:]), lw=0.8, ls="--", label=f"{d.names[i]} after")
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel(f"[{unit}/√Hz]")
    ax.legend(fontsize=6, ncol=2)
    ax.set_title(f"{kind}: residual spectrum")
    p = out / f"{kind}_spectrum.png"
    fig.savefig(p, dpi=90)
    plt.close(fig)
    return [f"![spectrum]({p.name})", ""]


def _plot_effect(plt: Any, out: Path, kind: str, d: Any, rb: np.ndarray, ra: np.ndarray,
                 unit: str, e: dict[str, Any]) -> list[str]:
    """Plot the residual against one claimed effect's regressor (binned means) before and
    after; the page's lines for it.

    Parameters
    ----------
    plt, out, kind, d, rb, ra, unit
        As :func:`_plot_step_means`.
    e : dict
        The effect (one of :attr:`Diagnosis.effects`, of this kind).

    Returns
    -------
    list of str
    """
    i = e["sensors"][0] - 1
    c = get_candidate(e["name"])
    z = c.columns(d, i, e["params"])[:, 0]
    order = np.argsort(z)
    bins = np.array_split(order, min(40, z.size))
    zc = np.array([z[b].mean() for b in bins])
    fig, ax = plt.subplots(figsize=(6, 3.5))
    ax.plot(zc, [rb[b, i].mean() for b in bins], "o", ms=3, label="before")
    ax.plot(zc, [ra[b, i].mean() for b in bins], "s", ms=3, label="after")
    ax.set_xlabel(f"{e['name']} regressor (SI per {e['unit']})")
    ax.set_ylabel(f"{d.names[i]} residual [{unit}]")
    ax.legend(fontsize=7)
    ax.set_title(f"{kind} {d.names[i]}: residual against {e['name']}")
    p = out / f"{kind}_{i + 1}_{e['name']}.png"
    fig.savefig(p, dpi=90)
    plt.close(fig)
    return [f"![{e['name']}]({p.name})", ""]
