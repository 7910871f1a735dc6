"""What the monitor answers: one :class:`Answer` per sample, a :class:`BlockResult` per block.

Both are frozen results. Sensors are numbered from 1 in events and from 0 in arrays.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["CAPABILITIES", "EVENT_TYPES", "STATUSES", "TIME_STATUSES", "Answer", "BlockResult",
           "Event"]

EVENT_TYPES = ("detected", "isolated", "disagree", "health", "readmitted", "envelope")
"""Kinds of :class:`Event`: ``"disagree"`` names sensors whose fault hypotheses the data
cannot tell apart (no exclusion; the rate along their axes is unverified); ``"envelope"``
marks leaving (reason: the envelope reasons) and re-entering (reason ``"in"``) the operating
envelope."""

CAPABILITIES = ("isolate", "detect", "reconstruct", "none")
"""What the monitor can still do with its healthy sensors (best first)."""

TIME_STATUSES = ("ok", "nonfinite", "backward", "jump", "rebased")
"""Verdicts on a sample's time stamp (``Answer.time_status``), in the order of the kernel's
codes (:data:`fdi.state.TIME`)."""
STATUSES = ("ok", "detected", "isolated", "stale", "nonfinite", "range", "stuck", "length",
            "vibration")
"""Per-sensor status strings: ``"ok"``; ``"detected"`` (a fault is detected in the healthy
set and not yet attributed); ``"isolated"`` (by the parity test); or the health check that
isolated it."""


def _num(x: float | None) -> float | None:
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


@dataclass(frozen=True, eq=False)
class Event:
    """A fault event.

    Attributes
    ----------
    t : float
        Time of the sample that caused it (s).
    sensor : int or None
        1-based sensor, None for a detection not attributed to a sensor.
    type : str
        One of :data:`EVENT_TYPES`.
    reason : str
        ``"parity scale 8"`` (window of 8 samples), ``"cusum"``, ``"stuck"``,
        ``"nonfinite"``, ``"stale"``, ``"range"``, ``"length"``, ...
    statistic, threshold : float
        The test statistic and the threshold it crossed (NaN for health events without one).
    scale : int or None
        Window length in samples of the scale that fired.
    magnitude : float or None
        Estimated fault size (SI input units: rad/s for gyros), where estimable.
    sensors : tuple of int
        1-based sensors a ``"disagree"`` event names (empty otherwise).
    envelope : int
        Operating-envelope code of the sample (0: inside; :mod:`fdi.envelope` bits).
    """

    t: float
    sensor: int | None
    type: str
    reason: str
    statistic: float = float("nan")
    threshold: float = float("nan")
    scale: int | None = None
    magnitude: float | None = None
    sensors: tuple[int, ...] = ()
    envelope: int = 0

    def _key(self) -> tuple:
        def k(x: float | None) -> Any:
            return ("nan",) if isinstance(x, float) and math.isnan(x) else x
        return (self.t, self.sensor, self.type, self.reason, k(self.statistic),
                k(self.threshold), self.scale, k(self.magnitude), self.sensors,
                self.envelope)

    def __eq__(self, other: object) -> bool:
        """Field-wise equality in which NaN equals NaN (two identical events are equal)."""
        if not isinstance(other, Event):
            return NotImplemented
        return self._key() == other._key()

    def __hash__(self) -> int:
        return hash(self._key())

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary (non-finite numbers become None)."""
        return {"t": float(self.t), "sensor": self.sensor, "type": self.type,
                "reason": self.reason, "statistic": _num(self.statistic),
                "threshold": _num(self.threshold), "scale": self.scale,
                "magnitude": _num(self.magnitude), "sensors": list(self.sensors),
                "envelope": int(self.envelope)}


