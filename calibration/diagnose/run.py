"""``diagnose(session, cal)``: find the effects the model lacks, refit, error before and after.

Steps: check that the calibration belongs to the session (:func:`.context.check_match`);
residuals per kind (:mod:`.context`); forward selection and adequacy probes
(:mod:`.selection`); joint refit of the sensors with claimed effects (:mod:`.refit`);
before / after figures (:mod:`.metrics`). The result serialises to the ``--json`` layout
of ``rimu diagnose`` (:meth:`Diagnosis.to_json`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from calibration.diagnose.adequacy import adequacy_record, with_holdout, with_limits
from calibration.diagnose.bounds import SENSOR_CLASSES, bound_check, bound_label
from calibration.diagnose.bounds import sensor_class as class_of
from calibration.diagnose.context import KindData, check_match, check_same_session, kind_data
from calibration.diagnose.detect import POWER, limits
from calibration.diagnose.holdout import holdout
from calibration.diagnose.library import (
    OUTSIDE_ALIASES,
    candidates,
    get_candidate,
    model_effects,
)
from calibration.diagnose.metrics import error_summary
from calibration.diagnose.refit import refit
from calibration.diagnose.selection import Selection, noise_sets, select
from calibration.session import Session
from fdi.adequacy import ADEQUATE, SUSPECTED
from fdi.calfile import Calibration
from fdi.errors import ConfigError

__all__ = ["BLAS_THREADS", "DIAGNOSIS_SCHEMA", "Diagnosis", "assess", "bound_fields",
           "diagnose"]

DIAGNOSIS_SCHEMA = "rimu.diagnosis/1"


@dataclass(frozen=True)
class Diagnosis:
    """What :func:`diagnose` found.

    Attributes
    ----------
    effects : list of dict
        Claimed effects: ``{"name", "kind", "sensors" (1-based), "estimate",
        "estimate_sd", "unit", "p_value", "log10_p_value", "threshold", "aliases",
        "params", "could_absorb", "physical", "physical_bound", "bound_note"}``
        (``physical``: False when the estimate is beyond the plausible bound of the
        sensor class, :mod:`.bounds`, and ``bound_note`` then says it is absorbing
        something else; None for an effect without a bound; ``could_absorb``: effects
        outside the library this
        term could be absorbing, :data:`.library.OUTSIDE_ALIASES`; "" for a registered one
        without an entry).
    unexplained : bool
    unexplained_detail : list of dict
        Per failing probe: ``{"kind", "sensor", "sensor_name", "test", "p_value", "steps",
        "band_hz" / "time_s", "partial_fits"}``.
    not_testable : list of dict
        ``{"name", "kind", "reason"[, "sensors"]}``.
    error_before, error_after : dict
        :func:`calibration.diagnose.metrics.error_summary`.
    alpha : float
    calibration : Calibration
        The refit calibration (effects and adequacy filled).
    selection : Selection
        Internals (models per sensor), for reports.
    noise_null : dict
        Per kind, the noise the tests took as the null: ``"white"`` or ``"white +
        Gauss-Markov"`` (:mod:`.coloured`).
    not_ruled_out : list of dict
        Library effects this session's noise could hide at a size that moves a parameter
        of the refit calibration by 5 σ (:mod:`.detect`, ``limit == "session"``):
        ``{"name", "kind", "sensor", "sensor_name", "size", "unit", "parameter",
        "shift_sigma", "power", "power_white", "size_for_power",
        "shift_sigma_for_power", "params"}``.
    sequence_limits : list of dict
        The same for effects the sequence itself cannot separate at that size (hidden
        even under white noise of the session's level).
    holdout : dict
        The held-out check of the refit model (:func:`.holdout.holdout`; empty when it
        did not run: something was already unexplained). A failing fold makes the verdict
        "effects suspected".
    """

    effects: list[dict[str, Any]]
    unexplained: bool
    unexplained_detail: list[dict[str, Any]]
    not_testable: list[dict[str, Any]]
    error_before: dict[str, Any]
    error_after: dict[str, Any]
    alpha: float
    calibration: Calibration
    selection: Selection = field(repr=False, compare=False, default_factory=Selection)
    noise_null: dict[str, str] = field(default_factory=dict)
    not_ruled_out: list[dict[str, Any]] = field(default_factory=list)
    sequence_limits: list[dict[str, Any]] = field(default_factory=list)
    holdout: dict[str, Any] = field(default_factory=dict)

    @property
    def adequate(self) -> bool:
        """True when nothing was claimed and nothing is unexplained."""
        return not self.effects and not self.unexplained

    @property
    def verdict(self) -> str:
        """The refit calibration's adequacy verdict (:data:`fdi.adequacy.VERDICTS`)."""
        return str((self.calibration.adequacy or {}).get("verdict", ADEQUATE))

    def to_json(self) -> dict[str, Any]:
        """The ``rimu diagnose --json`` document."""
        return {"schema": DIAGNOSIS_SCHEMA, "alpha": self.alpha, "effects": self.effects,
                "unexplained": self.unexplained,
                "unexplained_detail": self.unexplained_detail,
                "not_testable": self.not_testable, "noise_null": self.noise_null,
                "verdict": self.verdict, "not_ruled_out": self.not_ruled_out,
                "sequence_limits": self.sequence_limits, "holdout": self.holdout,
                "error_before": self.error_before, "error_after": self.error_after}


BLAS_THREADS = 1
"""BLAS threads inside the diagnosis: its products are tall and thin (N × few), which
threads do not speed up and which a loaded machine slows down several-fold with them."""


def assess(session: Session, cal: Calibration, *, alpha: float = 0.01,
           effects: Iterable[str] | None = None,
           datas: Mapping[str, KindData] | None = None, noise: str = "auto") -> Selection:
    """Selection and probes only (no refit): what :func:`diagnose` and the adequacy
    check of ``rimu calibrate`` share. ``effects``: fit these without testing. ``noise``:
    the null's noise (:func:`.selection.select`; ``"auto"`` adds a Gauss-Markov term per
    kind where the calibration's noise-model selection finds one)."""
    with threadpool_limits(limits=BLAS_THREADS, user_api="blas"):
        return _assess(session, cal, alpha=alpha, effects=effects, datas=datas, noise=noise)


def _assess(session: Session, cal: Calibration, *, alpha: float,
            effects: Iterable[str] | None,
            datas: Mapping[str, KindData] | None, noise: str = "auto") -> Selection:
    datas = model_effects(kind_data(session, cal), cal.effects) if datas is None else datas
    forced = list(effects) if effects is not None else None
    if forced:
        for name in forced:
            c = get_candidate(name)
            why = {k: c.needs(d) for k, d in datas.items() if k in c.kinds}
            if not why:
                raise ConfigError(f"{session.source}: effect {name!r} applies to "
                                  f"{' and '.join(c.kinds)}; the session has none")
            if all(w is not None for w in why.values()):
                kind, reason = next(iter(why.items()))
                raise ConfigError(f"{session.source}: effect {name!r} cannot be fitted "
                                  f"to the {kind}s: {reason}")
    return select(datas, candidates() if not forced else [get_candidate(n) for n in forced],
                  alpha, forced=forced, noise=noise)


def _effects_json(sel: Selection, new: Calibration, cls: str) -> list[dict[str, Any]]:
    out = []
    terms = {(t.kind, t.sensor, t.name): t for t in new.effects}
    for s in sel.claimed:
        t = terms[(s.kind, s.sensor, s.candidate.name)]
        params = {k: v for k, v in t.params.items() if k != "p_value"}
        out.append({"name": t.name, "kind": t.kind, "sensors": [t.sensor + 1],
                    "estimate": t.estimate, "estimate_sd": t.estimate_sd, "unit": t.unit,
                    "p_value": s.p_value,
                    "log10_p_value": float(s.log_p / np.log(10)) if np.isfinite(s.log_p)
                    else None,
                    "threshold": None if not np.isfinite(s.threshold) else s.threshold,
                    "aliases": list(s.aliases), "params": params,
                    "could_absorb": OUTSIDE_ALIASES.get(t.name, ""),
                    **bound_fields(t.name, t.kind, t.estimate, t.unit, cls)})
    return out


def bound_fields(name: str, kind: str, estimate: float, unit: str, cls: str
                 ) -> dict[str, Any]:
    """``physical``, ``physical_bound`` and ``bound_note`` of an effect estimate
    (:mod:`.bounds`; ``physical`` None for an effect without a bound)."""
    chk = bound_check(name, kind, estimate, cls)
    if chk is None:
        return {"physical": None, "physical_bound": None, "bound_note": ""}
    return {"physical": chk["physical"], "physical_bound": chk,
            "bound_note": bound_label(chk, unit)}


def diagnose(session: Session, cal: Calibration, *, alpha: float = 0.01,
             truth: tuple[Any, ...] | None = None,
             cal_path: str = "<calibration>",
             effects: Iterable[str] | None = None,
             detectability: bool = True, sensor_class: str | None = None) -> Diagnosis:
    """Diagnose a session under a calibration (see the module docstring).

    Parameters
    ----------
    session : Session
    cal : Calibration
        A calibration of this session (``rimu calibrate``).
    alpha : float
        Family-wise level of the tests (0 < α < 1).
    truth : (Calibration, effects) or (Calibration, effects, effect_sensors), optional
        From :func:`calibration.truth.load_truth`: adds parameter errors in σ.
    cal_path : str
        For error messages.
    effects : names, optional
        Fit exactly these (no selection).
    detectability : bool
        Add the detectability limits and the three-way verdict (:mod:`.detect`; default).
    sensor_class : {"fog", "mems"}, optional
        Class whose physical bounds label the effects found (:mod:`.bounds`); default:
        from the calibration's gyro noise.

    Raises
    ------
    ConfigError
        Calibration of another configuration or session, bad α, an asked-for effect the
        session lacks the inputs for.
    """
    if not 0 < alpha < 1:
        raise ConfigError(f"alpha must be between 0 and 1, got {alpha!r}")
    if sensor_class is not None and sensor_class not in SENSOR_CLASSES:
        raise ConfigError(f"sensor class must be one of {', '.join(SENSOR_CLASSES)}, got "
                          f"{sensor_class!r}")
    check_match(session, cal, cal_path)
    cls = sensor_class or class_of(cal)
    with threadpool_limits(limits=BLAS_THREADS, user_api="blas"):
        return _diagnose(session, cal, alpha, truth, effects, cal_path, detectability, cls)


def _diagnose(session: Session, cal: Calibration, alpha: float,
              truth: tuple[Any, ...] | None,
              effects: Iterable[str] | None, cal_path: str,
              detectability: bool = True, cls: str = "mems") -> Diagnosis:
    datas = model_effects(kind_data(session, cal), cal.effects)
    check_same_session(datas, cal, session.source, cal_path)
    sel = _assess(session, cal, alpha=alpha, effects=effects, datas=datas)
    rec = adequacy_record(sel, alpha, effects_refit=True)
    if rec["verdict"] != SUSPECTED:              # before "adequate": data it did not see
        rec = with_holdout(rec, holdout(datas, sel.models, alpha))
    fit = refit(datas, cal, sel.claimed, adequacy=rec, noise=noise_sets(sel))
    if detectability and rec["verdict"] != SUSPECTED:   # what could hide
        lim = limits(datas, sel.models, fit.calibration, alpha, sel.family_size,
                     skip={(s.kind, s.sensor, s.candidate.name) for s in sel.claimed}
                     | {(t.kind, t.sensor, t.name) for t in fit.calibration.effects})
        rec = with_limits(rec, lim, POWER)
        fit = dataclasses.replace(fit, calibration=dataclasses.replace(
            fit.calibration, adequacy=rec))
    before = error_summary(datas, {k: d.y for k, d in datas.items()},
                           {k: np.full(d.n, 4) for k, d in datas.items()}, cal, truth)
    after = error_summary(datas, fit.residual, fit.n_params, fit.calibration, truth)
    return Diagnosis(effects=_effects_json(sel, fit.calibration, cls),
                     unexplained=bool(sel.unexplained),
                     unexplained_detail=sel.unexplained, not_testable=sel.not_testable,
                     error_before=before, error_after=after, alpha=alpha,
                     calibration=fit.calibration, selection=sel,
                     noise_null=dict(sel.noise_null),
                     not_ruled_out=list(rec.get("not_ruled_out") or []),
                     sequence_limits=list(rec.get("sequence_limits") or []),
                     holdout=dict(rec.get("holdout") or {}))
