"""Which thresholds the monitor uses, and where they came from (one policy for every command).

:func:`select` is the single place that turns the options of ``rimu monitor-file``,
``rimu replay`` and ``rimu monitor`` into thresholds:

1. a thresholds file (``--thresholds``): a ``rimu.thresholds/2`` (or ``/1``) file, or a
   ``rimu.tuning/1`` file written by ``rimu tune`` (thresholds with their assumptions);
   source ``"file"`` or ``"tuned"``;
2. otherwise thresholds computed from the calibration for a false-alarm budget
   (``--false-alarms-per-hour``, default :data:`DEFAULT_FALSE_ALARMS_PER_HOUR`); source
   ``"calibration"``.

A file made for another sensor kind or number of sensors is refused here, naming the file;
so is a file made for another calibration or sample rate (:func:`check_made_for`): a
``rimu.thresholds/2`` file records the fingerprint of the calibration it was made for
(``calibration_fingerprint``, :meth:`fdi.calfile.Calibration.fingerprint`); an older file
records none and is accepted with a one-line warning.

It lives in :mod:`replay`, below :mod:`thresholds`, because the monitoring chain
(:mod:`replay.chain`) chooses its thresholds here; thresholds computed for a budget are
:func:`fdi.detector.default_thresholds`, the arithmetic :func:`thresholds.compute_thresholds`
runs when it is given no residuals (the provenance names that function, as before).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fdi.calfile import Calibration
from fdi.detector import default_thresholds
from fdi.errors import ConfigError, FileFormatError
from fdi.fileio import read_json_object
from fdi.settings import THRESHOLDS_SCHEMA, Thresholds, thresholds_from_dict

__all__ = ["DEFAULT_FALSE_ALARMS_PER_HOUR", "SAMPLE_RATE_RTOL", "SOURCES", "TUNING_SCHEMA",
           "ThresholdChoice", "check_made_for", "load_any_thresholds", "select"]

DEFAULT_FALSE_ALARMS_PER_HOUR = 1e-3
"""False-alarm budget (per hour) of thresholds computed when none is asked for."""
TUNING_SCHEMA = "rimu.tuning/1"
"""Schema of the files ``rimu tune`` writes (thresholds plus their assumptions)."""
SOURCES = ("file", "calibration", "tuned")
"""Where thresholds can come from."""
SAMPLE_RATE_RTOL = 1e-6
"""Relative difference of sample rates taken as the same rate (a JSON round trip)."""


@dataclass(frozen=True)
class ThresholdChoice:
    """Thresholds and their provenance.

    Attributes
    ----------
    thresholds : Thresholds
    source : str
        ``"file"`` (a ``rimu.thresholds/2`` (or ``/1``) file), ``"tuned"`` (a
        ``rimu.tuning/1`` file) or ``"calibration"`` (computed here from the
        calibration's statistics).
    assumptions : dict
        What the thresholds rest on: the file, the budget, and for tuned files the
        assumptions ``rimu tune`` recorded (noise model, Allan deviation per scale, ...).
    """

    thresholds: Thresholds
    source: str
    assumptions: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """Short JSON-ready provenance for reports (the thresholds themselves left out)."""
        out: dict[str, Any] = {"source": self.source,
                               "false_alarms_per_hour": self.thresholds.false_alarms_per_hour,
                               "scales": list(self.thresholds.scales)}
        for k in ("file", "method"):
            if k in self.assumptions:
                out[k] = self.assumptions[k]
        return out


def load_any_thresholds(path: str | Path) -> tuple[Thresholds, str, dict[str, Any]]:
    """Read a ``rimu.thresholds/2`` (or ``/1``) or ``rimu.tuning/1`` file.

    Returns
    -------
    thresholds : Thresholds
    source : str
        ``"file"`` or ``"tuned"``.
    assumptions : dict
        The tuning file's ``assumptions`` (empty for a plain thresholds file).

    Raises
    ------
    FileFormatError
        Naming the file and the field.
    """
    doc = read_json_object(path)
    schema = doc.get("schema")
    if schema == TUNING_SCHEMA:
        inner = doc.get("thresholds")
        if not isinstance(inner, dict):
            raise FileFormatError(str(path), "expected an object with the thresholds",
                                  field="thresholds")
        try:
            thr = thresholds_from_dict(inner, str(path))
        except FileFormatError as exc:
            raise FileFormatError(str(path), exc.detail,
                                  field=f"thresholds.{exc.field}" if exc.field
                                  else "thresholds") from None
        ass = doc.get("assumptions", {})
        if not isinstance(ass, dict):
            raise FileFormatError(str(path), "expected an object", field="assumptions")
        return thr, "tuned", dict(ass)
    if schema not in (THRESHOLDS_SCHEMA, None) and str(schema).startswith("rimu.tuning/"):
        raise FileFormatError(str(path), f"schema {schema!r} is not readable by this rimu; "
                              f"expected {TUNING_SCHEMA!r}", field="schema")
    return thresholds_from_dict(doc, str(path)), "file", {}


def check_made_for(thr: Any, cal: Calibration, thresholds_file: str | Path,
                   calibration_file: str | Path | None = None) -> None:
    """Refuse thresholds made for another calibration or sample rate.

    Parameters
    ----------
    thr : Thresholds
        As loaded; ``calibration_fingerprint`` (``rimu.thresholds/2``) names the
        calibration it was made for, empty or absent for a ``/1`` file.
    cal : Calibration
        The calibration the monitor runs with.
    thresholds_file, calibration_file : path
        For the messages (``calibration_file`` None: the calibration's configuration).

    Raises
    ------
    ConfigError
        One line naming both files and what differs. An old file without a fingerprint is
        accepted with a one-line ``rimu: warning:``.
    """
    where = (f"the calibration {calibration_file}" if calibration_file is not None
             else f"the calibration of {cal.configuration}")
    fs_thr, fs_cal = float(thr.sample_rate_hz), float(cal.sample_rate_hz)
    if not math.isclose(fs_thr, fs_cal, rel_tol=SAMPLE_RATE_RTOL):
        raise ConfigError(f"{thresholds_file}: thresholds made for {fs_thr:g} Hz, {where} is "
                          f"at {fs_cal:g} Hz: thresholds only apply at the rate they were "
                          "made for")
    made_for = str(getattr(thr, "calibration_fingerprint", "") or "")
    if not made_for:
        logging.getLogger("rimu").warning(
            f"{thresholds_file}: records no calibration fingerprint (an older thresholds "
            f"file): cannot check it was made for {where}")
        return
    fingerprint = getattr(cal, "fingerprint", None)
    mine = str(fingerprint()) if callable(fingerprint) else ""
    if made_for != mine:
        raise ConfigError(f"{thresholds_file}: thresholds made for the calibration with "
                          f"fingerprint {made_for}, {where} has {mine or 'none'}: thresholds "
                          "only apply to the calibration they were made for")


def select(cal: Calibration, *, kind: str = "gyro", thresholds_file: str | Path | None = None,
           false_alarms_per_hour: float | None = None,
           calibration_file: str | Path | None = None) -> ThresholdChoice:
    """The thresholds the options ask for, and where they came from.

    Parameters
    ----------
    cal : Calibration
    kind : str
        Sensor set the monitor watches.
    thresholds_file : path, optional
        A ``rimu.thresholds/2`` (or ``/1``) or ``rimu.tuning/1`` file; wins over the budget.
    false_alarms_per_hour : float, optional
        Budget for thresholds computed from the calibration (default
        :data:`DEFAULT_FALSE_ALARMS_PER_HOUR`).
    calibration_file : path, optional
        The calibration's file, named in the messages.

    Raises
    ------
    ConfigError
        A non-positive budget, or a file made for another sensor kind or count, another
        calibration or sample rate (:func:`check_made_for`).
    FileFormatError
        A bad thresholds file.
    """
    s = cal.kind(kind)
    if thresholds_file is not None:
        thr, source, ass = load_any_thresholds(thresholds_file)
        if thr.kind != kind or thr.n != s.n:
            raise ConfigError(f"{thresholds_file}: thresholds for {thr.n} {thr.kind} sensors, "
                              f"the calibration has {s.n} {kind} sensors")
        check_made_for(thr, cal, thresholds_file, calibration_file)
        return ThresholdChoice(thr, source, {**ass, "file": str(thresholds_file)})
    budget = (DEFAULT_FALSE_ALARMS_PER_HOUR if false_alarms_per_hour is None
              else float(false_alarms_per_hour))
    if not budget > 0:
        raise ConfigError(f"--false-alarms-per-hour must be positive, got {budget:g}")
    thr = default_thresholds(cal, false_alarms_per_hour=budget, kind=kind)
    return ThresholdChoice(thr, "calibration",
                           {"method": "thresholds.compute_thresholds (per-sample Bonferroni)",
                            "false_alarms_per_hour": budget})
