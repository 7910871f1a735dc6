"""What every autopilot baseline shares: the IMU triads it reads and the answer it gives.

An autopilot compares whole IMUs, not single sensing axes: its rules read each IMU's
three-axis rate (or specific force) in the body frame, as the autopilot's own driver
delivers it after its boot calibration and board rotation. :class:`Triads` holds those
samples (SI), :func:`triads_from_flight` makes them from a :class:`replay.flight_data.Flight`
(the samples the log stores when they are already SI, which is what the autopilot saw;
otherwise the calibration's ``SF·u − b`` resolved onto the body axes), and
:class:`BaselineResult` is the answer of one rule over a block of samples: per sample
whether the rule flags a fault and which IMU it blames, the rule's own measure per IMU, and
the events where that answer changed.

A rule that flags without isolating (two IMUs, or a check that only says "inconsistent")
blames nobody: ``blamed`` is −1 and an event's ``imu`` is None.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fdi.calfile import Calibration
from fdi.errors import ConfigError
from replay.flight_data import Flight
from replay.time_offsets import imu_groups

__all__ = ["BASELINE_SCHEMA", "MOUNTING_TOLERANCE_DEG", "SI_UNITS", "BaselineEvent",
           "BaselineResult", "StreamingRule", "Triads", "answer_events", "triads_from_flight"]

BASELINE_SCHEMA = "rimu.baseline/1"
"""Format of one baseline's answer (:meth:`BaselineResult.to_dict`)."""

SI_UNITS = {"gyro": ("rad/s", "rad/s", "rads"), "accel": ("m/s^2", "m/s2", "mps2")}
"""Raw-unit spellings that are already SI, per sensor kind: such samples are read as the
autopilot logged them."""

_AXES = ("x", "y", "z")

MOUNTING_TOLERANCE_DEG = 10.0
"""An IMU whose calibrated mounting differs from its logged axes by more than this (°) is
read through that mounting's rotation: an autopilot user configures such a rotation (board
or custom rotation); below it the log is taken as already in the body frame."""


@dataclass(frozen=True, eq=False)
class Triads:
    """Each IMU's three-axis samples in the body frame.

    Attributes
    ----------
    t : ndarray, shape (N,)
        Sample times (s).
    values : ndarray, shape (N, k, 3)
        Rates (rad/s) or specific forces (m/s²) of the ``k`` IMUs; NaN where missing.
    valid : ndarray of bool, shape (N, k)
        True where the IMU delivered all three axes, finite.
    imus : tuple of str
        The IMU names (``"imu1"`` …), in order; the first is the autopilot's primary.
    kind : str
        ``"gyro"`` or ``"accel"``.
    sensors : tuple of tuple of int
        Per IMU, the 0-based monitored sensors (columns of the flight) of its x, y, z axes.
    how : str
        Where the samples came from (``"as logged"`` or ``"calibrated: SF·u − b, H⁻¹"``).
    """

    t: np.ndarray
    values: np.ndarray
    valid: np.ndarray
    imus: tuple[str, ...]
    kind: str
    sensors: tuple[tuple[int, ...], ...] = ()
    how: str = "as logged"

    @property
    def k(self) -> int:
        """Number of IMUs."""
        return len(self.imus)

    def imu_of_sensor(self, sensor: int) -> int:
        """The IMU (0-based) of a 1-based monitored sensor; −1 when none."""
        for j, cols in enumerate(self.sensors):
            if sensor - 1 in cols:
                return j
        return -1


def _axis_order(names: Sequence[str], where: str) -> list[int]:
    """Positions of x, y, z among one IMU's sensor names (``imu2.y`` → y)."""
    ax = [nm.rpartition(".")[2].lower() for nm in names]
    if sorted(ax) != list(_AXES):
        raise ConfigError(f"{where}: IMU sensors {', '.join(names)} are not one x, y and z "
                          "axis (the autopilot rules compare whole three-axis IMUs)")
    return [ax.index(a) for a in _AXES]


