"""The operating envelope of a recorded flight: :mod:`fdi.envelope` fed from a flight folder.

One decision for every user: the monitoring chain (:func:`flight_envelope` gives the codes
``Monitor.run(..., envelope=...)`` takes), the in-flight calibration and diagnose
(:mod:`calibration.inflight.segments`), and the reports (:func:`envelope_periods`,
:func:`envelope_summary`). The rates are the calibrated ones when a calibration is given;
without one (the in-flight calibration, which has none yet) the flight must be an IMU set
ingested in rad/s, whose axes are taken as the nominal x, y, z of each IMU.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from fdi.calfile import Calibration, SensorSet
from fdi.envelope import REASONS, EnvelopeSettings, EnvelopeTracker, reason_names
from fdi.errors import ConfigError
from replay.flight_data import Flight
from replay.log_events import DEFAULT_DECLARED, declared_intervals

__all__ = [
    "EnvelopePeriod",
    "describe_summary",
    "envelope_periods",
    "envelope_summary",
    "envelope_tracker",
    "flight_accel",
    "flight_envelope",
    "flight_rates",
    "flying_mask",
    "uncalibrated_summary",
]


def flight_rates(flight: Flight, cal: Calibration | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Rates of the monitored gyros and their axes: ((N, n) rad/s, H (n, 3)).

    With ``cal``: ``raw · SF − b`` along the calibrated axes. Without: the raw values,
    which must be rad/s, along the nominal axes of each three-axis IMU group (x, y, z).
    """
    if flight.kind != "gyro":
        raise ConfigError(f"{flight.source}: the envelope needs gyros, the flight monitors "
                          f"{flight.kind}")
    if cal is not None:
        s = cal.gyro
        if s.n != flight.n:
            raise ConfigError(f"{flight.source}: {flight.n} sensors, the calibration has "
                              f"{s.n}")
        with np.errstate(over="ignore", invalid="ignore"):   # 1e308 raw: inf, flagged
            return flight.raw * s.scale_factors - s.biases, s.H
    groups = flight.imu_groups()
    if flight.raw_unit != "rad/s" or not groups or any(len(g) != 3 for g in groups.values()):
        raise ConfigError(f"{flight.source}: without a calibration the envelope needs IMU "
                          f"groups of three axes in rad/s (raw unit {flight.raw_unit!r})")
    H = np.zeros((flight.n, 3))
    for idx in groups.values():
        for k, i in enumerate(idx):
            H[i, k] = 1.0
    return np.asarray(flight.raw, float), H


def flight_accel(flight: Flight) -> np.ndarray | None:
    """Specific force of each IMU with three accelerometer axes: (N, k, 3) m/s², or None."""
    if flight.aux is None:
        return None
    acc = flight.aux.select("accel")
    if not acc.m:
        return None
    blocks = []
    for g in dict.fromkeys(acc.imu):
        cols = [j for j, h in enumerate(acc.imu) if h == g]
        if len(cols) == 3:
            blocks.append(acc.values[:, cols])
    return np.stack(blocks, axis=1) if blocks else None


def envelope_tracker(H: np.ndarray, groups: Sequence[str], limits: SensorSet | None = None,
                     declared: Sequence[Any] = (), settings: EnvelopeSettings | None = None,
                     *, whole_imus: bool) -> EnvelopeTracker:
    """The envelope tracker of a sensor set: the one construction from a calibration.

    Parameters
    ----------
    H : ndarray, shape (n, 3)
        Sensor axes (the calibrated ones, or nominal axes without a calibration).
    groups : sequence of str, length n (or empty)
        IMU group of each sensor (``""``: in none); the rate estimates are the groups', in
        order of first appearance.
    limits : SensorSet, optional
        The calibrated set whose validated rate, specific force and jolt bound the envelope
        (None: no validated limits).
    declared : sequence
        Declared intervals of the log (:func:`replay.log_events.declared_intervals`).
    settings : EnvelopeSettings, optional
    whole_imus : bool
        The rule for the rate estimates. True (the monitoring chain): the IMU groups only
        when there are two or more and every sensor is in one, otherwise the leave-one-out
        subsets (:func:`fdi.envelope.independent_estimates`). False (a flight's codes,
        :func:`flight_envelope`): the IMU groups as they are, leave-one-out only when there
        are none.
    """
    idx: dict[str, list[int]] = {}
    for i, g in enumerate(groups):
        idx.setdefault(g, []).append(i)
    if whole_imus:
        use = list(idx.values()) if len(idx) > 1 and "" not in idx else None
    else:
        use = list(idx.values()) or None
    rate = force = jolt = None
    if limits is not None:
        rate, force, jolt = (limits.validated_rate, limits.validated_specific_force,
                             limits.validated_jolt)
    return EnvelopeTracker(settings, H=H, groups=use, declared=tuple(declared),
                           validated_rate=rate, validated_specific_force=force,
                           validated_jolt=jolt)


