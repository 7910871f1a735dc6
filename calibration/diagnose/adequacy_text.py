"""The text of an adequacy record: what ``rimu calibrate``, ``rimu diagnose`` and ``rimu
repeat`` print about the verdict, the held-out check and the detectability limits, and the
calibration warning of an "effects not ruled out" verdict (:mod:`.adequacy`)."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

from calibration.diagnose.adequacy import MONITOR_NOTE
from calibration.diagnose.bounds import sensor_class as class_of
from calibration.diagnose.run import bound_fields
from fdi.adequacy import NOT_RULED_OUT
from fdi.calfile import Calibration

__all__ = ["format_adequacy", "holdout_lines", "limit_lines", "not_ruled_out_warning"]

_MAX_LINES = 6
"""At most this many limits printed (the file holds them all)."""


def _limit_line(r: Mapping[str, Any]) -> str:
    p = r.get("params") or {}
    at = (f" at {p['time_s']:.0f} s" if "time_s" in p else
          f" at {p['frequency_hz']:.3g} Hz" if "frequency_hz" in p else "")
    return (f"{r['name']}{at} on {r['kind']} {r['sensor']}: {r['size']:.3g} {r['unit']} "
            f"moves its {str(r['parameter']).replace('_', ' ')} by "
            f"{r['shift_sigma']:.0f} sigma, found with probability {r['power']:.2f} "
            f"(0.99 from {r['size_for_power']:.3g} {r['unit']}, "
            f"{r['shift_sigma_for_power']:.1f} sigma)")


def _worst_per_effect(recs: Iterable[Mapping[str, Any]]) -> list[Mapping[str, Any]]:
    """The least detectable sensor of each effect, least detectable first."""
    best: dict[str, Mapping[str, Any]] = {}
    for r in recs:
        if r["name"] not in best or r["power"] < best[r["name"]]["power"]:
            best[r["name"]] = r
    return sorted(best.values(), key=lambda r: r["power"])


def not_ruled_out_warning(rec: Mapping[str, Any]) -> str:
    """The calibration warning of an "effects not ruled out" verdict."""
    names = ", ".join(r["name"] for r in _worst_per_effect(rec["not_ruled_out"]))
    applied = rec.get("noise_model_applied")
    return (f"model adequacy: {NOT_RULED_OUT} (" + names + "): nothing was found, but "
            "this session's noise could hide them at sizes that move a parameter by 5 "
            "sigma" + ("; the Gauss-Markov widening is applied (no effect is suspected)"
                       if applied == "auto" else "") + ". " + str(rec.get("advice", "")))


def limit_lines(a: Mapping[str, Any]) -> list[str]:
    """The detectability limits of an adequacy record (:func:`.adequacy.with_limits`), least
    detectable sensor of each effect, with the advice."""
    out = []
    nro = _worst_per_effect(a.get("not_ruled_out") or [])
    if nro:
        out.append("  not ruled out (this session's noise could hide them; least "
                   "detectable sensor of each):")
        out.extend("    " + _limit_line(r) for r in nro[:_MAX_LINES])
        if a.get("advice"):
            out.append(f"  what to do: {a['advice']}")
    seq = _worst_per_effect(a.get("sequence_limits") or [])
    if seq:
        out.append("  limits of the sequence (hidden even under white noise of this "
                   "level):")
        out.extend("    " + _limit_line(r) for r in seq[:_MAX_LINES])
        if not nro and a.get("advice"):
            out.append(f"  what to do: {a['advice']}")
    return out


def holdout_lines(a: Mapping[str, Any]) -> list[str]:
    """The held-out check of an adequacy record (:func:`.adequacy.with_holdout`): one line
    (the failing folds themselves are in ``where``), and one for folds not tested."""
    h = a.get("holdout")
    if not h:
        return []
    w = h.get("worst")
    worst = (f"; worst {w['kind']} {w['sensor']} fold {w['fold']} (steps "
             f"{w['steps'][0]}-{w['steps'][-1]}): chi2 {w['chi2']:.1f} on {w['dof']} dof, "
             f"p {w['p_value']:.2g}" if w else "")
    out = [f"  held-out check ({h.get('folds_tested', 0)} sensor-folds, each refitted "
           f"without its steps and predicted; limit p < {h['threshold']:.2g}): "
           + ("passed" if h["passed"] else "FAILED, the model does not predict steps it "
              "did not see") + worst]
    nt = [n for n in h.get("not_tested") or [] if "fold" in n]
    if nt:
        out.append(f"    {len(nt)} fold(s) not tested: the other folds do not determine "
                   "the model's columns there")
    return out


def format_adequacy(cal: Calibration, sensor_class: str | None = None) -> list[str]:
    """Lines ``rimu calibrate`` prints about the adequacy and the effect terms
    (``sensor_class``: ``"fog"`` or ``"mems"``, whose physical bounds label the effect
    terms, :mod:`.bounds`; default: read from the calibration's gyro noise)."""
    a = cal.adequacy
    out = []
    if a is not None:
        out.append(f"model adequacy (alpha {a.get('alpha')}): {a['verdict']}"
                   + (": " + "; ".join(a.get("where", [])) if a.get("where") else ""))
        coloured = [k for k, v in (a.get("noise_null") or {}).items() if v != "white"]
        if coloured:
            out.append(f"  tested against white + Gauss-Markov noise ({', '.join(coloured)}: "
                       "the residual reads as coloured)")
        if a.get("noise_model_requested") != a.get("noise_model_applied"):
            out.append(f"  noise model: {a.get('noise_model_applied')} (asked for "
                       f"{a.get('noise_model_requested')})")
        out.extend(holdout_lines(a))
        out.extend(limit_lines(a))
    cls = (sensor_class or class_of(cal)) if cal.effects else ""
    for t in cal.effects:
        out.append(f"effect {t.name} on {t.kind} {t.sensor + 1}: {t.estimate:+.4g} ± "
                   f"{t.estimate_sd:.2g} {t.unit}")
        note = bound_fields(t.name, t.kind, t.estimate, t.unit, cls)["bound_note"]
        if note:
            out.append(f"  {note}")
    if cal.effects:
        out.append(f"note: {MONITOR_NOTE}")
    return out
