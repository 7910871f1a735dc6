"""All typed entries of a calibration's ``extra`` block (:class:`CalibrationExtras`) and the
one function that reads them (:func:`extras_from_dict`)."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fdi.extras.ferraris import FerrarisRecord, read_ferraris
from fdi.extras.inflight import (
    InflightAlignment,
    InflightTiming,
    inflight_to_dict,
    read_inflight_alignment,
    read_inflight_timing,
)
from fdi.extras.read import floats, plain, strings
from fdi.extras.static import StaticAlignment, read_static
from fdi.extras.turntable import (
    EarthRateRecord,
    GyroBias,
    NoiseModel,
    RateTest,
    ResidualStep,
    parity_sd_to_dict,
    read_earth_rate,
    read_gyro_bias,
    read_noise_model,
    read_parity_sd,
    read_rate_test,
    read_residual_steps,
    residual_steps_to_dict,
)
from fdi.fileio import Fields

__all__ = ["FERRARIS_LAYOUT", "INFLIGHT_LAYOUT", "STATIC_LAYOUT", "TURNTABLE_LAYOUT",
           "TYPED_KEYS", "CalibrationExtras", "Method", "extras_from_dict", "replace_extras"]

_PREFIX = "extra"
TYPED_KEYS = ("earth_rate_fit", "ferraris", "gyro_bias", "inflight", "method", "noise_model",
              "parity_accel_calibrated_sd", "parity_calibrated_sd", "rate_test",
              "residual_steps", "source", "static", "step_residual_chi2_dof", "warnings")
"""Keys of ``extra`` read into types (the others are kept as they are, unchecked)."""


@dataclass(frozen=True)
class Method:
    """How the calibration was made (``extra.method``): one line, or one line per part.

    Attributes
    ----------
    text : str
        The file's ``method`` when it is a string (in-flight, static calibrations).
    parts : dict of str to str
        The file's ``method`` when it is an object (turntable: ``gyro``, ``bias``,
        ``denoise``; Ferraris: ``gyro``, ``accel``).
    """

    text: str = ""
    parts: Mapping[str, str] = field(default_factory=dict)

    def part(self, key: str, default: str = "") -> str:
        """The line of one part (``default`` when the file has none)."""
        return self.parts.get(key, default)

    def to_dict(self) -> str | dict[str, str]:
        """The JSON value of ``extra.method``: :attr:`parts` when there are any, else
        :attr:`text`."""
        return dict(self.parts) if self.parts else self.text


def read_method(r: Fields) -> Method:
    v = r.get("method", "")
    if isinstance(v, str):
        return Method(text=v)
    m = r.mapping("method")
    return Method(parts={k: m.string(k, "", nonempty=False) for k in m.keys()})


# -- all of them ------------------------------------------------------------------------
@dataclass(frozen=True)
class CalibrationExtras:
    """The typed entries of ``Calibration.extra`` (see the module docstring).

    Attributes
    ----------
    inflight : InflightTiming or None
        In-flight calibrations only: the time offsets.
    inflight_alignment : InflightAlignment or None
        In-flight calibrations only: the alignment estimates.
    warnings : tuple of str
        What the calibration warns about, one line each.
    source : str
        The session or flight it was made from (``""`` when not recorded).
    method : Method
    static : StaticAlignment or None
        Static (at rest) calibrations only.
    noise_model : NoiseModel or None
        Turntable calibrations only.
    rate_test : RateTest or None
    step_residual_chi2_dof : tuple of float
        Per gyro, χ²/dof of the per-step residual means (expectation 1 under white noise).
    residual_steps : dict of str to tuple of ResidualStep
        Per sensor kind.
    earth_rate_fit : EarthRateRecord or None
    gyro_bias : GyroBias or None
    parity_sd : dict of str to tuple of tuple of float
        Per sensor kind, the first-order sd of the calibrated parity matrix, shape (n-3, n)
        (dimensionless; ``()`` for a set of three).
    ferraris : FerrarisRecord or None
        Ferraris calibrations only.
    """

    inflight: InflightTiming | None = None
    inflight_alignment: InflightAlignment | None = None
    warnings: tuple[str, ...] = ()
    source: str = ""
    method: Method = field(default_factory=Method)
    static: StaticAlignment | None = None
    noise_model: NoiseModel | None = None
    rate_test: RateTest | None = None
    step_residual_chi2_dof: tuple[float, ...] = ()
    residual_steps: Mapping[str, tuple[ResidualStep, ...]] = field(default_factory=dict)
    earth_rate_fit: EarthRateRecord | None = None
    gyro_bias: GyroBias | None = None
    parity_sd: Mapping[str, tuple[tuple[float, ...], ...]] = field(default_factory=dict)
    ferraris: FerrarisRecord | None = None

    def time_offsets_s(self) -> dict[str, float]:
        """``{IMU group: τ (s)}`` of an in-flight calibration (empty for any other)."""
        return {} if self.inflight is None else self.inflight.time_offsets_s()

    def to_dict(self, layout: Sequence[str] = (),
                other: Mapping[str, Any] | None = None) -> dict[str, Any]:
        """The ``extra`` block: the JSON of the typed entries, in the file's units.

        Parameters
        ----------
        layout : sequence of str
            The ``extra`` keys a writer lists, in its order (:data:`TURNTABLE_LAYOUT`,
            :data:`FERRARIS_LAYOUT`, :data:`STATIC_LAYOUT`, :data:`INFLIGHT_LAYOUT`): each is
            written unless its entry is None, empty ones too (``"warnings": []``). Other typed
            entries follow in :data:`TYPED_KEYS` order, only when set (not None, not empty).
        other : mapping, optional
            Entries the types do not cover (``regressors``, ``refit``, ...): placed where
            ``layout`` lists them, else at the end.

        Returns
        -------
        dict
        """
        entries = {**_entries(self, frozenset(layout)), **(other or {})}
        order = dict.fromkeys([*layout, *TYPED_KEYS, *entries])
        return {k: entries[k] for k in order if k in entries}


TURNTABLE_LAYOUT = ("source", "method", "rate_test", "step_residual_chi2_dof", "warnings",
                    "noise_model", "gyro_bias", "parity_calibrated_sd", "residual_steps",
                    "regressors", "earth_rate_fit", "parity_accel_calibrated_sd")
"""The ``extra`` keys of a turntable calibration (``rimu calibrate turntable``), in order."""
FERRARIS_LAYOUT = ("source", "method", "ferraris", "warnings")
"""The ``extra`` keys of a Ferraris calibration, in order."""
STATIC_LAYOUT = ("method", "source", "static")
"""The ``extra`` keys of a calibration at rest (``rimu calibrate static``), in order."""
INFLIGHT_LAYOUT = ("method", "source", "inflight")
"""The ``extra`` keys of an in-flight calibration (``rimu calibrate in-flight``), in order."""


def _set(v: Any) -> bool:
    """Not None and not empty."""
    return v is not None and not (isinstance(v, str | tuple | list | Mapping) and not v)


def _json(v: Any) -> Any:
    return v.to_dict()


def _array(v: Any) -> np.ndarray:
    return np.array(v, float)


_WRITE: dict[str, Callable[[Any], Any]] = {
    "warnings": list, "source": str, "method": _json, "static": _json,
    "noise_model": _json, "rate_test": _json, "step_residual_chi2_dof": _array,
    "residual_steps": residual_steps_to_dict, "earth_rate_fit": _json, "gyro_bias": _json,
    "ferraris": _json}
"""How each field of :class:`CalibrationExtras` becomes its JSON (``parity_sd`` and the
in-flight pair are written by :func:`_entries`)."""


def _entries(x: CalibrationExtras, always: frozenset[str]) -> dict[str, Any]:
    """``{extra key: JSON}`` of the fields of ``x`` to write: set, or listed in ``always``
    and not None."""
    out: dict[str, Any] = dict(parity_sd_to_dict(x.parity_sd))
    if x.inflight is not None or x.inflight_alignment is not None:
        out["inflight"] = inflight_to_dict(x.inflight, x.inflight_alignment)
    for name, write in _WRITE.items():
        v = getattr(x, name)
        if name == "method" and not _set(v.to_dict()) and name not in always:
            continue
        if _set(v) or (v is not None and name in always):
            out[name] = write(v)
    return out


def replace_extras(extra: Mapping[str, Any], **entries: Any) -> dict[str, Any]:
    """A copy of an ``extra`` block with some typed entries written anew (a key keeps its
    place; a new one goes at the end). The other entries are copied as they are.

    Parameters
    ----------
    extra : mapping
    **entries
        Fields of :class:`CalibrationExtras` (``warnings=[...]``), written as
        :meth:`CalibrationExtras.to_dict` writes them (empty ones too).
    """
    out = dict(extra)
    out.update(CalibrationExtras(**entries).to_dict(layout=tuple(entries)))
    return out


def extras_from_dict(extra: Mapping[str, Any], path: str = "<calibration>"
                     ) -> CalibrationExtras:
    """Read the typed entries of an ``extra`` block (a calibration file's or one in memory).

    Parameters
    ----------
    extra : mapping
        The block; numpy values are read as their JSON would be.
    path : str
        The file, for the messages.

    Raises
    ------
    FileFormatError
        A typed entry of the wrong type; the message names the file and the field
        (``extra.inflight.imus.imu2.time_offset_ms``).
    """
    r = Fields({k: plain(extra[k]) for k in TYPED_KEYS if k in extra}, path, _PREFIX)
    return CalibrationExtras(
        inflight=read_inflight_timing(r), inflight_alignment=read_inflight_alignment(r),
        warnings=strings(r, "warnings"), source=r.string("source", "", nonempty=False),
        method=read_method(r), static=read_static(r), noise_model=read_noise_model(r),
        rate_test=read_rate_test(r),
        step_residual_chi2_dof=floats(r, "step_residual_chi2_dof"),
        residual_steps=read_residual_steps(r), earth_rate_fit=read_earth_rate(r),
        gyro_bias=read_gyro_bias(r), parity_sd=read_parity_sd(r), ferraris=read_ferraris(r))