def triads_from_flight(flight: Flight, cal: Calibration | None = None) -> Triads:
    """The IMU triads of a flight, as an autopilot would read them.

    Parameters
    ----------
    flight : Flight
        Two or more IMU groups of three axes (``imu1.x`` …, or the manifest's ``imu``).
    cal : Calibration, optional
        Needed when the samples are not SI (:data:`SI_UNITS`): then each IMU's
        ``SF·u − b`` is resolved onto the body axes through the inverse of its three rows
        of H̃. SI samples are used as logged (an autopilot log stores the body-frame rates
        after the autopilot's own calibration; giving the rules rimu's calibration would
        give them what the autopilot does not have), except that an IMU whose calibrated
        mounting is more than :data:`MOUNTING_TOLERANCE_DEG` from its logged axes is
        rotated by that mounting (the rotation nearest its rows of H̃: what an autopilot
        user would configure), never scaled or de-biased.

    Raises
    ------
    ConfigError
        Fewer than two IMUs of three axes, or non-SI samples without a calibration.
    """
    where = flight.source
    groups: dict[str, list[int]] = {}
    for i, g in enumerate(imu_groups(flight.sensor_names, flight.imu)):
        groups.setdefault(g, []).append(i)
    if "" in groups or len(groups) < 2 or any(len(v) != 3 for v in groups.values()):
        raise ConfigError(f"{where}: the autopilot baselines need two or more IMUs of three "
                          f"axes (sensor names imu1.x … or the manifest's 'imu'); this "
                          f"{flight.kind} set has {flight.n} sensors in "
                          f"{len(groups)} group(s)")
    raw = np.asarray(flight.raw, float)
    ok = np.asarray(flight.valid, bool) & np.isfinite(raw)
    si = flight.raw_unit.strip().lower() in SI_UNITS.get(flight.kind, ())
    how = "as logged"
    if not si:
        if cal is None:
            raise ConfigError(f"{where}: samples in {flight.raw_unit!r}, not SI: the "
                              "baselines need the calibration to read them")
        s = cal.kind(flight.kind)
        y = raw * s.scale_factors - s.biases
        how = "calibrated: SF·u − b resolved onto the body axes (H⁻¹ per IMU)"
    N = raw.shape[0]
    rotated = []
    vals = np.full((N, len(groups), 3), np.nan)
    valid = np.zeros((N, len(groups)), bool)
    cols_out = []
    for j, (g, cols) in enumerate(groups.items()):
        order = [cols[p] for p in _axis_order([flight.sensor_names[c] for c in cols],
                                              f"{where}: {g}")]
        cols_out.append(tuple(order))
        v = ok[:, order].all(axis=1)
        if si:
            x = raw[:, order]
            R = _mounting(cal, flight.kind, order)
            if R is not None:
                x = x @ R               # row form of ω = Rᵀ·u (u = R·ω)
                rotated.append(g)
        else:
            H = np.asarray(cal.kind(flight.kind).H, float)[order]   # type: ignore[union-attr]
            x = np.linalg.solve(H, y[:, order].T).T
        vals[v, j] = x[v]
        valid[:, j] = v
    if rotated:
        how = (f"as logged, {', '.join(rotated)} rotated by the calibration's mounting "
               f"(more than {MOUNTING_TOLERANCE_DEG:g} deg from the logged axes)")
    return Triads(t=np.asarray(flight.t, float), values=vals, valid=valid,
                  imus=tuple(groups), kind=flight.kind, sensors=tuple(cols_out), how=how)


def _mounting(cal: Calibration | None, kind: str, order: list[int]) -> np.ndarray | None:
    """The rotation nearest an IMU's rows of H̃ when it is more than
    :data:`MOUNTING_TOLERANCE_DEG` from the identity (None otherwise, or without a
    calibration)."""
    if cal is None:
        return None
    try:
        H = np.asarray(cal.kind(kind).H, float)[order]
    except (ConfigError, IndexError):
        return None
    if H.shape != (3, 3) or not np.isfinite(H).all():
        return None
    U, _, Vt = np.linalg.svd(H)
    R = U @ Vt
    if np.linalg.det(R) < 0:
        return None                    # a reflection: not a mounting
    ang = np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)))
    return R if ang > MOUNTING_TOLERANCE_DEG else None


