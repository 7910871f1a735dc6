"""PNG pictures of a monitoring run (matplotlib, Agg: no display needed).

One module draws every monitoring run's picture: ``rimu demo``, ``rimu monitor-file
--report``, ``rimu replay --report`` and ``rimu diagnose --report`` (a flight).

:class:`RunTrace` follows a run fed in pieces in bounded memory (at most
:data:`MAX_BINS` time bins: when full, neighbouring bins merge and each bin covers twice
the samples). Per bin it keeps the estimated body rates ω̂ (mean, min, max per axis), whether
any sample of the bin had an unverified body axis or lay outside the operating envelope,
and the largest ratio statistic / threshold of each detector scale. :func:`plot_run` draws
it with the run's events, injected faults and envelope periods (the ``rimu.report/1``
dictionary's) in three panels sharing the time axis:

1. ω̂ (°/s) per axis, the unverified spans shaded, the envelope excursions hatched;
2. statistic / threshold per window (log scale; an alarm where a line crosses 1);
3. the events per sensor (detections, disagreements, isolations, health, readmissions)
   and the injected faults from their onset.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from fdi.units import DPS

__all__ = ["MAX_BINS", "RunTrace", "plot_run", "scale_labels", "spans"]

MAX_BINS = 4096
"""Time bins a :class:`RunTrace` keeps at most (about 0.3 MB)."""

_EVENT_STYLE = {"detected": ("v", "tab:orange"), "disagree": ("d", "tab:purple"),
                "isolated": ("X", "tab:red"), "health": ("s", "tab:brown"),
                "readmitted": ("^", "tab:green"), "envelope": ("o", "tab:gray")}
_AXIS_COLOURS = ("tab:blue", "tab:orange", "tab:green")


class RunTrace:
    """A monitoring run's time series, binned to at most :data:`MAX_BINS` bins.

    Each bin holds ``per_bin`` consecutive samples (the last one fewer, until it fills);
    the bins of a run fed in pieces are those of the run fed at once.

    Parameters
    ----------
    max_bins : int
        Bins kept at most (even, ≥ 2).
    """

    # a bin's row: t0, t1, sum ω̂ (3), finite count (3), min (3), max (3), unverified (3),
    # out of envelope, ratio (K): every column combines associatively (see _combine)
    def __init__(self, max_bins: int = MAX_BINS) -> None:
        self.max_bins = max(2, int(max_bins) // 2 * 2)
        self.per_bin = 1  # samples per full bin
        self.scales = 0  # detector columns (K)
        self._buf: np.ndarray | None = None  # the full bins (allocated once: flat memory)
        self._n_full = 0
        self._open: np.ndarray | None = None  # the bin filling up
        self._open_n = 0
        self._started = False

    def update(self, result: Any) -> None:
        """Add one piece of answers (``fdi.answer.BlockResult``, or anything with ``t``,
        ``omega`` (N, 3) rad/s, ``statistics`` and ``thresholds`` (N, K), optional
        ``unverified`` (N, 3) and ``envelope`` (N,))."""
        t = np.asarray(result.t, float)
        N = t.shape[0]
        if N == 0:
            return
        stats = np.asarray(result.statistics, float).reshape(N, -1)
        thr = np.asarray(result.thresholds, float).reshape(N, -1)
        if not self._started:
            self.scales, self._started = stats.shape[1], True
            self._buf = np.empty((self.max_bins, 18 + self.scales))
        if stats.shape[1] != self.scales:
            return  # another monitor's answers: not mixed in
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(thr > 0, stats / thr, np.nan)
        omega = np.asarray(result.omega, float).reshape(N, 3) / DPS
        fin = np.isfinite(omega)
        unv = getattr(result, "unverified", None)
        unv = (np.asarray(unv, float) if unv is not None and np.shape(unv) == (N, 3)
               else np.zeros((N, 3)))
        env = getattr(result, "envelope", None)
        out = (np.asarray(env, float) != 0 if env is not None and np.shape(env) == (N,)
               else np.zeros(N, bool))
        rows = np.column_stack([t, t, np.where(fin, omega, 0.0), fin.astype(float),
                                np.where(fin, omega, np.inf), np.where(fin, omega, -np.inf),
                                unv, out.astype(float), ratio])
        k = 0
        while k < N:                  # in time order: the open bin, full bins, a new open
            if self._open is not None:
                take = min(self.per_bin - self._open_n, N - k)
                self._open = _combine(np.vstack([self._open[None], rows[k:k + take]]))
                self._open_n += take
                k += take
                if self._open_n == self.per_bin:
                    done, self._open, self._open_n = self._open, None, 0
                    self._push(done[None])      # a merge may open the last bin again
                continue
            full = (N - k) // self.per_bin * self.per_bin
            if full:
                self._push(_combine(rows[k:k + full].reshape(-1, self.per_bin,
                                                             rows.shape[1]), axis=1))
                k += full
                continue
            self._open, self._open_n = _combine(rows[k:]), N - k
            k = N
        if self._n_full + (self._open is not None) > self.max_bins:
            self._fit(self._buf[:self._n_full].copy())

    def _push(self, bins: np.ndarray) -> None:
        """Append full bins, merging neighbours (each bin then covers twice the samples)
        until they and the open bin fit in :attr:`max_bins`."""
        n, k = self._n_full, bins.shape[0]
        if n + k + (self._open is not None) <= self.max_bins:
            self._buf[n:n + k] = bins
            self._n_full = n + k
            return
        self._fit(np.vstack([self._buf[:n], bins]))

    def _fit(self, b: np.ndarray) -> None:
        """Full bins ``b`` merged until they and the open bin fit, into the buffer."""
        while b.shape[0] + (self._open is not None) > self.max_bins:
            b = self._merge(b)
        self._buf[:b.shape[0]] = b
        self._n_full = b.shape[0]

    def _merge(self, b: np.ndarray) -> np.ndarray:
        """Neighbouring bins of ``b`` merged; an odd last one becomes (part of) the open
        bin."""
        odd = b.shape[0] % 2
        pairs = b[: b.shape[0] - odd]
        self.per_bin *= 2
        out = (_combine(pairs.reshape(-1, 2, b.shape[1]), axis=1) if pairs.size
               else b[:0])
        if odd:                                     # half a new bin: it opens again
            parts = [b[-1:]] + ([self._open[None]] if self._open is not None else [])
            self._open = _combine(np.vstack(parts))
            self._open_n = self.per_bin // 2 + self._open_n
        return out

    def bins(self) -> dict[str, np.ndarray]:
        """The bins so far (the open one included), as arrays.

        Returns
        -------
        dict
            ``t0``, ``t1`` (B,) s; ``mean``, ``min``, ``max`` (B, 3) °/s (NaN where a bin
            had no finite ω̂); ``unverified`` (B, 3) bool; ``out_of_envelope`` (B,) bool;
            ``ratio`` (B, K) largest statistic / threshold per detector column.
        """
        full = self._buf[:self._n_full] if self._buf is not None else np.zeros((0, 18))
        b = np.vstack([full, self._open[None]]) if self._open is not None else full.copy()
        cnt = b[:, 5:8]
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = np.where(cnt > 0, b[:, 2:5] / cnt, np.nan)
        return {"t0": b[:, 0], "t1": b[:, 1], "mean": mean,
                "min": np.where(cnt > 0, b[:, 8:11], np.nan),
                "max": np.where(cnt > 0, b[:, 11:14], np.nan),
                "unverified": b[:, 14:17] > 0, "out_of_envelope": b[:, 17] > 0,
                "ratio": b[:, 18:]}


def _combine(r: np.ndarray, axis: int = 0) -> np.ndarray:
    """Rows (along ``axis``) combined into one bin row each (see RunTrace)."""
    r = np.moveaxis(r, axis, -2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN ratio columns stay NaN
        return np.concatenate([
            r[..., 0, 0:1], r[..., -1, 1:2], r[..., 2:8].sum(axis=-2),
            r[..., 8:11].min(axis=-2), r[..., 11:14].max(axis=-2),
            r[..., 14:18].max(axis=-2), np.nanmax(r[..., 18:], axis=-2)], axis=-1)


def _break_gaps(b: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """A NaN bin inserted into each time gap (wider than 3 bins) so lines break there."""
    t0, t1 = b["t0"], b["t1"]
    if t0.size < 3:
        return b
    width = float(np.median(t1 - t0)) + float(np.median(np.diff(t0))) * 0.5
    gap = np.flatnonzero(t0[1:] - t1[:-1] > 3 * max(width, 1e-12)) + 1
    if gap.size == 0:
        return b
    out = {}
    for k, v in b.items():
        if k in ("t0", "t1"):
            fill = 0.5 * (t1[gap - 1] + t0[gap])
        elif v.dtype == bool:
            fill = False
        else:
            fill = np.nan
        out[k] = np.insert(v, gap, fill, axis=0)
    return out


def scale_labels(thresholds: Any, K: int) -> list[str] | None:
    """Names of a monitor's K detector columns from its thresholds (``"window 8"`` per
    dyadic scale, then ``"cusum"``), or None when they do not match K."""
    if thresholds is None:
        return None
    names = [f"window {int(w)}" for w in thresholds.scales]
    if getattr(thresholds, "detector", "windows") != "windows":
        names.append("cusum")
    return names if len(names) == K else None


def spans(t0: np.ndarray, t1: np.ndarray, flag: np.ndarray) -> list[tuple[float, float]]:
    """Contiguous runs of ``flag`` as ``(start, end)`` times (s), from bins' ``t0``/``t1``."""
    f = np.asarray(flag, bool)
    if f.size == 0:
        return []
    edges = np.flatnonzero(np.diff(np.concatenate([[0], f.astype(np.int8), [0]])))
    return [(float(t0[a]), float(t1[b - 1])) for a, b in zip(edges[::2], edges[1::2],
                                                             strict=True)]


