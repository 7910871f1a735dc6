"""The adequacy record of a calibration and the one function that decides its verdict.

The verdicts and their order are :data:`fdi.adequacy.VERDICTS` (the file format's strings).
Both ``rimu calibrate`` (:func:`calibration.checked_calibration.calibrate_checked`) and
``rimu diagnose`` (:func:`calibration.diagnose.run.diagnose`) build the record in the same
stages, each of which adds its evidence and lets :func:`decide` set the verdict:

1. :func:`adequacy_record`: the selection's claimed effects and unexplained structure
   (``where``; effects a refit model holds go to ``effects_found`` instead);
2. :func:`with_holdout`: the held-out check (:mod:`.holdout`), a failing fold added to
   ``where``; run only while nothing is suspected;
3. :func:`with_limits`: the detectability limits (:mod:`.detect`), ``not_ruled_out`` and
   ``sequence_limits``; run only while nothing is suspected.

:func:`decide` reads the evidence, not the stage: the worst verdict whose evidence is in
the record wins.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

from calibration.diagnose.selection import Selection
from fdi.adequacy import ADEQUATE, NOT_RULED_OUT, SUSPECTED, VERDICTS, WITHIN_SEQUENCE_LIMITS

__all__ = ["ADVICE", "MONITOR_NOTE", "SEQUENCE_ADVICE", "VERDICTS", "adequacy_record",
           "decide", "holdout_where", "public_limit", "with_holdout", "with_limits"]

MONITOR_NOTE = ("the runtime monitor compensates the effect terms whose inputs it has at "
                "run time (rate sign, rate squared, specific force, temperature) and lists "
                "the others with the reason (docs/effects-runtime.md)")
ADVICE = ("repeat the session and compare (a warm-up repeats at every switch-on, at the same "
          "time after it; a Gauss-Markov wander does not), or record a longer session so "
          "that the wander and a slow effect separate; the sizes listed could hide in this "
          "one")
SEQUENCE_ADVICE = ("no repetition of this sequence can see the effects listed (its noise and "
                   "the sigma shrink together, so the power at 5 sigma stays); another "
                   "sequence may: the limits depend on the sequence alone, so simulate a "
                   "candidate (rimu simulate calibration) and calibrate it to read its "
                   "limits before using it on the table")
_ADVICE = {NOT_RULED_OUT: ADVICE, WITHIN_SEQUENCE_LIMITS: SEQUENCE_ADVICE}
"""What to do, per verdict that has advice (written as ``advice``)."""
_METHOD = ("forward selection over the rimu.diagnose candidate library and adequacy probes "
           "(per-step means, slow trend, change point, spectral line, input correlation), "
           "nested-model F-tests (white noise) or profile-likelihood ratio tests against "
           "white + Gauss-Markov noise (where the noise-model selection keeps a Gauss-Markov "
           "term), Holm/Bonferroni at alpha over candidates x sensors")


def decide(rec: Mapping[str, Any]) -> str:
    """The verdict of an adequacy record, from the evidence it holds, worst first.

    - ``where`` not empty (an effect the model lacks, unexplained structure, a failing
      held-out fold) or a held-out check that did not pass: "effects suspected";
    - ``not_ruled_out`` not empty (this session's noise could hide a library effect that
      moves a parameter by 5 σ): "effects not ruled out";
    - ``sequence_limits`` not empty (only what the sequence cannot separate could hide):
      "adequate within sequence limits";
    - otherwise "adequate".

    Evidence a stage did not gather (no held-out check, no limits) counts as none.
    """
    if rec.get("where") or not (rec.get("holdout") or {}).get("passed", True):
        return SUSPECTED
    if rec.get("not_ruled_out"):
        return NOT_RULED_OUT
    if rec.get("sequence_limits"):
        return WITHIN_SEQUENCE_LIMITS
    return ADEQUATE


def _decided(rec: dict[str, Any]) -> dict[str, Any]:
    """``rec`` with ``verdict`` (:func:`decide`) and, for a verdict that has one, the
    ``advice``."""
    rec["verdict"] = decide(rec)
    if rec["verdict"] in _ADVICE:
        rec["advice"] = _ADVICE[rec["verdict"]]
    return rec


def adequacy_record(sel: Selection, alpha: float, *,
                    effects_refit: bool = False) -> dict[str, Any]:
    """The ``adequacy`` entry of a calibration file from a selection.

    Parameters
    ----------
    sel : Selection
    alpha : float
        The family-wise level of the tests.
    effects_refit : bool
        The record is for the model refit with the claimed effects (``rimu diagnose``):
        when nothing is unexplained, those effects are listed as ``effects_found`` (with
        the ``monitor`` note) instead of under ``where``.

    Returns
    -------
    dict
        ``{"verdict", "alpha", "where", "noise_null", "method"[, "effects_found",
        "monitor"]}``; the verdict "adequate" or "effects suspected" (:func:`with_holdout`
        and :func:`with_limits` add the rest of the evidence).
    """
    found = [f"{s.kind} {s.sensor + 1}: {s.candidate.name}" for s in sel.claimed]
    unexplained = [f"{u['kind']} {u['sensor']}: unexplained ({u['test']}"
                   + (f", steps {', '.join(map(str, u['steps']))}" if u.get("steps") else "")
                   + (f", {u['band_hz'][0]:.3g}-{u['band_hz'][1]:.3g} Hz"
                      if u.get("band_hz") else "") + ")" for u in sel.unexplained]
    held = effects_refit and bool(found) and not unexplained
    rec: dict[str, Any] = {"verdict": None, "alpha": alpha,
                           "where": unexplained if held else found + unexplained,
                           "noise_null": dict(sel.noise_null), "method": _METHOD}
    if held:                                     # the refit model holds the effects found
        rec.update(effects_found=found, monitor=MONITOR_NOTE)
    return _decided(rec)


def holdout_where(f: Mapping[str, Any]) -> str:
    """The ``where`` entry of a failing held-out fold."""
    steps = f["steps"]
    span = f"steps {steps[0]}-{steps[-1]}" if len(steps) > 1 else f"step {steps[0]}"
    return (f"{f['kind']} {f['sensor']}: held-out check (fold {f['fold']}, {span}: "
            f"chi2 {f['chi2']:.1f} on {f['dof']} dof, p {f['p_value']:.2g})")


def with_holdout(rec: Mapping[str, Any], ho: Mapping[str, Any]) -> dict[str, Any]:
    """``rec`` (:func:`adequacy_record`) with the held-out check (:mod:`.holdout`): its
    summary under ``holdout``, a failing fold listed under ``where`` (a model that does not
    predict steps it did not see is not adequate, whatever the tests on the steps it saw
    said: :func:`decide` makes it "effects suspected")."""
    out = dict(rec)
    out["holdout"] = {k: ho[k] for k in ("schema", "passed", "alpha", "threshold", "failed",
                                         "not_tested", "worst")}
    out["holdout"]["folds_tested"] = len(ho["folds"])
    if not ho["passed"]:
        out["where"] = list(out.get("where", [])) + [holdout_where(f) for f in ho["failed"]]
    return _decided(out)


def public_limit(rec: Mapping[str, Any]) -> dict[str, Any]:
    """A limit of :func:`.detect.limits` for files and JSON (plain numbers)."""
    keys = ("name", "kind", "sensor", "sensor_name", "size", "unit", "parameter",
            "shift_sigma", "power", "power_white", "size_for_power", "shift_sigma_for_power",
            "params")
    return {k: rec[k] for k in keys if k in rec}


def with_limits(rec: Mapping[str, Any], lim: Iterable[Mapping[str, Any]],
                power: float) -> dict[str, Any]:
    """``rec`` (:func:`adequacy_record`) with the detectability limits of :mod:`.detect`:
    effects this session's noise could hide at a size that moves a parameter by 5 σ
    (``not_ruled_out``), and those the sequence itself cannot separate (hidden even under
    white noise of the session's level: ``sequence_limits``); :func:`decide` turns
    them into "effects not ruled out" or "adequate within sequence limits", with the
    ``advice``."""
    lim = list(lim)
    out = dict(rec)
    out["not_ruled_out"] = [public_limit(r) for r in lim if r["limit"] == "session"]
    out["sequence_limits"] = [public_limit(r) for r in lim if r["limit"] == "sequence"]
    out["detection_power"] = power
    return _decided(out)