@dataclass(frozen=True)
class BaselineEvent:
    """A change of a rule's answer.

    Attributes
    ----------
    t : float
        Time of the sample (s).
    type : str
        ``"flagged"`` (a fault is declared, or the IMU blamed changes while flagged) or
        ``"cleared"`` (the rule no longer declares a fault).
    imu : str or None
        The IMU blamed (None: flagged without isolation, or cleared).
    reason : str
        The rule that decided (``"selector"``, ``"stale"``, ``"timeout"``,
        ``"inconsistent"``), with the two-IMU caveat where it applies.
    value : float
        The rule's measure at that sample (``unit``).
    threshold : float
        What it was compared with (``unit``).
    unit : str
    """

    t: float
    type: str
    imu: str | None
    reason: str
    value: float = float("nan")
    threshold: float = float("nan")
    unit: str = ""

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (non-finite numbers become None)."""
        def num(x: float) -> float | None:
            return float(x) if np.isfinite(x) else None
        return {"t": float(self.t), "type": self.type, "imu": self.imu, "reason": self.reason,
                "value": num(self.value), "threshold": num(self.threshold), "unit": self.unit}


@dataclass(frozen=True, eq=False)
class BaselineResult:
    """One autopilot rule over a block of samples.

    Attributes
    ----------
    name : str
        ``"px4"`` or ``"ardupilot"``.
    rule : str
        What was run, in a line.
    kind : str
    imus : tuple of str
    t : ndarray, shape (N,)
    flagged : ndarray of bool, shape (N,)
        The rule declares a fault at this sample.
    blamed : ndarray of int, shape (N,)
        0-based IMU blamed (−1: none).
    measure : ndarray, shape (N, k)
        The rule's measure per IMU (``measure_unit``): PX4's accumulated error, ArduPilot's
        difference to the primary.
    measure_unit : str
    threshold : float
        The measure's fault threshold (``measure_unit``).
    events : tuple of BaselineEvent
    settings : dict
        The rule's parameters, in the autopilot's own units and names.
    left_out : tuple of str
        The parts of the autopilot's logic not run on these samples, each with the reason.
    """

    name: str
    rule: str
    kind: str
    imus: tuple[str, ...]
    t: np.ndarray
    flagged: np.ndarray
    blamed: np.ndarray
    measure: np.ndarray
    measure_unit: str
    threshold: float
    events: tuple[BaselineEvent, ...]
    settings: dict[str, Any] = field(default_factory=dict)
    left_out: tuple[str, ...] = ()

    def first_flag(self, after: float = -np.inf) -> BaselineEvent | None:
        """The first ``flagged`` event at or after ``after`` (s)."""
        return next((e for e in self.events if e.type == "flagged" and e.t >= after - 1e-9),
                    None)

    def first_blame(self, after: float = -np.inf) -> BaselineEvent | None:
        """The first ``flagged`` event naming an IMU at or after ``after`` (s)."""
        return next((e for e in self.events if e.type == "flagged" and e.imu is not None
                     and e.t >= after - 1e-9), None)

    def to_dict(self, *, max_events: int | None = None) -> dict[str, Any]:
        """The JSON record (``rimu.baseline/1``): events and a summary, no per-sample
        arrays."""
        ev = list(self.events)
        onsets = [e for e in ev if e.type == "flagged"]
        n = self.t.shape[0]
        blamed = sorted({e.imu for e in onsets if e.imu is not None})
        first = onsets[0] if onsets else None
        return {"schema": BASELINE_SCHEMA, "name": self.name, "rule": self.rule,
                "kind": self.kind, "imus": list(self.imus), "settings": dict(self.settings),
                "left_out": list(self.left_out),
                "summary": {"flag_events": len(onsets),
                            "first_flag_s": None if first is None else float(first.t),
                            "first_blamed": None if first is None else first.imu,
                            "blamed_imus": blamed,
                            "flagged_fraction": float(np.mean(self.flagged)) if n else 0.0,
                            "flagged_at_end": bool(self.flagged[-1]) if n else False},
                "events": [e.to_dict() for e in (ev if max_events is None
                                                 else ev[:max_events])],
                "events_total": len(ev),
                "units": {"t": "s", "value": self.measure_unit,
                          "threshold": self.measure_unit}}


def answer_events(t: np.ndarray, flagged: np.ndarray, blamed: np.ndarray,
                  reason: np.ndarray, value: np.ndarray, prev: list[Any],
                  imus: Sequence[str], reasons: Sequence[str], threshold: float,
                  unit: str) -> list[BaselineEvent]:
    """The events of a run of answers: where (flagged, blamed) changes.

    ``prev`` is ``[flagged, blamed]`` of the sample before the block (updated in place), so
    that a stream cut into blocks (or stepped one sample at a time) gives the events of the
    whole. ``reason`` holds per sample an index into ``reasons``; ``value`` the measure
    reported with the event.
    """
    out = []
    for r in range(t.shape[0]):
        f, b = bool(flagged[r]), int(blamed[r])
        if f and (not prev[0] or b != prev[1]):
            out.append(BaselineEvent(float(t[r]), "flagged", imus[b] if b >= 0 else None,
                                     reasons[int(reason[r])], float(value[r]), threshold,
                                     unit))
        elif prev[0] and not f:
            out.append(BaselineEvent(float(t[r]), "cleared", None, reasons[int(reason[r])],
                                     float(value[r]), threshold, unit))
        prev[0], prev[1] = f, (b if f else -1)
    return out


class StreamingRule:
    """The one streaming shape of a baseline rule: ``step`` (one sample) and ``run`` (a
    block) both go through the rule's ``_advance(t, x, ok) -> (flag, blame, value, events)``
    on arrays of shape (N,), (N, k, 3), (N, k), so they share the arithmetic; ``_answer`` is
    the rule's per-sample answer class, built as ``(t, flagged, blamed, value, events)``."""

    _answer: Any

    def _advance(self, t: np.ndarray, x: np.ndarray, ok: np.ndarray) -> tuple[Any, ...]:
        raise NotImplementedError

    def result(self, t: np.ndarray, flag: np.ndarray, blame: np.ndarray, value: np.ndarray,
               events: Any) -> BaselineResult:
        raise NotImplementedError

    def step(self, t: float, values: np.ndarray, valid: np.ndarray) -> Any:
        """One sample: ``values`` (k, 3) SI, ``valid`` (k,)."""
        flag, blame, value, ev = self._advance(
            np.array([float(t)]), np.asarray(values, float).reshape(1, -1, 3),
            np.asarray(valid, bool).reshape(1, -1))
        return self._answer(float(t), bool(flag[0]), int(blame[0]), value[0], tuple(ev))

    def run(self, t: np.ndarray, values: np.ndarray, valid: np.ndarray) -> BaselineResult:
        """A block: ``t`` (N,), ``values`` (N, k, 3) SI, ``valid`` (N, k)."""
        t = np.asarray(t, float)
        flag, blame, value, ev = self._advance(t, np.asarray(values, float),
                                               np.asarray(valid, bool))
        return self.result(t, flag, blame, value, ev)
