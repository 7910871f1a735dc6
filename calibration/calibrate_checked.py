"""``calibrate_checked``, the entry point of ``rimu calibrate``: calibrate, check the model's
adequacy, only then model coloured noise.

The coloured-noise model (``noise_model="auto"``, a Gauss-Markov bias fitted to the residual
spectrum) widens the uncertainties for correlated *noise*. An unmodelled effect leaves
structure in the residual that the same fit would read as noise and hide behind wider σ.
So: calibrate with white noise, run the adequacy check of :mod:`calibration.diagnose`
(candidate effects and generic probes, at level α) on the residual, and

- nothing suspected → the held-out check (:mod:`calibration.diagnose.holdout`: each
  sensor's model refitted without each quarter of the steps must predict it); a failing
  quarter makes the verdict "effects suspected" (below). Passed →
  calibrate with the requested noise model (the estimates do not
  depend on it), then ask whether the session could have seen every library effect that
  moves a parameter of *that* calibration by 5 σ (:mod:`calibration.diagnose.detect`):
  yes → "adequate"; yes except for what the sequence itself cannot separate from the
  parameters (hidden even under white noise of the session's level) → "adequate within
  sequence limits", those listed (``sequence_limits``); no → "effects not ruled out", the
  limits listed (``not_ruled_out``), the widening still applied, a warning with what to
  do;
- effects suspected → keep the white-noise uncertainties, withhold the Gauss-Markov
  widening, and say where the structure is (``adequacy`` in the calibration, a warning).

The check's null is white noise, or white + Gauss-Markov noise with its parameters profiled
out (:mod:`calibration.diagnose.coloured`) for a set whose residual the noise-model
selection reads as coloured: a genuine bias instability is then noise, not an effect, and
the widening applies; structure that a Gauss-Markov wander of the fitted size cannot
explain as well still makes the session "effects suspected".

With ``effects`` given (``rimu calibrate turntable --effects``) those effects are fitted
jointly with the calibration (:mod:`calibration.diagnose.refit`) and the adequacy is checked on the
extended model.

The verdict is decided by :func:`calibration.diagnose.adequacy.decide`, the function
``rimu diagnose`` uses too; this module only decides what follows from it (which noise
model is applied, which warning is written).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Mapping
from typing import Any

import scipy.stats
from threadpoolctl import threadpool_limits

from calibration.calibrate import calibrate
from calibration.diagnose.adequacy import (
    MONITOR_NOTE,
    adequacy_record,
    with_holdout,
    with_limits,
)
from calibration.diagnose.adequacy_text import not_ruled_out_warning
from calibration.diagnose.context import KindData, kind_data
from calibration.diagnose.detect import POWER, limits
from calibration.diagnose.holdout import holdout
from calibration.diagnose.library import model_effects
from calibration.diagnose.metrics import step_chi2_dof
from calibration.diagnose.refit import Refit, refit
from calibration.diagnose.run import BLAS_THREADS, assess
from calibration.diagnose.selection import noise_sets
from calibration.fit_residuals import WARN_ALPHA
from calibration.session import Session
from fdi.adequacy import ADEQUATE, NOT_RULED_OUT, SUSPECTED
from fdi.calfile import Calibration
from fdi.errors import ConfigError
from fdi.extras import replace_extras

__all__ = ["calibrate_checked"]


def calibrate_checked(session: Session, *, alpha: float = 0.01, noise_model: str = "auto",
                      effects: Iterable[str] | None = None, detectability: bool = True,
                      **kw: Any) -> Calibration:
    """:func:`calibration.calibrate.calibrate` with the adequacy check (module docstring).

    Parameters
    ----------
    session : Session
    alpha : float
        Family-wise level of the adequacy check.
    noise_model : {"auto", "white"}
        Wanted noise model; ``"auto"`` is applied only when the model is adequate.
    effects : names, optional
        Effects to fit jointly (no selection among them).
    detectability : bool
        Ask whether the session could have seen every library effect that moves a
        parameter by 5 σ (:mod:`calibration.diagnose.detect`; default). False: the
        verdict is "adequate" or "effects suspected" from the tests alone (Monte Carlo
        runs that only count flags).
    **kw
        Passed to :func:`calibration.calibrate.calibrate` (``bias_method``, ``denoise``, ...).

    Returns
    -------
    Calibration
        ``adequacy`` filled; ``effects`` filled when asked for.
    """
    if not 0 < alpha < 1:
        raise ConfigError(f"alpha must be between 0 and 1, got {alpha!r}")
    effects = [e for e in (effects or []) if e]
    white = calibrate(session, noise_model="white", **kw)
    datas = white_datas = kind_data(session, white)
    if effects:
        forced = assess(session, white, alpha=alpha, effects=effects, datas=datas)
        fit = refit(datas, white, forced.claimed, noise=noise_sets(forced))
        fitted = dataclasses.replace(fit.calibration, extra=replace_extras(
            fit.calibration.extra, warnings=_refit_warnings(fit, datas)))
        datas = model_effects(kind_data(session, fitted), fitted.effects)
        sel = assess(session, fitted, alpha=alpha, datas=datas)
        base = fitted
    else:
        sel = assess(session, white, alpha=alpha, datas=datas)
        base = white
    rec = adequacy_record(sel, alpha)
    if rec["verdict"] == ADEQUATE:               # before "adequate": data it did not see
        with threadpool_limits(limits=BLAS_THREADS, user_api="blas"):
            rec = with_holdout(rec, holdout(white_datas if effects else datas,
                                            forced.models if effects else sel.models,
                                            alpha))
    rec["noise_model_requested"] = noise_model
    warnings = list(base.extras.warnings)
    if effects:
        rec["effects_fitted"] = effects
        rec["refit_noise"] = dict(forced.noise_null)      # sandwich where Gauss-Markov
        rec["monitor"] = MONITOR_NOTE
    if rec["verdict"] == ADEQUATE:
        if noise_model != "white" and not effects:
            base = calibrate(session, noise_model=noise_model, **kw)
            warnings = list(base.extras.warnings)
        rec["noise_model_applied"] = noise_model if not effects else "white"
        if detectability:
            with threadpool_limits(limits=BLAS_THREADS, user_api="blas"):
                lim = limits(datas, sel.models, base, alpha, sel.family_size,
                             skip={(s.kind, s.sensor, s.candidate.name) for s in sel.claimed}
                             | {(t.kind, t.sensor, t.name) for t in base.effects})
            rec = with_limits(rec, lim, POWER)
        if rec["verdict"] == NOT_RULED_OUT:
            warnings.append(not_ruled_out_warning(rec))
    else:
        rec["noise_model_applied"] = "white"
        warnings.append(f"model adequacy: {SUSPECTED} (" + "; ".join(rec["where"])
                        + "); " + ("the Gauss-Markov noise widening is withheld (it would "
                                   "hide them): run rimu diagnose"
                                   if noise_model != "white" else "run rimu diagnose"))
    return dataclasses.replace(base, adequacy=rec,
                               extra=replace_extras(base.extra, warnings=warnings))


def _refit_warnings(fit: Refit, datas: Mapping[str, KindData]) -> list[str]:
    """The warnings of a calibration refit with effects.

    The white-noise fit's whiteness warnings (:func:`calibration.fit_residuals.
    whiteness_warnings`) describe the model without the effects; for the sensors the refit
    changed they are stale and are replaced by the step-mean check on the refit residual
    (:func:`calibration.diagnose.metrics.step_chi2_dof`, at the same 0.1 % level).
    """
    cal = fit.calibration
    touched = {(t.kind, t.sensor) for t in cal.effects}
    stale = {f"{kind} {s.name}: " for kind, i in touched
             for s in (cal.sets[kind].sensors[i],)}
    out = [w for w in cal.extras.warnings
           if not (any(w.startswith(p) for p in stale) and "white noise explains" in w)]
    for kind, d in datas.items():
        if kind not in fit.residual:
            continue
        chi = step_chi2_dof(d, fit.residual[kind], fit.n_params[kind])
        for i in sorted(i for k, i in touched if k == kind):
            dof = max(len(d.steps) - int(fit.n_params[kind][i]), 1)
            lim = float(scipy.stats.chi2.isf(WARN_ALPHA, dof)) / dof
            if chi[i] > lim:
                out.append(f"{kind} {cal.sets[kind].sensors[i].name}: with the effect terms "
                           "fitted, the step means of the residuals still scatter more than "
                           f"white noise explains (chi2/dof {chi[i]:.2f}, 0.1 % limit "
                           f"{lim:.2f}): run rimu diagnose")
    return out
