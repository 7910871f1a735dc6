"""Plots of an evaluation (matplotlib, Agg): ROC, delay against size, isolation confusion,
detectable size per scale. Each function takes the ``evaluation.json`` dictionary."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["plot_all", "plot_baselines"]


def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _roc(ev: dict[str, Any], path: Path) -> None:
    plt = _plt()
    fig, ax = plt.subplots(figsize=(5.5, 4))
    pts = [(r["false_alarms_per_hour"], r["pd_step_ramp"], r["multiplier"]) for r in ev["roc"]]
    x = np.array([p[0] for p in pts], float)
    y = np.array([p[1] for p in pts], float)
    ax.plot(np.maximum(x, 1e-3), y, "o-")
    for xi, yi, c in pts:
        ax.annotate(f"×{c:g}", (max(xi, 1e-3), yi), fontsize=7, xytext=(3, -8),
                    textcoords="offset points")
    ax.set_xscale("log")
    ax.set_xlabel("false alarms per hour (full set)")
    ax.set_ylabel("P(detect) step + ramp faults")
    ax.set_title("ROC: thresholds × multiplier")
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _delay(ev: dict[str, Any], path: Path) -> None:
    plt = _plt()
    from matplotlib.ticker import NullFormatter

    floor = 1.0 / float(ev["thresholds"].get("sample_rate_hz") or 100.0)
    kinds = sorted({f["fault"] for f in ev["faults"] if f["unit"] not in ("-",)})
    fig, axes = plt.subplots(1, max(1, len(kinds)), figsize=(3.2 * max(1, len(kinds)), 3.4),
                             squeeze=False)
    for ax, k in zip(axes[0], kinds, strict=False):
        rows = [f for f in ev["faults"] if f["fault"] == k]
        s = [f["size"] for f in rows]
        d = [np.nan if f["delay_s_median"] is None else max(f["delay_s_median"], floor)
             for f in rows]
        p = [np.nan if f["delay_s_p90"] is None else max(f["delay_s_p90"], floor)
             for f in rows]
        ax.plot(s, d, "o-", label="median")
        ax.plot(s, p, "s--", label="90 %")
        if all(v > 0 for v in s):
            ax.set_xscale("log")
        if np.any(np.asarray(d, float) > 0):
            ax.set_yscale("log")
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_title(k)
        ax.set_xlabel(f"size ({rows[0]['unit']})")
        ax.grid(True, which="both", alpha=0.3)
    axes[0][0].set_ylabel("detection delay (s; 0 drawn at one sample)")
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _confusion(ev: dict[str, Any], path: Path) -> None:
    plt = _plt()
    c = np.array(ev["isolation_confusion"]["counts"], float)
    n = c.shape[0]
    frac = c / np.maximum(c.sum(axis=1, keepdims=True), 1)
    fig, ax = plt.subplots(figsize=(5, 4))
    im = ax.imshow(frac, vmin=0, vmax=1, cmap="Blues")
    for i in range(n):
        for j in range(n + 1):
            if c[i, j]:
                ax.text(j, i, f"{int(c[i, j])}", ha="center", va="center", fontsize=7,
                        color="white" if frac[i, j] > 0.5 else "black")
    ax.set_xticks(range(n + 1), ["none"] + [str(k) for k in range(1, n + 1)])
    ax.set_yticks(range(n), [str(k) for k in range(1, n + 1)])
    ax.set_xlabel("isolated sensor")
    ax.set_ylabel("faulty sensor")
    ax.set_title("isolation (detected faults)")
    fig.colorbar(im, ax=ax, label="fraction of row")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _detectable(ev: dict[str, Any], path: Path) -> None:
    plt = _plt()
    rows = ev["detectable_sizes"]["per_scale"]
    w = [r["scale"] for r in rows]
    m = [np.nan if r["measured_sigma"] is None else r["measured_sigma"] for r in rows]
    lo = [np.nan if r["ci95_sigma"][0] is None else r["ci95_sigma"][0] for r in rows]
    hi = [np.nan if r["ci95_sigma"][1] is None else r["ci95_sigma"][1] for r in rows]
    fig, ax = plt.subplots(figsize=(5.5, 4))
    ax.errorbar(w, m, yerr=[np.subtract(m, lo), np.subtract(hi, m)], fmt="o",
                label="measured (probit fit, 95 %)")
    if "predicted_sigma" in rows[0]:
        ax.plot(w, [r["predicted_sigma"] for r in rows], "k--", label="rimu tune")
    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    ax.set_xlabel("window (samples)")
    ax.set_ylabel("step detected with 99 % (σ)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_all(ev: dict[str, Any], out: str | Path) -> list[Path]:
    """Write the PNGs of an evaluation into ``out``; returns their paths."""
    out = Path(out)
    paths = []
    jobs = [("roc.png", _roc, bool(ev.get("roc"))),
            ("delay_vs_size.png", _delay, bool(ev.get("faults"))),
            ("isolation_confusion.png", _confusion, bool(ev.get("faults"))),
            ("detectable_sizes.png", _detectable, "detectable_sizes" in ev)]
    for name, fn, ok in jobs:
        if ok:
            fn(ev, out / name)
            paths.append(out / name)
    return paths


def plot_baselines(ev: dict[str, Any], path: str | Path) -> Path:
    """rimu beside the autopilot rules (``ev["baselines"]``), per fault cell: probability of
    detection, of the right IMU blamed (rimu: its exclusion read per IMU) and the median
    detection delay."""
    plt = _plt()
    rules = ev["baselines"]["rules"]
    rimu = {(f["fault"], f["size"]): f for f in ev["faults"]}
    cells = [(f["fault"], f["size"]) for f in next(iter(rules.values()))["faults"]]
    labels = [f"{k} {s:g}" for k, s in cells]
    x = np.arange(len(cells))
    names = ["rimu", *rules]
    w = 0.8 / len(names)
    fig, axes = plt.subplots(3, 1, figsize=(max(6.0, 0.6 * len(cells) + 2), 8), sharex=True)
    for j, nm in enumerate(names):
        if nm == "rimu":
            first = next(iter(rules.values()))["faults"]
            pd = [rimu[c]["pd"] if c in rimu else np.nan for c in cells]
            pb = [f["rimu_p_isolation_imu"] for f in first]
            dl = [rimu[c]["delay_s_median"] if c in rimu else None for c in cells]
        else:
            fs = rules[nm]["faults"]
            pd = [f["pd"] for f in fs]
            pb = [f["p_blame_correct"] for f in fs]
            dl = [f["delay_s_median"] for f in fs]
        off = x - 0.4 + w * (j + 0.5)
        axes[0].bar(off, pd, w, label=nm)
        axes[1].bar(off, pb, w, label=nm)
        axes[2].bar(off, [np.nan if d is None else max(d, 1e-3) for d in dl], w, label=nm)
    axes[0].set_ylabel("P(detect)")
    axes[1].set_ylabel("P(right IMU blamed)")
    axes[2].set_ylabel("median delay (s)")
    axes[2].set_yscale("log")
    axes[0].legend(fontsize=7, ncol=len(names))
    axes[2].set_xticks(x)
    axes[2].set_xticklabels(labels, rotation=60, fontsize=7, ha="right")
    axes[0].set_title("rimu and the autopilot rules on the same samples")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
