"""Segments of a flight to leave out, found from the data.

The operating envelope is decided in one place, :mod:`fdi.envelope` (through
:func:`replay.envelope.flight_envelope`, the same codes the monitor gets); this module turns
its codes into segments and adds what only the offline fit needs:

- ``shock``, ``saturation``, ``tumble``, ``declared``: the envelope's reasons (see
  docs/envelope.md). A shock is labelled ``crash`` when it is followed by no motion or by
  the end of the log, ``take-off`` when it comes before the first motion;
- ``gap``: the samples next to a gap in the time base (more than two sample periods);
- ``invalid``: a sample some sensor did not send;
- ``time stamp``: samples whose time stamp does not come after every earlier one (repeated
  or running backward, as :func:`replay.time_base.time_base` counts them), with the sample
  before each run and :data:`STAMP_PAD_SAMPLES` sample periods either side: the samples
  cannot be placed on the time axis the fit reads the reference on.

The calibration is not causal: every envelope segment is widened by :data:`PAD_S` before
(the envelope already holds each reason ``hold_s`` after), gaps and invalid samples by
:data:`PAD_S` on both sides; overlapping segments of one reason are merged. Declared
events of the ``crash`` category count (:data:`replay.log_events.DEFAULT_DECLARED`).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from fdi.envelope import REASONS, SHOCK, EnvelopeSettings
from fdi.errors import ConfigError
from replay.envelope import flight_envelope, flying_mask
from replay.flight_data import Flight

__all__ = ["PAD_S", "STAMP_PAD_SAMPLES", "Segment", "find_segments", "flight_window",
           "keep_mask", "stamp_faults"]

PAD_S = 0.5
"""Margin (s) added before every segment (and after gaps and invalid samples)."""
STAMP_PAD_SAMPLES = 3
"""Sample periods left out either side of a repeated or backward time stamp (as the 3
samples next to a dropped block: the spline must not bridge them)."""


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


def _gap_samples(flight: Flight) -> np.ndarray:
    """The samples on either side of a jump of the time base by more than two periods."""
    t = flight.t
    gap = np.zeros(t.shape[0], bool)
    if t.shape[0] > 1 and flight.sample_rate_hz > 0:
        big = np.flatnonzero(np.diff(t) > 2.0 / flight.sample_rate_hz)
        gap[big] = True
        gap[big + 1] = True
    return gap


def stamp_faults(t: np.ndarray) -> tuple[np.ndarray, int, int]:
    """The samples whose time stamp does not come after every earlier one.

    Parameters
    ----------
    t : ndarray, shape (N,)
        Time stamps (s), in the order of the rows.

    Returns
    -------
    mask : ndarray of bool, shape (N,)
        True where ``t[k] <= max(t[:k])``; the rows left are strictly increasing.
    repeated, backward : int
        Intervals equal to zero and intervals below zero (what
        :func:`replay.time_base.time_base` counts as duplicates, and what a flight folder
        refuses).
    """
    t = np.asarray(t, float)
    if t.shape[0] < 2:
        return np.zeros(t.shape[0], bool), 0, 0
    prev_max = np.maximum.accumulate(t)[:-1]
    mask = np.concatenate([[False], t[1:] <= prev_max])
    dt = np.diff(t)
    return mask, int(np.count_nonzero(dt == 0)), int(np.count_nonzero(dt < 0))


def _stamp_segments(flight: Flight) -> list[Segment]:
    t = np.asarray(flight.t, float)
    mask, _, _ = stamp_faults(t)
    if not mask.any():
        return []
    pad = STAMP_PAD_SAMPLES / flight.sample_rate_hz if flight.sample_rate_hz > 0 else 0.0
    dt = np.concatenate([[np.inf], np.diff(t)])
    out = []
    for s0, e0 in _runs(mask):
        s, e = int(s0), int(e0)
        rep, back = int(np.count_nonzero(dt[s:e] == 0)), int(np.count_nonzero(dt[s:e] < 0))
        what = " and ".join(x for x in (f"{rep} repeated" * bool(rep),
                                        f"{back} running backward" * bool(back)) if x)
        why = (f"{e - s} time stamp{'s' * (e - s != 1)} not after every earlier one ("
               f"{what or 'below an earlier one'}): left out with the sample before and "
               f"{STAMP_PAD_SAMPLES} sample periods either side")
        span = t[max(s - 1, 0):e]
        out.append(Segment(float(span.min()) - pad, float(span.max()) + pad, "time stamp", why))
    return out


def _why(flight: Flight, bit: int, t0: float, t1: float,
         settings: EnvelopeSettings) -> str:
    if bit == SHOCK:
        return f"specific force above {settings.shock_limit_g:g} g, confirmed by every IMU"
    if bit == 2:
        return "a channel at its range or repeating a large value, confirmed"
    if bit == 4:
        return (f"every IMU above {settings.tumble_rate_dps:g} deg/s, or the IMUs' "
                f"disagreement jumps by {settings.disagree_spike_dps:g} deg/s in a fast turn")
    texts = [e.text for e in flight.events if e.category == "crash"
             and e.t_s <= t1 and e.t_end_s >= t0 - settings.hold_s]
    return "declared by the log: " + "; ".join(dict.fromkeys(texts)) if texts else \
        "declared by the log"


def find_segments(flight: Flight, settings: EnvelopeSettings | None = None) -> list[Segment]:
    """Segments to leave out (module docstring), sorted by time, merged, padded."""
    settings = settings if settings is not None else EnvelopeSettings()
    t = flight.t
    N = t.shape[0]
    if N == 0:
        return []
    codes = flight_envelope(flight, None, settings)
    moving = flying_mask(flight)
    first_move = int(np.argmax(moving)) if moving.any() else N
    last_move = N - 1 - int(np.argmax(moving[::-1])) if moving.any() else -1
    segs: list[Segment] = []
    for bit, name in REASONS.items():
        for s, e in _runs((codes & bit) != 0):
            reason = name
            if bit == SHOCK:
                reason = ("take-off" if e <= first_move else "crash" if s >= last_move - 1
                          else "shock")
            t0, t1 = float(t[s]), float(t[e - 1])
            segs.append(Segment(t0 - PAD_S, t1, reason, _why(flight, bit, t0, t1, settings)))
    flags: list[tuple[np.ndarray, str, str]] = [
        (_gap_samples(flight), "gap", "time base jumps by more than two sample periods"),
        (~flight.valid.all(axis=1), "invalid", "a sensor sent no sample")]
    for mask, reason, why in flags:
        segs.extend(Segment(float(t[s]) - PAD_S, float(t[e - 1]) + PAD_S, reason, why)
                    for s, e in _runs(mask))
    segs.extend(_stamp_segments(flight))
    return _merge(sorted(segs, key=lambda g: g.t0_s))


def _merge(segs: list[Segment]) -> list[Segment]:
    out: list[Segment] = []
    for g in segs:
        a, b = g.t0_s, g.t1_s
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


_START = re.compile(r"(?<!DIS)ARMED|NOT_LANDED|TAKE_?OFF|take-?off", re.IGNORECASE)
_END = re.compile(r"LAND_COMPLETE(?!_MAYBE)|DISARMED|(?<!NOT_)LANDED", re.IGNORECASE)


def flight_window(flight: Flight) -> tuple[float, float]:
    """The span from the log's first arm/take-off event to its last land/disarm event (s).

    Reads the flight folder's ``events`` (:mod:`replay.log_events`): a start is an event
    whose text says armed, not landed or take-off, an end one that says land complete,
    landed or disarmed, after the start. Without an end the record's last sample ends it.

    Raises
    ------
    ConfigError
        The folder carries no such start event (the message says to give ``--window``).
    """
    ev = sorted(flight.events, key=lambda e: e.t_s)
    starts = [e.t_s for e in ev if _START.search(e.text)]
    if not starts:
        raise ConfigError(f"{flight.source}: --window flight: the folder's events hold no "
                          "arm or take-off event; give the part of the record as "
                          "--window T0:T1 (seconds)")
    t0 = starts[0]
    ends = [e.t_s for e in ev if _END.search(e.text) and e.t_s > t0]
    t1 = ends[-1] if ends else float(flight.t[-1])
    return float(t0), float(t1)
