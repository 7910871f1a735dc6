"""Estimate against truth: estimate, truth, error and error/σ side by side.

Used by ``rimu calibrate turntable SESSION --compare TRUTH`` and by the acceptance tests.
Values are shown in the calibration's own file units (scale factors in ``scale_factor_unit``, biases
in ``bias_unit``, misalignment angles in mrad about the nominal axis, Earth rate in °/h).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from calibration.effects import EARTH_RATE_KNOB, TEMP_START_DEGC, TEMPERATURE_KNOB
from fdi.calfile import Calibration, misalignment_angles
from fdi.errors import ConfigError
from fdi.units import (
    DPH,
    EARTH_RATE_DPH,
    input_unit_factor,
    scale_factor_from_si,
    scale_factor_sd_from_si,
)

__all__ = ["ComparisonRow", "compare", "format_comparison", "true_bias",
           "true_earth_rate_dph"]


@dataclass(frozen=True)
class ComparisonRow:
    """One estimated parameter against its true value.

    Attributes
    ----------
    kind : str
        ``"gyro"``, ``"accel"`` or ``"site"``.
    sensor : str
        Sensor name (``""`` for the Earth rate).
    parameter : str
        ``"scale_factor"``, ``"bias"``, ``"misalignment_1"``, ``"misalignment_2"``,
        ``"earth_rate"``.
    unit : str
    estimate, truth, sd : float
    """

    kind: str
    sensor: str
    parameter: str
    unit: str
    estimate: float
    truth: float
    sd: float

    @property
    def error(self) -> float:
        """estimate − truth."""
        return self.estimate - self.truth

    @property
    def z(self) -> float:
        """error / σ (NaN when σ is 0)."""
        return self.error / self.sd if self.sd > 0 else float("nan")


def true_earth_rate_dph(truth: Calibration, effects: Mapping[str, float] | None = None) -> float:
    """The Earth rate a simulated session contains: 0 with ``no_earth_rate``, else the
    truth's ``earth_rate_dph`` or 15.041 °/h."""
    if effects and effects.get(EARTH_RATE_KNOB):
        return 0.0
    return truth.earth_rate_dph if truth.earth_rate_dph is not None else EARTH_RATE_DPH


def true_bias(cal: Calibration, truth: Calibration, kind: str, i: int,
              effects: Mapping[str, float] | None,
              effect_sensors: Mapping[str, tuple[int, ...]] | None) -> float:
    """The true bias (SI) of sensor ``i`` of ``kind`` at the calibration's reference.

    A calibration with a ``temperature`` term states its bias at the term's reference
    temperature T_ref (``params.reference_degC``, the session mean); the simulator's bias
    is at T₀ = :data:`calibration.effects.TEMP_START_DEGC`. When the truth has the
    temperature knob on this sensor (value k in °/h per °C), the bias the calibration
    estimates is b₀ + k·(T_ref − T₀). Otherwise the truth's bias as it is.
    """
    b0 = truth.sets[kind].sensors[i].bias
    k = (effects or {}).get(TEMPERATURE_KNOB, 0.0)
    on = (effect_sensors or {}).get(TEMPERATURE_KNOB, ())
    if kind != "gyro" or k == 0.0 or (i + 1) not in on:
        return b0
    for term in cal.effects:
        if (term.name, term.kind, term.sensor) == (TEMPERATURE_KNOB, kind, i) \
                and "reference_degC" in term.params:
            t_ref = float(term.params["reference_degC"])
            return b0 + k * DPH * (t_ref - TEMP_START_DEGC)
    return b0


def compare(cal: Calibration, truth: Calibration,
            effects: Mapping[str, float] | None = None,
            effect_sensors: Mapping[str, tuple[int, ...]] | None = None
            ) -> list[ComparisonRow]:
    """Rows of every parameter both calibrations hold.

    ``effects`` and ``effect_sensors`` are the truth sidecar's knobs
    (:func:`calibration.truth.load_truth`): they set the true Earth rate and the true bias at
    the calibration's temperature reference (:func:`true_bias`).

    Raises
    ------
    ConfigError
        The two have different sensor counts for a kind.
    """
    rows: list[ComparisonRow] = []
    for kind, est in cal.sets.items():
        if kind not in truth.sets:
            continue
        tru = truth.sets[kind]
        if tru.n != est.n:
            raise ConfigError(f"{kind}: calibration has {est.n} sensors, truth has {tru.n}")
        for i, (e, t) in enumerate(zip(est.sensors, tru.sensors, strict=True)):
            u = e.scale_factor_unit
            rows.append(ComparisonRow(
                kind, e.name, "scale_factor", u, scale_factor_from_si(e.scale_factor, u),
                scale_factor_from_si(t.scale_factor, u),
                scale_factor_sd_from_si(e.scale_factor, e.scale_factor_sd, u)))
            bf = input_unit_factor(e.bias_unit)
            tb = true_bias(cal, truth, kind, i, effects, effect_sensors)
            rows.append(ComparisonRow(kind, e.name, "bias", e.bias_unit, e.bias / bf,
                                      tb / bf, e.bias_sd / bf))
            me = e.misalignment
            mt = misalignment_angles(e.axis_nominal, t.axis)
            for j in range(2):
                rows.append(ComparisonRow(kind, e.name, f"misalignment_{j + 1}", "mrad",
                                          1e3 * me[j], 1e3 * mt[j],
                                          1e3 * float(e.misalignment_sd[j])))
    if cal.earth_rate_dph is not None and cal.earth_rate_dph_sd is not None:
        rows.append(ComparisonRow("site", "", "earth_rate", "deg/h", cal.earth_rate_dph,
                                  true_earth_rate_dph(truth, effects), cal.earth_rate_dph_sd))
    return rows


def _fmt(v: float) -> str:
    if not math.isfinite(v):
        return "nan"
    return f"{v:.6g}"


def format_comparison(rows: list[ComparisonRow]) -> str:
    """A readable table; the last line counts the rows beyond 3σ."""
    head = ("kind", "sensor", "parameter", "unit", "estimate", "truth", "error", "sd",
            "error/sd")
    body = [(r.kind, r.sensor, r.parameter, r.unit, _fmt(r.estimate), _fmt(r.truth),
             _fmt(r.error), _fmt(r.sd), f"{r.z:+.2f}" if math.isfinite(r.z) else "nan")
            for r in rows]
    widths = [max(len(x[k]) for x in [head, *body]) for k in range(len(head))]
    lines = ["  ".join(x[k].ljust(widths[k]) if k < 4 else x[k].rjust(widths[k])
                       for k in range(len(head))) for x in [head, *body]]
    z = np.array([r.z for r in rows], float)
    ok = np.isfinite(z)
    n_out = int(np.sum(np.abs(z[ok]) > 3))
    lines.append(f"{int(ok.sum())} parameters compared, {n_out} beyond 3 sigma"
                 + (f", max |error/sd| = {np.max(np.abs(z[ok])):.2f}" if ok.any() else ""))
    return "\n".join(lines)