def flight_envelope(flight: Flight, cal: Calibration | None = None,
                    settings: EnvelopeSettings | None = None, *,
                    categories: Sequence[str] = DEFAULT_DECLARED) -> np.ndarray:
    """Envelope codes of every sample of a flight, shape (N,) int64 (0 = inside).

    Causal: the codes are those :class:`fdi.envelope.EnvelopeTracker` gives online.
    ``categories`` chooses which declared log events count (:mod:`replay.log_events`).
    """
    rates, H = flight_rates(flight, cal)
    tr = envelope_tracker(H, flight.imu, cal.gyro if cal is not None else None,
                          declared_intervals(flight.events, categories), settings,
                          whole_imus=False)
    return tr.update(flight.t, rates, flight_accel(flight))


@dataclass(frozen=True)
class EnvelopePeriod:
    """A run of samples out of the envelope: ``[t0_s, t1_s]``, the OR of their codes."""

    t0_s: float
    t1_s: float
    code: int
    samples: int

    @property
    def reasons(self) -> tuple[str, ...]:
        """Names of the code bits."""
        return reason_names(self.code)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {"t0_s": self.t0_s, "t1_s": self.t1_s, "code": self.code,
                "reasons": list(self.reasons), "samples": self.samples}


def envelope_periods(t: np.ndarray, codes: np.ndarray) -> list[EnvelopePeriod]:
    """The runs of nonzero codes, in time order."""
    on = np.asarray(codes) != 0
    d = np.diff(np.concatenate([[0], on.astype(np.int8), [0]]))
    out = []
    for s, e in zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1), strict=True):
        out.append(EnvelopePeriod(float(t[s]), float(t[e - 1]),
                                  int(np.bitwise_or.reduce(np.asarray(codes[s:e]))), int(e - s)))
    return out


def flying_mask(flight: Flight, rest_rate_rad_s: float = 0.1) -> np.ndarray:
    """Samples counted as flying time, shape (N,) bool.

    Flying = every sample from the first to the last at which the first IMU's rate
    magnitude exceeds its rest level (median of the first 5 % of the log) by
    ``rest_rate_rad_s``; gaps in the time base hold no samples and so do not count.
    """
    groups = list(flight.imu_groups().values())
    idx = groups[0] if groups else list(range(min(3, flight.n)))
    # hypot: no overflow on huge values (1e308 counts as moving, NaN as still)
    r = np.hypot.reduce(np.nan_to_num(np.asarray(flight.raw, float)[:, idx]), axis=1)
    n = r.shape[0]
    out = np.zeros(n, bool)
    if n == 0:
        return out
    with np.errstate(over="ignore"):                   # the median of two 1e308: inf
        base = float(np.median(r[: max(1, n // 20)]))
    moving = r > base + rest_rate_rad_s
    if moving.any():
        a = int(np.argmax(moving))
        b = n - 1 - int(np.argmax(moving[::-1]))
        out[a:b + 1] = True
    return out


def envelope_summary(flight: Flight, codes: np.ndarray) -> dict[str, Any]:
    """Counts for a report: marked samples and fraction of the flying time, per reason."""
    codes = np.asarray(codes)
    fly = flying_mask(flight)
    nf = int(fly.sum())
    per = {}
    for bit, bit_name in REASONS.items():
        m = (codes & bit) != 0
        per[bit_name] = {"samples": int(m.sum()),
                         "flying_fraction": float((m & fly).sum() / nf) if nf else 0.0}
    marked = codes != 0
    return {"samples": int(codes.shape[0]), "flying_samples": nf,
            "marked_samples": int(marked.sum()),
            "marked_flying_fraction": float((marked & fly).sum() / nf) if nf else 0.0,
            "by_reason": per,
            "periods": [p.to_dict() for p in envelope_periods(flight.t, codes)]}


def uncalibrated_summary(flight: Flight) -> dict[str, Any] | None:
    """:func:`envelope_summary` on the raw rates (nominal axes), as ingest can give it
    before any calibration; None when the flight is not an IMU set in rad/s."""
    try:
        codes = flight_envelope(flight, None)
    except ConfigError:
        return None
    doc = envelope_summary(flight, codes)
    doc["rates"] = "uncalibrated (nominal axes of each IMU)"
    return doc


def describe_summary(doc: dict[str, Any]) -> str:
    """One line: the fraction of flying time marked, per reason."""
    per = ", ".join(f"{k} {100 * v['flying_fraction']:.1f} %"
                    for k, v in doc["by_reason"].items() if v["samples"])
    return (f"{100 * doc['marked_flying_fraction']:.1f} % of the flying time out of the "
            f"envelope in {len(doc['periods'])} period(s)" + (f" ({per})" if per else ""))
