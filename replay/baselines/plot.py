"""One time axis: the IMUs' rates, rimu's detections and exclusions, each baseline's flags
and blames (matplotlib, headless Agg)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from fdi.units import DPS
from replay.baselines.common import BaselineResult, Triads

__all__ = ["plot_baselines"]

_RIMU_MARKS = {"detected": ("x", "tab:orange"), "isolated": ("v", "tab:red"),
               "health": ("v", "tab:purple"), "disagree": (".", "tab:grey"),
               "readmitted": ("^", "tab:green")}


def _spans(ax: Any, t: np.ndarray, on: np.ndarray, color: str, label: str | None) -> None:
    """Shade the runs of ``on`` (bool, per sample)."""
    if not on.any():
        return
    edges = np.flatnonzero(np.diff(np.concatenate([[0], on.astype(np.int8), [0]])))
    for n, (a, b) in enumerate(zip(edges[::2], edges[1::2], strict=True)):
        ax.axvspan(t[a], t[b - 1], color=color, alpha=0.2, lw=0,
                   label=label if n == 0 else None)


def plot_baselines(path: str | Path, triads: Triads, results: Mapping[str, BaselineResult],
                   report: Mapping[str, Any] | None = None, *,
                   faults: Sequence[Any] = ()) -> Path:
    """Write the plot to ``path`` (PNG) and return it.

    Panels, sharing the time axis: each IMU's rates (°/s, or m/s²); rimu's events per
    sensor (``report``: its ``rimu.report/1``); per baseline its measure per IMU with the
    fault threshold, the flagged spans shaded and the blames marked. Injected faults are
    drawn as vertical lines.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    nb = len(results)
    fig, axes = plt.subplots(2 + nb, 1, sharex=True, figsize=(11, 2.4 * (2 + nb)),
                             squeeze=False)
    ax = axes[:, 0]
    _samples_panel(ax[0], triads)
    if report:
        _rimu_panel(ax[1], report)
    ax[1].set_title("rimu: detections, exclusions (isolated / health), disagreements",
                    fontsize=9)
    for k, (nm, r) in enumerate(results.items()):
        _baseline_panel(ax[2 + k], nm, r)
    for fl in faults:
        for a in ax:
            a.axvline(fl.onset, color="k", lw=0.8, alpha=0.6)
    ax[-1].set_xlabel("time (s)")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110, format="png")
    plt.close(fig)
    return path


def _samples_panel(ax: Any, triads: Triads) -> None:
    """Each IMU's x, y, z samples (°/s for gyros, m/s² for accelerometers).

    Parameters
    ----------
    ax : matplotlib Axes
    triads : Triads
    """
    t = triads.t
    gyro = triads.kind == "gyro"
    f = 1.0 / DPS if gyro else 1.0
    for j, nm in enumerate(triads.imus):
        for a in range(3):
            ax.plot(t, triads.values[:, j, a] * f, lw=0.5, color=f"C{j}",
                    alpha=(1.0, 0.7, 0.45)[a], label=f"{nm}" if a == 0 else None)
    ax.set_ylabel("rate (deg/s)" if gyro else "specific force (m/s^2)")
    ax.legend(loc="upper right", fontsize=7, ncol=len(triads.imus))
    ax.set_title("IMU samples (x, y, z of each IMU: full to light)", fontsize=9)


def _rimu_panel(ax: Any, report: Mapping[str, Any]) -> None:
    """rimu's events per sensor (row 0: the set), marked by type.

    Parameters
    ----------
    ax : matplotlib Axes
    report : mapping
        rimu's ``rimu.report/1``.
    """
    names = list(report.get("sensor_names", []))
    seen: set[str] = set()
    for e in report.get("events", []):
        mk = _RIMU_MARKS.get(e["type"])
        if mk is None:
            continue
        sensors = e.get("sensors") or ([e["sensor"]] if e.get("sensor") else [0])
        for s in sensors:
            ax.scatter([e["t"]], [s], marker=mk[0], color=mk[1], s=22,
                       label=e["type"] if e["type"] not in seen else None)
            seen.add(e["type"])
    ax.set_yticks(range(0, len(names) + 1))
    ax.set_yticklabels(["set", *names], fontsize=6)
    if seen:
        ax.legend(loc="upper right", fontsize=7, ncol=len(seen))


def _baseline_panel(a: Any, nm: str, r: BaselineResult) -> None:
    """One baseline's measure per IMU, its threshold, flagged spans and blames.

    Parameters
    ----------
    a : matplotlib Axes
    nm : str
        The baseline's name.
    r : BaselineResult
    """
    _spans(a, r.t, r.flagged, "tab:red", "flagged")
    for j, imu in enumerate(r.imus):
        a.plot(r.t, r.measure[:, j], lw=0.7, color=f"C{j}", label=imu)
    a.axhline(r.threshold, color="k", ls="--", lw=0.8, label="fault threshold")
    for e in r.events:
        if e.type == "flagged" and e.imu is not None:
            j = r.imus.index(e.imu)
            a.annotate(f"blames {e.imu}", (e.t, r.threshold), fontsize=7,
                       color=f"C{j}", rotation=90, va="bottom")
    a.set_ylabel(r.measure_unit)
    a.set_title(f"{nm}: {r.rule}", fontsize=8)
    a.legend(loc="upper right", fontsize=7, ncol=len(r.imus) + 2)
