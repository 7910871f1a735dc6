"""``diagnose(session, cal)``: find the effects the model lacks, refit, error before and after.

Steps: check that the calibration belongs to the session (:func:`.context.check_match`);
residuals per kind (:mod:`.context`); forward selection and adequacy probes
(:mod:`.selection`); joint refit of the sensors with claimed effects (:mod:`.refit`);
before / after figures (:mod:`.metrics`). The result serialises to the ``--json`` layout
of ``rimu diagnose`` (:meth:`Diagnosis.to_json`).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from calibration.diagnose.context import KindData, check_match, check_same_session, kind_data
from calibration.diagnose.library import Candidate, candidates, get_candidate, model_effects
from calibration.diagnose.metrics import error_summary
from calibration.diagnose.refit import refit
from calibration.diagnose.selection import Selection, noise_sets, select
from calibration.session import Session
from fdi.calfile import Calibration
from fdi.errors import ConfigError

__all__ = ["BLAS_THREADS", "DIAGNOSIS_SCHEMA", "MONITOR_NOTE", "Diagnosis", "adequacy_record",
           "assess",
           "diagnose"]

DIAGNOSIS_SCHEMA = "rimu.diagnosis/1"
MONITOR_NOTE = ("the runtime monitor compensates the effect terms whose inputs it has at "
                "run time (rate sign, rate squared, specific force, temperature) and lists "
                "the others with the reason (docs/effects-runtime.md)")


@dataclass(frozen=True)
class Diagnosis:
    """What :func:`diagnose` found.

    Attributes
    ----------
    effects : list of dict
        Claimed effects: ``{"name", "kind", "sensors" (1-based), "estimate",
        "estimate_sd", "unit", "p_value", "log10_p_value", "threshold", "aliases",
        "params"}``.
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

    @property
    def adequate(self) -> bool:
        """True when nothing was claimed and nothing is unexplained."""
        return not self.effects and not self.unexplained

    def to_json(self) -> dict[str, Any]:
        """The ``rimu diagnose --json`` document."""
        return {"schema": DIAGNOSIS_SCHEMA, "alpha": self.alpha, "effects": self.effects,
                "unexplained": self.unexplained,
                "unexplained_detail": self.unexplained_detail,
                "not_testable": self.not_testable, "noise_null": self.noise_null,
                "error_before": self.error_before, "error_after": self.error_after}


def adequacy_record(sel: Selection, alpha: float) -> dict[str, Any]:
    """The ``adequacy`` entry of a calibration file from a selection."""
    where = [f"{s.kind} {s.sensor + 1}: {s.candidate.name}" for s in sel.claimed]
    where += [f"{u['kind']} {u['sensor']}: unexplained ({u['test']}"
              + (f", steps {', '.join(map(str, u['steps']))}" if u.get("steps") else "")
              + (f", {u['band_hz'][0]:.3g}-{u['band_hz'][1]:.3g} Hz" if u.get("band_hz")
                 else "") + ")" for u in sel.unexplained]
    return {"verdict": "effects suspected" if where else "adequate", "alpha": alpha,
            "where": where, "noise_null": dict(sel.noise_null),
            "method": "forward selection over the rimu.diagnose candidate library and "
                      "adequacy probes (per-step means, slow trend, change point, spectral "
                      "line, input correlation), nested-model F-tests (white noise) or "
                      "profile-likelihood ratio tests against white + Gauss-Markov noise "
                      "(where the noise-model selection keeps a Gauss-Markov term), "
                      "Holm/Bonferroni at alpha over candidates x sensors"}


def _candidates(names: Iterable[str] | None) -> list[Candidate]:
    if names is None:
        return candidates()
    return [get_candidate(n) for n in names]


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


def _effects_json(sel: Selection, new: Calibration) -> list[dict[str, Any]]:
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
                    "aliases": list(s.aliases), "params": params})
    return out


def diagnose(session: Session, cal: Calibration, *, alpha: float = 0.01,
             truth: tuple[Any, ...] | None = None,
             cal_path: str = "<calibration>",
             effects: Iterable[str] | None = None) -> Diagnosis:
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

    Raises
    ------
    ConfigError
        Calibration of another configuration or session, bad α, an asked-for effect the
        session lacks the inputs for.
    """
    if not 0 < alpha < 1:
        raise ConfigError(f"alpha must be between 0 and 1, got {alpha!r}")
    check_match(session, cal, cal_path)
    with threadpool_limits(limits=BLAS_THREADS, user_api="blas"):
        return _diagnose(session, cal, alpha, truth, effects, cal_path)


def _diagnose(session: Session, cal: Calibration, alpha: float,
              truth: tuple[Any, ...] | None,
              effects: Iterable[str] | None, cal_path: str) -> Diagnosis:
    datas = model_effects(kind_data(session, cal), cal.effects)
    check_same_session(datas, cal, session.source, cal_path)
    sel = _assess(session, cal, alpha=alpha, effects=effects, datas=datas)
    rec = adequacy_record(sel, alpha)
    if sel.claimed and not sel.unexplained:      # the refit model holds the effects found
        rec = {**rec, "verdict": "adequate", "effects_found": rec["where"], "where": [],
               "monitor": MONITOR_NOTE}
    fit = refit(datas, cal, sel.claimed, adequacy=rec, noise=noise_sets(sel))
    before = error_summary(datas, {k: d.y for k, d in datas.items()},
                           {k: np.full(d.n, 4) for k, d in datas.items()}, cal, truth)
    after = error_summary(datas, fit.residual, fit.n_params, fit.calibration, truth)
    return Diagnosis(effects=_effects_json(sel, fit.calibration),
                     unexplained=bool(sel.unexplained),
                     unexplained_detail=sel.unexplained, not_testable=sel.not_testable,
                     error_before=before, error_after=after, alpha=alpha,
                     calibration=fit.calibration, selection=sel,
                     noise_null=dict(sel.noise_null))