def plot_run(trace: RunTrace, path: str | Path, *, report: Mapping[str, Any] | None = None,
             scale_names: Sequence[str] | None = None, title: str | None = None) -> Path:
    """Draw a monitoring run (see the module docstring) into the PNG ``path``.

    Parameters
    ----------
    trace : RunTrace
    path : path
        The PNG to write.
    report : dict, optional
        The run's ``rimu.report/1`` dictionary: events, faults (with truth), envelope
        periods, sensor names and source.
    scale_names : sequence of str, optional
        Names of the detector columns (``"window 8"``, ``"cusum"``); default ``"scale j"``.
    title : str, optional

    Returns
    -------
    Path
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rep = dict(report or {})
    b = _break_gaps(trace.bins())
    fig, (ax1, ax2, ax3) = plt.subplots(3, 1, figsize=(11, 8.5), sharex=True,
                                        gridspec_kw={"height_ratios": [3, 3, 2]})
    unv = _rates_panel(ax1, ax2, trace, b, rep)
    _ratio_panel(ax2, b, scale_names, unv, plt.get_cmap("viridis"))
    _events_panel(ax3, b["t1"], rep)
    ttl = title or f"monitoring run: {rep.get('source', '')}"
    if trace.per_bin > 1:
        ttl += f"  (bins of {trace.per_bin} samples: band min-max, line mean)"
    fig.suptitle(ttl, fontsize=10)
    fig.tight_layout()
    p = Path(path)
    fig.savefig(p, dpi=100)
    plt.close(fig)
    return p


def _rates_panel(ax1: Any, ax2: Any, trace: RunTrace, b: dict[str, np.ndarray],
                 rep: Mapping[str, Any]) -> list[tuple[float, float]]:
    """Panel 1 of :func:`plot_run`: the rates, unverified spans shaded, envelope excursions
    hatched (on panel 2 too); returns the unverified spans."""
    t0, t1 = b["t0"], b["t1"]
    tm = 0.5 * (t0 + t1)
    for j, a in enumerate("xyz"):
        c = _AXIS_COLOURS[j]
        if trace.per_bin > 1:
            ax1.fill_between(tm, b["min"][:, j], b["max"][:, j], color=c, alpha=0.25, lw=0)
        ax1.plot(tm, b["mean"][:, j], color=c, lw=0.8, label=f"ω̂{a}")
    unv = spans(t0, t1, b["unverified"].any(axis=1))
    for k, (a, z) in enumerate(unv):
        ax1.axvspan(a, z, color="gold", alpha=0.35, lw=0,
                    label="unverified (sensors disagree)" if k == 0 else None)
    periods = [(float(p["t0_s"]), float(p["t1_s"]), p.get("reasons", []))
               for p in (rep.get("summary") or {}).get("envelope_periods", [])]
    if not periods:
        periods = [(a, z, []) for a, z in spans(t0, t1, b["out_of_envelope"])]
    for k, (a, z, _) in enumerate(periods):
        for ax in (ax1, ax2):
            ax.axvspan(a, z, facecolor="none", edgecolor="0.4", hatch="//", lw=0,
                       label="out of envelope" if k == 0 and ax is ax1 else None)
    ax1.set_ylabel("ω̂ (°/s)")
    ax1.legend(loc="upper right", fontsize=8, ncol=5)
    ax1.grid(alpha=0.3)
    return unv


def _ratio_panel(ax2: Any, b: dict[str, np.ndarray], scale_names: Sequence[str] | None,
                 unv: list[tuple[float, float]], cmap: Any) -> None:
    """Panel 2 of :func:`plot_run`: statistic / threshold per detector column."""
    tm = 0.5 * (b["t0"] + b["t1"])
    K = b["ratio"].shape[1]
    labels = list(scale_names) if scale_names is not None and len(scale_names) == K \
        else [f"scale {j + 1}" for j in range(K)]
    for j in range(K):
        r = b["ratio"][:, j]
        ax2.plot(tm, np.where(r > 0, r, np.nan), lw=0.8, color=cmap(j / max(K - 1, 1)),
                 label=labels[j])
    ax2.axhline(1.0, color="k", lw=1.2, ls="--", label="threshold")
    if np.any(np.nan_to_num(b["ratio"]) > 0):
        ax2.set_yscale("log")
        top = float(np.nanmax(np.where(b["ratio"] > 0, b["ratio"], np.nan)))
        ax2.set_ylim(1e-3, max(10.0, 2.0 * top))      # below 1/1000 of the threshold: noise
    ax2.set_ylabel("statistic / threshold")
    ax2.legend(loc="upper left", fontsize=7, ncol=min(K + 1, 6))
    ax2.grid(alpha=0.3, which="both")
    for a, z in unv:
        ax2.axvspan(a, z, color="gold", alpha=0.25, lw=0)


def _fault_marks(ax3: Any, t1: np.ndarray, faults: Sequence[Mapping[str, Any]]) -> set[str]:
    """The injected faults of panel 3, a bar from onset to the end; returns the legend
    entries drawn (``{"fault"}`` or none)."""
    seen: set[str] = set()
    for f in faults:
        s, on = f.get("sensor"), f.get("onset")
        if isinstance(s, int) and on is not None:
            end = float(t1[-1]) if t1.size else float(on)
            ax3.plot([float(on), end], [s, s], color="tab:red", lw=6, alpha=0.25,
                     solid_capstyle="butt",
                     label="injected fault" if "fault" not in seen else None)
            ax3.annotate(str(f.get("spec", "")), (float(on), s + 0.25), fontsize=7)
            seen.add("fault")
    return seen


def _events_panel(ax3: Any, t1: np.ndarray, rep: Mapping[str, Any]) -> None:
    """Panel 3 of :func:`plot_run`: events and injected faults per sensor."""
    names = list(rep.get("sensor_names") or [])
    events = list(rep.get("events") or [])
    n = len(names) or max([int(e["sensor"]) for e in events
                           if isinstance(e.get("sensor"), int)] + [1])
    seen = _fault_marks(ax3, t1, rep.get("faults") or [])
    for e in events:
        ty = e.get("type", "")
        mk, col = _EVENT_STYLE.get(ty, ("o", "k"))
        s = e.get("sensor")
        ys = [s] if isinstance(s, int) else (list(e.get("sensors") or []) or [0])
        for y in ys:
            ax3.plot([float(e["t"])], [y], mk, color=col, ms=7,
                     label=ty if ty not in seen else None)
            seen.add(ty)
    ax3.set_yticks(range(0, n + 1))
    ax3.set_yticklabels(["set"] + [f"{k + 1} {names[k]}" if k < len(names) else str(k + 1)
                                   for k in range(n)], fontsize=8)
    ax3.set_ylim(-0.7, n + 0.7)
    ax3.set_ylabel("sensor")
    ax3.set_xlabel("time (s)")
    ax3.grid(alpha=0.3)
    if seen:
        ax3.legend(loc="upper left", fontsize=7, ncol=7)

