"""The truth sidecar of a simulated session: ``DIR/truth.json``, ``"schema": "rimu.truth/1"``.

Same layout as a calibration file (:meth:`fdi.calfile.Calibration.to_dict`) holding the TRUE
values (every ``*_sd`` is 0), plus::

    "effects":        {name: value}            # effects switched on, in the units of
                                               # calibration.effects.EFFECTS
    "effect_sensors": {name: [1-based sensors]}
    "effect_units":   {name: unit}
    "effect_details": {...}                    # constants the effects used (tau, table rate)

The ``noise_covariance`` is the true per-sample white-noise covariance of the compensated
outputs (SI²). Compare a calibration with
``rimu calibrate turntable ... --compare DIR/truth.json``.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from calibration.effects import EFFECTS
from fdi.calfile import CALIBRATION_SCHEMA, Calibration, calibration_from_dict
from fdi.errors import FileFormatError
from fdi.fileio import read_json_object

__all__ = ["TRUTH_SCHEMA", "load_truth", "save_truth", "truth_to_dict"]

TRUTH_SCHEMA = "rimu.truth/1"


def truth_to_dict(cal: Calibration, effects: Mapping[str, float] | None = None,
                  effect_sensors: Mapping[str, Iterable[int]] | None = None,
                  details: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """JSON-ready truth document (see the module docstring)."""
    doc = cal.to_dict()
    doc["schema"] = TRUTH_SCHEMA
    eff = {str(k): float(v) for k, v in (effects or {}).items()}
    doc["effects"] = eff
    doc["effect_sensors"] = {str(k): [int(i) for i in v]
                             for k, v in (effect_sensors or {}).items()}
    doc["effect_units"] = {k: EFFECTS[k].unit for k in eff if k in EFFECTS}
    doc["effect_details"] = dict(details or {})
    return doc


def save_truth(cal: Calibration, effects: Mapping[str, float] | None,
               effect_sensors: Mapping[str, Iterable[int]] | None, path: str | Path, *,
               details: Mapping[str, Any] | None = None) -> None:
    """Write a truth sidecar.

    Parameters
    ----------
    cal : Calibration
        True parameters (sd fields 0).
    effects : mapping of name to value, or None
    effect_sensors : mapping of name to 1-based sensors, or None
    path : str or Path
    details : mapping, optional
        Constants the effects used (written under ``"effect_details"``).
    """
    doc = truth_to_dict(cal, effects, effect_sensors, details)
    Path(path).write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")


def load_truth(path: str | Path) -> tuple[Calibration, dict[str, float],
                                          dict[str, tuple[int, ...]]]:
    """Read a truth sidecar.

    Returns
    -------
    cal : Calibration
        The true parameters (``cal.schema`` is the calibration schema).
    effects : dict of name to value
    effect_sensors : dict of name to tuple of 1-based sensors

    Raises
    ------
    FileFormatError
        Missing file, bad JSON, wrong schema or version, bad field (named).
    """
    p = str(path)
    doc = read_json_object(path, TRUTH_SCHEMA)
    effects_raw = doc.get("effects", {})
    if not isinstance(effects_raw, dict):
        raise FileFormatError(p, "expected an object {name: value}", field="effects")
    effects: dict[str, float] = {}
    for k, v in effects_raw.items():
        if k not in EFFECTS:
            raise FileFormatError(p, f"unknown effect; expected one of {', '.join(EFFECTS)}",
                                  field=f"effects.{k}")
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise FileFormatError(p, f"expected a finite number, got {v!r}",
                                  field=f"effects.{k}")
        effects[k] = float(v)
    es_raw = doc.get("effect_sensors", {})
    if not isinstance(es_raw, dict):
        raise FileFormatError(p, "expected an object {name: [sensors]}",
                              field="effect_sensors")
    effect_sensors: dict[str, tuple[int, ...]] = {}
    for k, v in es_raw.items():
        if not isinstance(v, list) or not all(isinstance(i, int) and not isinstance(i, bool)
                                              and i >= 1 for i in v):
            raise FileFormatError(p, f"expected a list of sensor numbers from 1, got {v!r}",
                                  field=f"effect_sensors.{k}")
        effect_sensors[k] = tuple(v)
    cal_doc = {k: v for k, v in doc.items()
               if k not in ("effects", "effect_sensors", "effect_units", "effect_details")}
    cal_doc["schema"] = CALIBRATION_SCHEMA
    cal = calibration_from_dict(cal_doc, p)
    return cal, effects, effect_sensors
