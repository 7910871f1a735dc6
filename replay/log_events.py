"""Events a flight log declares about itself (ArduPilot ``ERR``/``EV``/``MSG``, PX4 flags).

A :class:`LogEvent` is a time span on the flight's clock with the log's own words and a
category:

- ``"crash"``: the vehicle left controlled flight by the autopilot's own account (crash
  check, loss of control, thrust loss, flip, PX4's attitude failure detector or flight
  termination). :func:`declared_intervals` hands these to
  :class:`fdi.envelope.EnvelopeTracker` as :data:`fdi.envelope.DECLARED` by default.
- ``"estimator"``: the navigation filter complains (ArduPilot EKF check bad variance,
  EKF/INAV failsafe, EKF primary change; PX4 filter fault flags). Kept and reported, but
  by default **not** declared out of the envelope: the estimator's complaint is a
  consequence, and one of its causes is an IMU fault, the very thing the monitor must be
  free to exclude; when the cause is physical (vibration, clipping, impact) the physical
  rules of :mod:`fdi.envelope` see it directly. ``declared_intervals(...,
  categories=("crash", "estimator"))`` includes them.
- ``"info"``: arming, landing, mode and text messages.

In a flight folder they are the manifest's ``events`` list (:func:`event_to_dict`,
:func:`event_from_dict`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from fdi.envelope import DeclaredInterval
from fdi.errors import FileFormatError

__all__ = ["CATEGORIES", "DEFAULT_DECLARED", "LogEvent", "declared_intervals",
           "event_from_dict", "event_to_dict", "flag_intervals"]

CATEGORIES = ("crash", "estimator", "info")
"""Kinds of log event (module docstring)."""
DEFAULT_DECLARED = ("crash",)
"""Categories declared out of the envelope unless asked otherwise."""


@dataclass(frozen=True)
class LogEvent:
    """One event of a log.

    Attributes
    ----------
    t_s : float
        Start (s, on the flight's time base).
    t_end_s : float
        End (s); equal to ``t_s`` for an instant, ``inf`` when it lasts to the end of the
        log (a crash with no re-arming).
    source : str
        Where it comes from: ``"ERR"``, ``"EV"``, ``"MSG"`` (ArduPilot),
        ``"vehicle_status.failure_detector_status"``, ``"logged_message"`` (PX4), ...
    text : str
        What the log says, decoded (``"ERR CRASH_CHECK 1: crash"``).
    code : int
        The log's own number (ECode, EV Id, flag bits; 0 when none).
    category : str
        ``"crash"``, ``"estimator"`` or ``"info"`` (:data:`CATEGORIES`).
    """

    t_s: float
    t_end_s: float
    source: str
    text: str
    code: int = 0
    category: str = "info"


def declared_intervals(events: Sequence[LogEvent],
                       categories: Sequence[str] = DEFAULT_DECLARED
                       ) -> tuple[DeclaredInterval, ...]:
    """The events of ``categories`` as intervals for :class:`fdi.envelope.EnvelopeTracker`."""
    return tuple(DeclaredInterval(e.t_s, e.t_end_s, e.text) for e in events
                 if e.category in categories)


def event_to_dict(e: LogEvent) -> dict[str, Any]:
    """JSON-ready (``t_end`` is ``null`` for an event that lasts to the end of the log)."""
    return {"t": e.t_s, "t_end": e.t_end_s if math.isfinite(e.t_end_s) else None,
            "source": e.source, "text": e.text, "code": int(e.code),
            "category": e.category}


def event_from_dict(d: Any, path: str, where: str) -> LogEvent:
    """Read one entry of a manifest's ``events`` list; errors name ``where``."""
    if not isinstance(d, Mapping):
        raise FileFormatError(path, "expected an object", field=where)
    unknown = sorted(set(d) - {"t", "t_end", "source", "text", "code", "category"})
    if unknown:
        raise FileFormatError(path, f"unknown key {unknown[0]!r}", field=f"{where}.{unknown[0]}")
    t = d.get("t")
    if isinstance(t, bool) or not isinstance(t, int | float) or not math.isfinite(t):
        raise FileFormatError(path, f"expected a finite time (s), got {t!r}", field=f"{where}.t")
    te = d.get("t_end", t)
    if te is None:
        te = math.inf
    if isinstance(te, bool) or not isinstance(te, int | float) or math.isnan(te) or te < t:
        raise FileFormatError(path, f"expected null or a time >= t, got {te!r}",
                              field=f"{where}.t_end")
    for k in ("source", "text"):
        if not isinstance(d.get(k, ""), str):
            raise FileFormatError(path, f"expected a string, got {d.get(k)!r}",
                                  field=f"{where}.{k}")
    code = d.get("code", 0)
    if isinstance(code, bool) or not isinstance(code, int):
        raise FileFormatError(path, f"expected an integer, got {code!r}", field=f"{where}.code")
    cat = d.get("category", "info")
    if cat not in CATEGORIES:
        raise FileFormatError(path, f"expected one of {', '.join(CATEGORIES)}, got {cat!r}",
                              field=f"{where}.category")
    return LogEvent(float(t), float(te), d.get("source", ""), d.get("text", ""), code, cat)


def flag_intervals(t: np.ndarray, flags: np.ndarray, mask: int = -1
                   ) -> list[tuple[float, float, int]]:
    """Spans where ``flags & mask`` is nonzero in a sampled status topic.

    A span starts at the first sample with the bits set and ends at the first sample
    where they are clear again (``inf`` when they never clear); its code is the OR of the
    bits seen. ``t`` (s) and ``flags`` (integers) have shape (N,).
    """
    t = np.asarray(t, float)
    f = np.asarray(flags).astype(np.int64) & int(mask)
    out: list[tuple[float, float, int]] = []
    on = f != 0
    d = np.diff(np.concatenate([[0], on.astype(np.int8), [0]]))
    for s, e in zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1), strict=True):
        end = float(t[e]) if e < t.shape[0] else math.inf
        out.append((float(t[s]), end, int(np.bitwise_or.reduce(f[s:e]))))
    return out
