"""Segments of a flight to leave out, found from the data.

- ``saturation``: a gyro or accelerometer channel sits at its largest magnitude for at
  least :data:`CLIP_RUN` samples in a row (a clipped sensor repeats its full-scale value);
- ``shock``: the specific-force magnitude of an IMU exceeds :data:`SHOCK_G` g (an impact:
  hard take-off or landing, crash); labelled ``crash`` when it is followed by no motion
  or by the end of the log, ``take-off`` when it comes before the first motion;
- ``gap``: the samples next to a gap in the time base (more than two sample periods);
- ``invalid``: a sample some sensor did not send.

Every segment is widened by :data:`PAD_S` on both sides and overlapping ones are merged.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fdi.units import G0
from replay.flight_data import Flight

__all__ = ["CLIP_RUN", "PAD_S", "SHOCK_G", "Segment", "find_segments", "keep_mask"]

CLIP_RUN = 3
"""Consecutive samples at the channel's extreme value that count as saturation."""
SHOCK_G = 4.0
"""Specific force (g) above which a sample is an impact."""
PAD_S = 0.5
"""Margin (s) added on both sides of every segment."""


@dataclass(frozen=True)
class Segment:
    """A time span to leave out: ``[t0_s, t1_s]`` and why."""

    t0_s: float
    t1_s: float
    reason: str
    detail: str = ""

    def to_dict(self) -> dict[str, object]:
        """JSON-ready."""
        return {"t0_s": self.t0_s, "t1_s": self.t1_s, "reason": self.reason,
                "detail": self.detail}


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) index pairs of the True runs of a boolean vector."""
    d = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1), strict=True))


def _clipped(x: np.ndarray) -> np.ndarray:
    """Samples where a channel repeats its extreme magnitude CLIP_RUN times or more."""
    out = np.zeros(x.shape[0], bool)
    a = np.abs(x)
    if not np.isfinite(a).any():
        return out
    top = np.nanmax(a)
    if not top > 0:
        return out
    at = a >= top * (1 - 1e-9)
    for s, e in _runs(at):
        if e - s >= CLIP_RUN:
            out[s:e] = True
    return out


def _saturation_and_shock(flight: Flight) -> tuple[np.ndarray, np.ndarray]:
    """Samples where a gyro or accelerometer channel sits at full scale, and samples whose
    specific force (per IMU, three accelerometer axes) exceeds ``SHOCK_G``; shape (N,)."""
    N = flight.t.shape[0]
    sat = np.zeros(N, bool)
    for i in range(flight.n):
        sat |= _clipped(flight.raw[:, i])
    acc = flight.aux.select("accel") if flight.aux is not None else None
    shock = np.zeros(N, bool)
    if acc is None or not acc.m:
        return sat, shock
    for j in range(acc.m):
        sat |= _clipped(acc.values[:, j])
    for g in sorted(set(acc.imu)):
        cols = [k for k, h in enumerate(acc.imu) if h == g]
        if len(cols) == 3:
            mag = np.linalg.norm(acc.values[:, cols], axis=1)
            shock |= np.nan_to_num(mag, nan=0.0) > SHOCK_G * G0
    return sat, shock


def _gap_samples(flight: Flight) -> np.ndarray:
    """The samples on either side of a jump of the time base by more than two periods."""
    t = flight.t
    gap = np.zeros(t.shape[0], bool)
    if t.shape[0] > 1 and flight.sample_rate_hz > 0:
        big = np.flatnonzero(np.diff(t) > 2.0 / flight.sample_rate_hz)
        gap[big] = True
        gap[big + 1] = True
    return gap


def find_segments(flight: Flight) -> list[Segment]:
    """Segments to leave out (module docstring), sorted by time, merged, padded."""
    t = flight.t
    N = t.shape[0]
    if N == 0:
        return []
    sat, shock = _saturation_and_shock(flight)
    flags: list[tuple[np.ndarray, str, str]] = [
        (sat, "saturation", "a channel repeats its full-scale value"),
        (_gap_samples(flight), "gap", "time base jumps by more than two sample periods")]
    flags.append((~flight.valid.all(axis=1), "invalid", "a sensor sent no sample"))
    moving = _moving(flight)
    first_move = int(np.argmax(moving)) if moving.any() else N
    last_move = N - 1 - int(np.argmax(moving[::-1])) if moving.any() else -1
    segs: list[Segment] = []
    for s, e in _runs(shock):
        reason = ("take-off" if e <= first_move else "crash" if s >= last_move - 1
                  else "shock")
        segs.append(Segment(float(t[s]), float(t[e - 1]), reason,
                            f"specific force above {SHOCK_G:g} g"))
    for mask, reason, why in flags:
        segs.extend(Segment(float(t[s]), float(t[e - 1]), reason, why)
                    for s, e in _runs(mask))
    return _merge(sorted(segs, key=lambda g: g.t0_s))


def _moving(flight: Flight) -> np.ndarray:
    """Samples where the body turns: rate magnitude (first IMU) above 0.1 rad/s."""
    k = min(3, flight.n)
    r = np.linalg.norm(np.nan_to_num(flight.raw[:, :k]), axis=1)
    base = np.median(r[: max(1, r.shape[0] // 20)])
    return r > base + 0.1


def _merge(segs: list[Segment]) -> list[Segment]:
    out: list[Segment] = []
    for g in segs:
        a, b = g.t0_s - PAD_S, g.t1_s + PAD_S
        if out and a <= out[-1].t1_s and out[-1].reason == g.reason:
            p = out[-1]
            out[-1] = Segment(p.t0_s, max(p.t1_s, b), p.reason, p.detail)
        else:
            out.append(Segment(a, b, g.reason, g.detail))
    return out


def keep_mask(t: np.ndarray, segments: list[Segment]) -> np.ndarray:
    """True for samples outside every segment, shape (N,)."""
    keep = np.ones(t.shape[0], bool)
    for g in segments:
        keep &= ~((t >= g.t0_s) & (t <= g.t1_s))
    return keep
