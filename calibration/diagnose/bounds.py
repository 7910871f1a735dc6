"""Physical bounds of effect sizes per sensor class: an estimate beyond one is absorbing
something else.

A fitted effect term is a number whatever it absorbs: a warm-up and a drift fitted
together to a curved drift can come out at tens of °/h each, opposite in sign, on a
sensor whose warm-up cannot be that large. Such an estimate is not a physical claim. Each
effect found is compared with a plausible bound for the class of sensor; beyond it the
output labels it ``"beyond the physical bound ... : absorbing something else"``
(``physical`` false in the JSON) instead of presenting it as the sensor's property.

Classes. The class is read from the calibration itself, the gyros' white noise
(angle random walk, ``σ/√f_s``): below :data:`FOG_CLASS_ARW_DPSH` °/√h the set is
"fog" (fibre-optic or other tactical/navigation-grade gyros: roughly 0.01-0.3 °/√h),
above it "mems" (MEMS rate gyros of the ADXRS class: 0.5-3 °/√h; the ADXRS150 of the
cone preset has 0.05 °/s/√Hz = 3 °/√h). The accelerometers of a set take the gyros'
class. Coarse: a high-end MEMS unit (0.15-0.4 °/√h) reads as fog; ``sensor_class``
overrides it.

Bounds (:data:`PHYSICAL_BOUNDS`, from each effect spec's ``bounds``). Each is two to ten
times the magnitude the class's data sheets give for the effect (so that only an estimate
no sensor of the class could have is labelled, not one from a poor unit), in the effect's
unit. Sources, order of magnitude:

- MEMS gyros: Analog Devices ADXRS150 data sheet (acceleration sensitivity 0.2 °/s per g,
  nonlinearity 0.1 % of full scale, null drift of tenths of °/s over temperature);
  accelerometers: ADXL202E / ADXL313 / ADXL350 data sheets (0 g offset drift 0.5 mg/°C,
  nonlinearity 0.5 % of full scale, alignment 0.1°, cross-axis 1-3 %).
- FOG: tactical-grade FOG data sheets (KVH DSP-1750-class; KVH, "Understanding
  specifications of fiber optic gyros", 2012): bias instability 0.05-1 °/h, bias over
  temperature and warm-up of a few °/h, g-sensitivity below 1 °/h per g, scale-factor
  nonlinearity and asymmetry of 100-500 ppm.
- both: a sampling delay within a few sample periods (a skew of a second is a time-stamp
  error, not a sensor effect); a re-mounting tilt within tens of mrad (a degree or two;
  beyond it the mounting, not the sensor, moved); a fraction of the Earth rate missing
  within 0-1.

The bounds describe sensors, not a session: they are not tuned to any test.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from fdi.calfile import Calibration
from fdi.effect_specs import effect_specs
from fdi.units import DPS

__all__ = ["FOG_CLASS_ARW_DPSH", "PHYSICAL_BOUNDS", "SENSOR_CLASSES", "bound_check",
           "bound_label", "sensor_class"]

SENSOR_CLASSES = ("fog", "mems")
FOG_CLASS_ARW_DPSH = 0.5
"""Angle random walk (°/√h) below which a gyro set is taken as FOG / tactical class."""

PHYSICAL_BOUNDS: dict[str, dict[tuple[str, str], float]] = {
    cls: {(sp.name, kind): b for sp in effect_specs()
          for kind, b in sp.bounds.get(cls, {}).items()}
    for cls in SENSOR_CLASSES}
"""Largest plausible |estimate| per class, (effect, kind), in the effect's unit (module
docstring for the sources; each spec's ``bounds``, :mod:`fdi.effect_specs.builtin`).
Effects bounded alike in every class are in :data:`_COMMON`."""

_COMMON: dict[tuple[str, str], float] = {
    (sp.name, kind): b for sp in effect_specs() for kind, b in sp.bounds.get("*", {}).items()}
_FRACTION_RANGE = {sp.name: sp.fraction_range for sp in effect_specs() if sp.fraction_range}
"""Effects whose value is a fraction of a physical quantity: the plausible interval
(0-1, with a margin for the estimate's scatter)."""


def sensor_class(cal: Calibration) -> str:
    """The class of the calibration's gyro set from its white noise (module docstring)."""
    g = cal.sets.get("gyro")
    if g is None or not cal.sample_rate_hz > 0:
        return "mems"
    var = np.diag(np.asarray(g.noise_covariance, float))
    if var.size == 0 or not np.all(np.isfinite(var)):
        return "mems"
    arw_dpsh = float(np.sqrt(np.median(var) / cal.sample_rate_hz)) / DPS * 60.0
    return "fog" if arw_dpsh < FOG_CLASS_ARW_DPSH else "mems"


def bound_check(name: str, kind: str, estimate: float, cls: str
                ) -> dict[str, Any] | None:
    """The bound of an effect for a class and whether the estimate is within it; None
    when the effect has no bound (a user effect).

    Returns
    -------
    dict
        ``{"sensor_class", "bound", "physical"}`` (``bound`` a number, or ``[lo, hi]``
        for a fraction).
    """
    if name in _FRACTION_RANGE:
        lo, hi = _FRACTION_RANGE[name]
        return {"sensor_class": cls, "bound": [lo, hi],
                "physical": bool(lo <= estimate <= hi)}
    b = PHYSICAL_BOUNDS.get(cls, {}).get((name, kind), _COMMON.get((name, kind)))
    if b is None:
        return None
    return {"sensor_class": cls, "bound": b, "physical": bool(abs(estimate) <= b)}


def bound_label(rec: Mapping[str, Any], unit: str) -> str:
    """The label of an estimate beyond its bound (empty when within it)."""
    if rec.get("physical", True):
        return ""
    b = rec["bound"]
    lim = f"{b[0]:g} to {b[1]:g}" if isinstance(b, list) else f"|{b:g}|"
    return (f"beyond the physical bound of a {rec['sensor_class']}-class sensor "
            f"({lim} {unit}): absorbing something else, not a property of the sensor")