@dataclass(frozen=True)
class Answer:
    """The monitor's answer to one sample.

    Attributes
    ----------
    t : float
        Sample time (s).
    omega : ndarray, shape (3,)
        Reconstructed body rate (SI: rad/s for gyros), weighted least squares from the
        healthy sensors that delivered this sample. NaN when fewer than 3 independent remain.
    omega_sd : ndarray, shape (3,)
        Standard deviation per axis of ``omega`` (white noise, from G Σ Gᵀ).
    healthy : ndarray of bool, shape (n,)
    status : tuple of str
        One of :data:`STATUSES` per sensor.
    parity : ndarray, shape (n - 3,)
        Parity vector V·y of the healthy set (first m − 3 entries), NaN-padded.
    statistics : ndarray, shape (K,)
        Whitened detection statistic per scale (window of 1, 2, 4, ... samples); NaN while a
        window is not yet full or the sample is incomplete.
    thresholds : ndarray, shape (K,)
        Threshold per scale for this sample (grows with the rate: calibration uncertainty).
    events : tuple of Event
    capability : str
        ``"isolate"``, ``"detect"``, ``"reconstruct"`` or ``"none"``.
    protection_level : float
        Largest rate error (rad/s, vector norm) that a not yet detected fault on one
        sensor could cause, at the stated missed-detection probability; inf where the answer
        is not verified (no detection capability, a detection active, out of the envelope).
    envelope : int
        Operating-envelope code of the sample (0: inside; bits of :mod:`fdi.envelope`). Out
        of the envelope the monitor excludes nothing on the parity.
    unverified : ndarray of bool, shape (3,)
        Body axes whose rate the monitor cannot vouch for: a detection is active and a
        fault on one of the suspected sensors would move that axis (see
        :meth:`fdi.monitor.Monitor.step`).
    suspects : tuple of int
        1-based sensors under suspicion while a detection is active (the hypotheses the
        data do not reject); empty otherwise.
    time_status : str
        The verdict on the sample's time stamp (:data:`TIME_STATUSES`): ``"ok"``;
        ``"nonfinite"`` (NaN or ±inf), ``"backward"`` (earlier than the last good one) or
        ``"jump"`` (more than ``MonitorSettings.max_time_step_s`` after it): the sample is
        tested as any other but its time is not taken for the stale and re-admission
        clocks (the stale clock then runs on the sample count); ``"rebased"``: a run of
        bad but mutually consistent time stamps became the new time base here.
    """

    t: float
    omega: np.ndarray
    omega_sd: np.ndarray
    healthy: np.ndarray
    status: tuple[str, ...]
    parity: np.ndarray
    statistics: np.ndarray
    thresholds: np.ndarray
    events: tuple[Event, ...]
    capability: str
    protection_level: float
    envelope: int = 0
    unverified: np.ndarray = field(default_factory=lambda: np.zeros(3, bool))
    suspects: tuple[int, ...] = ()
    time_status: str = "ok"


@dataclass(frozen=True)
class BlockResult:
    """The answers to a block of N samples (the block path :meth:`fdi.monitor.Monitor.run`).

    Attributes
    ----------
    t : ndarray, shape (N,)
    omega, omega_sd : ndarray, shape (N, 3)
    healthy : ndarray of bool, shape (N, n)
    statistics, thresholds : ndarray, shape (N, K)
    protection_level : ndarray, shape (N,)
    capability : ndarray of str, shape (N,)
    events : list of Event
        In time order.
    parity : ndarray, shape (N, n - 3)
        Parity vectors (NaN-padded), as in :class:`Answer`.
    envelope : ndarray of int, shape (N,)
        Operating-envelope code per sample (None from producers that do not track it).
    unverified : ndarray of bool, shape (N, 3)
        Unverified body axes per sample, as in :class:`Answer`.
    time_status : ndarray of str, shape (N,)
        The verdict on each sample's time stamp, as in :class:`Answer` (None from
        producers that do not judge it).
    """

    t: np.ndarray
    omega: np.ndarray
    omega_sd: np.ndarray
    healthy: np.ndarray
    statistics: np.ndarray
    thresholds: np.ndarray
    protection_level: np.ndarray
    capability: np.ndarray
    events: list[Event] = field(default_factory=list)
    parity: np.ndarray | None = None
    envelope: np.ndarray | None = None
    unverified: np.ndarray | None = None
    time_status: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.t.shape[0])
