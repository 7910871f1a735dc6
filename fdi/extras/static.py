"""Typed record of a static (at rest) calibration (``extra.static``): each IMU's rotation,
bias and drift relative to the reference and what of the drift is whose. Angles in rad,
rates in rad/s (``_deg``, ``_dps`` in the file)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fdi.extras.read import floats, strings
from fdi.fileio import Fields
from fdi.units import DEG, DPS

__all__ = ["ATTRIBUTION_UNIT", "DriftAttribution", "OwnDrift", "StaticAlignment", "StaticImu",
           "read_static"]

ATTRIBUTION_UNIT = "deg/s over the record (body frame of the reference)"
"""``extra.static.drift_attribution.unit``: the unit of the drifts in the file."""


def _dps(v: tuple[float, ...]) -> list[float]:
    return (np.asarray(v, float) / DPS).tolist()


@dataclass(frozen=True)
class StaticImu:
    """One IMU of a static (at rest) calibration, relative to the reference
    (``extra.static.imus.<imu>``; degrees and deg/s in the file).

    Attributes
    ----------
    rotation, rotation_sd : tuple of float
        Rotation vector onto the reference and its sd (rad).
    relative_bias : tuple of float
        Bias relative to the reference (rad/s).
    relative_drift, relative_drift_sd : tuple of float
        Change of that bias over the record and its sd (rad/s).
    relative_drift_z, relative_drift_p : tuple of float
        Its z and p-value per axis.
    drift_block_s : float
        Block length of the drift's sd (s).
    drift_hac_lags : int
    """

    rotation: tuple[float, ...] = ()
    rotation_sd: tuple[float, ...] = ()
    relative_bias: tuple[float, ...] = ()
    relative_drift: tuple[float, ...] = ()
    relative_drift_sd: tuple[float, ...] = ()
    relative_drift_z: tuple[float, ...] = ()
    relative_drift_p: tuple[float, ...] = ()
    drift_block_s: float = float("nan")
    drift_hac_lags: int = 0

    def to_dict(self) -> dict[str, Any]:
        """The JSON record (``extra.static.imus.<imu>``; degrees and deg/s)."""
        return {"rotation_deg": np.degrees(np.asarray(self.rotation, float)).tolist(),
                "rotation_deg_sd": np.degrees(np.asarray(self.rotation_sd, float)).tolist(),
                "relative_bias_dps": _dps(self.relative_bias),
                "relative_drift_dps": _dps(self.relative_drift),
                "relative_drift_dps_sd": _dps(self.relative_drift_sd),
                "relative_drift_z": list(self.relative_drift_z),
                "relative_drift_p": list(self.relative_drift_p),
                "drift_block_s": self.drift_block_s, "drift_hac_lags": self.drift_hac_lags}


@dataclass(frozen=True)
class OwnDrift:
    """One IMU's drift relative to the reference (``extra.static.drift_attribution.own``).

    Attributes
    ----------
    drift : tuple of float
        Change over the record (rad/s, body frame of the reference).
    z : tuple of float
        Per axis, drift over its sd.
    p_value : float
        χ² test of the three together.
    """

    drift: tuple[float, ...] = ()
    z: tuple[float, ...] = ()
    p_value: float = float("nan")

    def to_dict(self) -> dict[str, Any]:
        """The JSON record (deg/s)."""
        return {"drift": _dps(self.drift), "z": list(self.z), "p_value": self.p_value}


@dataclass(frozen=True)
class DriftAttribution:
    """What of the IMUs' drifts relative to the reference is the reference's own
    (``extra.static.drift_attribution``, :func:`calibration.inflight.static.attribute_drift`).

    Attributes
    ----------
    common, common_sd : tuple of float
        The drift every IMU shares relative to the reference (minus the reference's own)
        and its sd (rad/s).
    common_p : float
        Its χ² p-value.
    consistent_chi2, consistent_p : float
        χ² and p-value of the IMUs differing from the common drift.
    consistent_dof : int
    own : dict of str to OwnDrift
    statement : str
        The conclusion, one line.
    """

    common: tuple[float, ...] = ()
    common_sd: tuple[float, ...] = ()
    common_p: float = float("nan")
    consistent_chi2: float = float("nan")
    consistent_dof: int = 0
    consistent_p: float = float("nan")
    own: Mapping[str, OwnDrift] = field(default_factory=dict)
    statement: str = ""

    def to_dict(self) -> dict[str, Any]:
        """The JSON record (``extra.static.drift_attribution``; deg/s)."""
        return {"common": _dps(self.common), "common_sd": _dps(self.common_sd),
                "common_p": self.common_p, "consistent_chi2": self.consistent_chi2,
                "consistent_dof": self.consistent_dof, "consistent_p": self.consistent_p,
                "own": {g: o.to_dict() for g, o in self.own.items()},
                "statement": self.statement, "unit": ATTRIBUTION_UNIT}


@dataclass(frozen=True)
class StaticAlignment:
    """A static (at rest) calibration's record (``extra.static``).

    Attributes
    ----------
    reference : str
        The IMU the others are aligned to.
    imus : dict of str to StaticImu
        Per IMU other than the reference.
    drift_attribution : DriftAttribution or None
    notes : tuple of str
    alpha : float
        Level of the drift tests.
    bias, bias_sd : tuple of float
        Per sensor (rad/s; file: ``bias_dps``, ``bias_dps_sd``).
    samples : int
    duration_s : float
        Length of the record at rest (s).
    alignment_full : bool
        The full rotation was observable (gravity alone leaves the rotation about it free).
    """

    reference: str = ""
    imus: Mapping[str, StaticImu] = field(default_factory=dict)
    drift_attribution: DriftAttribution | None = None
    notes: tuple[str, ...] = ()
    alpha: float = float("nan")
    bias: tuple[float, ...] = ()
    bias_sd: tuple[float, ...] = ()
    samples: int = 0
    duration_s: float = float("nan")
    alignment_full: bool = True

    def to_dict(self) -> dict[str, Any]:
        """The JSON record (``extra.static``; degrees and deg/s)."""
        attr = {} if self.drift_attribution is None else {
            "drift_attribution": self.drift_attribution.to_dict()}
        return {"reference": self.reference,
                "imus": {g: m.to_dict() for g, m in self.imus.items()},
                "alignment_full": self.alignment_full, "notes": list(self.notes), **attr,
                "alpha": self.alpha, "bias_dps": _dps(self.bias), "bias_dps_sd": _dps(self.bias_sd),
                "samples": self.samples, "duration_s": self.duration_s}


def _static_imu(r: Fields) -> StaticImu:
    return StaticImu(
        rotation=floats(r, "rotation_deg", scale=DEG),
        rotation_sd=floats(r, "rotation_deg_sd", scale=DEG),
        relative_bias=floats(r, "relative_bias_dps", scale=DPS),
        relative_drift=floats(r, "relative_drift_dps", scale=DPS),
        relative_drift_sd=floats(r, "relative_drift_dps_sd", scale=DPS),
        relative_drift_z=floats(r, "relative_drift_z"),
        relative_drift_p=floats(r, "relative_drift_p"),
        drift_block_s=r.number("drift_block_s", float("nan"), finite=False),
        drift_hac_lags=r.integer("drift_hac_lags", 0, lo=0))


def _attribution(r: Fields) -> DriftAttribution | None:
    if "drift_attribution" not in r:
        return None
    a = r.mapping("drift_attribution")
    own = a.mapping("own", {})
    nan = float("nan")

    def own_drift(o: Fields) -> OwnDrift:
        return OwnDrift(drift=floats(o, "drift", scale=DPS), z=floats(o, "z"),
                        p_value=o.number("p_value", nan, finite=False))

    return DriftAttribution(
        common=floats(a, "common", scale=DPS), common_sd=floats(a, "common_sd", scale=DPS),
        common_p=a.number("common_p", nan, finite=False),
        consistent_chi2=a.number("consistent_chi2", nan, finite=False),
        consistent_dof=a.integer("consistent_dof", 0, lo=0),
        consistent_p=a.number("consistent_p", nan, finite=False),
        own={g: own_drift(own.mapping(g)) for g in own.keys()},
        statement=a.string("statement", "", nonempty=False))


def read_static(r: Fields) -> StaticAlignment | None:
    """``extra.static`` (None when absent)."""
    if "static" not in r:
        return None
    s = r.mapping("static")
    imus = s.mapping("imus", {})
    return StaticAlignment(
        reference=s.string("reference", "", nonempty=False),
        imus={g: _static_imu(imus.mapping(g)) for g in imus.keys()},
        drift_attribution=_attribution(s), notes=strings(s, "notes"),
        alpha=s.number("alpha", float("nan"), finite=False),
        bias=floats(s, "bias_dps", scale=DPS), bias_sd=floats(s, "bias_dps_sd", scale=DPS),
        samples=s.integer("samples", 0, lo=0),
        duration_s=s.number("duration_s", float("nan"), finite=False),
        alignment_full=s.boolean("alignment_full", True))

