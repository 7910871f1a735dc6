"""Forward selection of effects by nested-model tests, then the adequacy probes.

Each sensor's model is a :class:`.linmodel.LinModel` (white-noise F-tests) or, for a kind
whose residual the calibration's noise-model selection reads as coloured, a
:class:`.coloured.GlsModel` (profile-likelihood tests against white + Gauss-Markov noise,
``(ρ, τ)`` common to the set: accepting an effect on one sensor re-tests the whole set).

Family: every testable (candidate, sensor) pair of every kind. At each round every pair not
yet accepted is tested against its sensor's current model (:class:`.linmodel.LinModel`);
the smallest p-value is accepted when ``p < (α/2) / m`` with ``m`` the pairs still in the
family (Holm's step-down, which stops at the first non-rejection). The remaining ``α/2``
goes to the adequacy probes (:mod:`.probes`), Bonferroni over probes × sensors plus one
stationarity test per fitted periodic line (:mod:`.stationarity`): the chance that a
session whose model is complete gets any effect or "unexplained" is at most α.

A failing ``change_point`` probe is named ``bias_step`` on its sensor when the step at
the probe's time makes every probe of the kind pass (:func:`_promote_steps`): the probe
and the candidate make the same test, the probe in the smaller family. This relabels a
finding and never adds one, so the level above holds.

A sensor whose probes still fail after selection is *unexplained*: effects accepted on it
are not claimed (they are reported as partial fits), since picking the best of a bad lot
would name an effect the data do not show. Candidates whose regressor is collinear with
the calibration model on this sequence are "not testable" (rank 0); a candidate whose
projected regressor is almost collinear (canonical correlation > 0.95) with the accepted
one is listed as its alias (this sequence cannot tell them apart).
"""

from __future__ import annotations

import copy
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from calibration.diagnose.coloured import GlsModel, NoiseSet, block_noise, needs_coloured
from calibration.diagnose.context import KindData
from calibration.diagnose.library import Candidate, effect_searching, testable
from calibration.diagnose.linmodel import LinModel
from calibration.diagnose.probes import PROBES, run_probes, shared_regressors
from calibration.diagnose.stationarity import LINE_EFFECT, line_stationarity

__all__ = ["ALIAS_CORRELATION", "STEP_EFFECT", "Selected", "Selection", "base_columns",
           "noise_sets", "select"]

ALIAS_CORRELATION = 0.95
STEP_EFFECT = effect_searching("time_s")
"""The library effect a failing ``change_point`` probe is named (:func:`_promote_steps`)."""


@dataclass(frozen=True)
class Selected:
    """An accepted (candidate, sensor) pair.

    Attributes
    ----------
    candidate : Candidate
    kind : str
    sensor : int
        0-based.
    params : dict
        Searched or fixed parameters (time, frequency, reference temperature).
    p_value : float
        Of its nested-model test (scan multiplicity included).
    threshold : float
        The Holm threshold it passed.
    aliases : tuple of str
        Candidates this session cannot tell apart from it.
    log_p : float
        Natural log of ``p_value`` (finite where ``p_value`` underflows to 0).
    """

    candidate: Candidate
    kind: str
    sensor: int
    params: dict[str, Any]
    p_value: float
    threshold: float
    aliases: tuple[str, ...] = ()
    log_p: float = float("nan")


@dataclass
class Selection:
    """What :func:`select` found."""

    claimed: list[Selected] = field(default_factory=list)
    partial: list[Selected] = field(default_factory=list)
    unexplained: list[dict[str, Any]] = field(default_factory=list)
    not_testable: list[dict[str, Any]] = field(default_factory=list)
    models: dict[tuple[str, int], LinModel | GlsModel] = field(default_factory=dict)
    family_size: int = 0
    """The (candidate, sensor) pairs tested (the ``m`` of the first Holm threshold)."""
    noise_null: dict[str, str] = field(default_factory=dict)
    """Per kind, the noise of the null hypothesis: ``"white"`` or ``"white +
    Gauss-Markov"`` (profile-likelihood tests, :mod:`.coloured`)."""
    promoted: list[dict[str, Any]] = field(default_factory=list)
    """Change points the probes found that were named ``bias_step`` (claimed with the
    probe's p): ``{"kind", "sensor" (1-based), "name", "p_value", "time_s"}``."""


def noise_sets(sel: Selection) -> dict[str, NoiseSet]:
    """Per kind tested against white + Gauss-Markov noise, the set's fitted noise."""
    out = {}
    for (kind, _), m in sel.models.items():
        if isinstance(m, GlsModel):
            out[kind] = m.group
    return out


def base_columns(d: KindData, i: int) -> np.ndarray:
    """The calibration's own free columns for sensor ``i``: bias and gain vector
    (scale factor and the two misalignment angles), ``[1, x]``."""
    return np.column_stack([np.ones(d.N), d.x])


def _evaluate(d: KindData, i: int, c: Candidate, model: LinModel
              ) -> tuple[float, float, dict[str, Any], np.ndarray, int, float]:
    """(p, log p, params, Z, rank, sum of squares) of adding ``c`` to sensor ``i``'s model; the scan
    multiplicity (Bonferroni) is included in p."""
    if c.search is not None:
        params, mult = c.search(d, i, model.Q, model.e)
    else:
        params, mult = (c.fixed_params(d, i) if c.fixed_params else {}), 1
    ft = model.test(c.columns(d, i, params))
    if not ft.rank:
        return 1.0, 0.0, params, ft.Z, 0, 0.0
    logp = min(0.0, ft.log_p + float(np.log(mult)))
    return float(np.exp(logp)), logp, params, ft.Z, ft.rank, ft.ss


def select(datas: Mapping[str, KindData], cands: Iterable[Candidate], alpha: float, *,
           forced: Iterable[str] | None = None, noise: str = "auto") -> Selection:
    """Forward selection over every kind and sensor, then the adequacy probes.

    Parameters
    ----------
    datas : mapping of kind to KindData
    cands : candidates to try
    alpha : float
        Family-wise level (α/2 for the selection, α/2 for the probes).
    forced : names, optional
        Fit these on every sensor they apply to, without testing (``--effects``); the
        selection then runs on top of them only for the probes.
    noise : {"auto", "white", "coloured"}
        The noise of the null hypothesis: ``"auto"`` takes white + Gauss-Markov for a kind
        whose residual the calibration's noise-model selection reads as coloured
        (:func:`.coloured.needs_coloured`), white otherwise.
    """
    if noise not in ("auto", "white", "coloured"):
        raise ValueError(f"noise must be auto, white or coloured, got {noise!r}")
    cands = list(cands)
    out = Selection()
    forced = list(forced or [])
    family = _family(datas, cands, out, noise)
    if forced:
        for kind, i, c in family:
            if c.name in forced:
                d, model = datas[kind], out.models[(kind, i)]
                p, _, params, Z, rank, _ = _evaluate(d, i, c, model)
                if rank:
                    model.add(Z)
                out.claimed.append(Selected(c, kind, i, params, p, float("nan")))
        _probe(datas, out, alpha, demote=False)
        return out
    cache = _first_pass(datas, family, out)
    out.family_size = len(cache)
    _forward(datas, {c.name: c for c in cands}, cache, out, alpha)
    _probe(datas, out, alpha,
           step=next((c for c in cands if c.name == STEP_EFFECT), None))
    return out


_Cached = tuple[float, float, dict[str, Any], np.ndarray, float]
"""(p, log p, params, basis, sum of squares explained) of one (kind, sensor, effect)."""


def _family(datas: Mapping[str, KindData], cands: list[Candidate],
            out: Selection, noise: str = "auto") -> list[tuple[str, int, Candidate]]:
    """Base models per sensor, and every (kind, sensor, candidate) that can be tested;
    the others go to ``out.not_testable`` with the reason."""
    family: list[tuple[str, int, Candidate]] = []
    for kind, d in datas.items():
        coloured = noise == "coloured" or (noise == "auto"
                                           and needs_coloured(d.y, d.sample_rate_hz))
        out.noise_null[kind] = "white + Gauss-Markov" if coloured else "white"
        group = NoiseSet(block_noise(d.N, d.sample_rate_hz)) if coloured else None
        for i in range(d.n):
            out.models[(kind, i)] = (GlsModel(d.y[:, i], base_columns(d, i), group, i)
                                     if group is not None
                                     else LinModel(d.y[:, i], base_columns(d, i)))
        for c in cands:
            why = testable(c, d)
            if why is not None:
                if kind in c.kinds:
                    out.not_testable.append({"name": c.name, "kind": kind, "reason": why})
                continue
            family.extend((kind, i, c) for i in range(d.n))
    return family


def _first_pass(datas: Mapping[str, KindData], family: list[tuple[str, int, Candidate]],
                out: Selection) -> dict[tuple[str, int, str], _Cached]:
    """Evaluate every member once; rank-0 candidates are not identifiable on this sequence
    (listed as not testable, collinear with the calibration model)."""
    cache: dict[tuple[str, int, str], _Cached] = {}
    collinear: dict[tuple[str, str], list[int]] = {}
    for kind, i, c in family:
        p, logp, params, Z, rank, ss = _evaluate(datas[kind], i, c, out.models[(kind, i)])
        if rank == 0:
            collinear.setdefault((c.name, kind), []).append(i + 1)
            continue
        cache[(kind, i, c.name)] = (p, logp, params, Z, ss)
    for (name, kind), sens in collinear.items():
        out.not_testable.append({"name": name, "kind": kind, "sensors": sens,
                                 "reason": "collinear with the calibration model on this "
                                           "sequence (cannot be told apart from bias and "
                                           "scale factor)"})
    return cache


def _aliases(cache: dict[tuple[str, int, str], _Cached], key: tuple[str, int, str],
             accepted: set[tuple[str, int, str]], model: LinModel, Z: np.ndarray,
             thr: float) -> list[str]:
    """Other significant candidates of the same sensor strongly correlated with ``key``'s."""
    aliases = []
    basis = None
    for k2, (_, lp2, _, Z2, _) in cache.items():
        if k2 in accepted or k2 == key or k2[:2] != key[:2] or not lp2 < np.log(thr):
            continue
        basis = model.basis(Z) if basis is None else basis
        if np.linalg.norm(basis.T @ model.basis(Z2), 2) > ALIAS_CORRELATION:
            aliases.append(k2[2])
    return aliases


def _forward(datas: Mapping[str, KindData], by_name: dict[str, Candidate],
             cache: dict[tuple[str, int, str], _Cached], out: Selection,
             alpha: float) -> None:
    """Forward selection with Holm's step-down at α/2: take the most significant
    remaining member while its p beats (α/2)/m, refit that sensor, re-evaluate the rest.
    Members are ranked by log p, then by the sum of squares (log p underflows to -inf for
    strong effects)."""
    m_total = len(cache)
    accepted: set[tuple[str, int, str]] = set()
    while len(accepted) < m_total:
        m = m_total - len(accepted)
        key = min((k for k in cache if k not in accepted),
                  key=lambda k: (cache[k][1], -cache[k][4]))
        p, logp, params, Z, _ = cache[key]
        thr = (alpha / 2) / m
        if not logp < np.log(thr):
            break
        kind, i, name = key
        model = out.models[(kind, i)]
        aliases = _aliases(cache, key, accepted, model, Z, thr)
        accepted.add(key)
        out.claimed.append(Selected(by_name[name], kind, i, params, p, thr, tuple(aliases),
                                    logp))
        model.add(Z)
        shared = isinstance(model, GlsModel)     # (ρ, τ) common to the set: all re-tested
        for k2 in list(cache):
            if k2 not in accepted and (k2[:2] == (kind, i) or (shared and k2[0] == kind)):
                p2, lp2, par2, Z2, _, ss2 = _evaluate(datas[kind], k2[1], by_name[k2[2]],
                                                      out.models[k2[:2]])
                cache[k2] = (p2, lp2, par2, Z2, ss2)


def _line_terms(out: Selection, kind: str, i: int) -> list[Selected]:
    """The fitted periodic lines of sensor ``i`` (claimed or forced)."""
    return [s for s in out.claimed if (s.kind, s.sensor) == (kind, i)
            and s.candidate.name == LINE_EFFECT and "frequency_hz" in s.params]


def _sensor_probes(d: KindData, kind: str, i: int, model: LinModel | GlsModel,
                   out: Selection, thr: float,
                   shared: dict[str, tuple[np.ndarray, np.ndarray]]) -> list[dict[str, Any]]:
    """Failing probes of one sensor: the adequacy probes (:mod:`.probes`) and, per line
    its model holds, the line's stationarity (:mod:`.stationarity`)."""
    recs = run_probes(d, i, model, thr, shared)
    mine = [s for s in out.claimed if (s.kind, s.sensor) == (kind, i)]
    for ln in _line_terms(out, kind, i):
        others = [s.candidate.columns(d, i, s.params) for s in mine if s is not ln]
        rec = line_stationarity(d, i, model, ln.candidate, ln.params, others)
        if rec is not None and rec["p_value"] < thr:
            recs.append(rec)
    return recs


def _probe(datas: Mapping[str, KindData], out: Selection, alpha: float, *,
           demote: bool = True, step: Candidate | None = None) -> None:
    """Adequacy probes on every sensor (with the stationarity of every fitted line, in the
    same Bonferroni family); name a change point ``bias_step`` where that explains the
    sensor (:func:`_promote_steps`, when ``step`` is given); demote effects of sensors
    that still fail."""
    n_sensors = sum(d.n for d in datas.values())
    n_lines = sum(len(_line_terms(out, k, i)) for k, d in datas.items() for i in range(d.n))
    thr = (alpha / 2) / (len(PROBES) * max(n_sensors, 1) + n_lines)
    found: dict[tuple[str, int], list[dict[str, Any]]] = {}
    for kind, d in datas.items():
        shared = shared_regressors(d)
        for i in range(d.n):
            recs = _sensor_probes(d, kind, i, out.models[(kind, i)], out, thr, shared)
            if recs:
                found[(kind, i)] = recs
    if step is not None:
        _promote_steps(datas, out, found, thr, step)
    for (kind, i), recs in found.items():
        out.unexplained.extend({"kind": kind, "sensor": i + 1,
                                "sensor_name": datas[kind].names[i], **rec} for rec in recs)
    if not demote:
        return
    keep = []
    for s in out.claimed:
        (out.partial if (s.kind, s.sensor) in found else keep).append(s)
    out.claimed = keep
    for rec in out.unexplained:
        rec["partial_fits"] = [s.candidate.name for s in out.partial
                               if (s.kind, s.sensor + 1) == (rec["kind"], rec["sensor"])]


def _promote_steps(datas: Mapping[str, KindData], out: Selection,
                   found: dict[tuple[str, int], list[dict[str, Any]]], thr: float,
                   step: Candidate) -> None:
    """Name a failing ``change_point`` probe ``bias_step`` on its sensor when the step
    explains the sensor.

    The ``change_point`` probe and the ``bias_step`` candidate make the same test (a bias
    step at the best scanned time, Bonferroni over the scan); the probe's family is the
    smaller one, so a step can pass the probe's threshold and miss the selection's Holm
    threshold (as under a coloured-noise null, whose wider σ a chance colour of another
    sensor can bring). Sensors whose failing probes include ``change_point`` are tried
    in order of that probe's p: the step at the probe's time is added to a copy of the
    kind's models (the set's noise is shared, so every sensor of the kind is re-probed),
    and the step is claimed, with the probe's p and threshold, only when the sensor then
    passes every probe and no sensor of the kind that passed fails. Under a complete model
    this changes no session's "anything found" (it only relabels a probe that already
    failed), so the family-wise level stays at most α.
    """
    while True:
        for p, key, rec in _step_probes(datas, out, found, step):
            if _claim_step(datas, out, found, thr, step, p, key, rec):
                break
        else:
            return


def _step_probes(datas: Mapping[str, KindData], out: Selection,
                 found: dict[tuple[str, int], list[dict[str, Any]]], step: Candidate
                 ) -> list[tuple[float, tuple[str, int], dict[str, Any]]]:
    """Failing ``change_point`` probes a step could explain, in order of their p.

    Parameters
    ----------
    datas : mapping of str to KindData
    out : Selection
    found : dict
        Failing probes per (kind, sensor).
    step : Candidate
        ``bias_step``.

    Returns
    -------
    list of (p, (kind, sensor), probe record)
        Probes on a kind the step applies to and can be tested on, whose sensor has not
        claimed the step yet.
    """
    def open_(key: tuple[str, int]) -> bool:
        return (key[0] in step.kinds and testable(step, datas[key[0]]) is None
                and not any((s.kind, s.sensor, s.candidate.name) == (*key, step.name)
                            for s in out.claimed))

    return sorted(((r["p_value"], key, r) for key, recs in found.items()
                   for r in recs if r["test"] == "change_point" and open_(key)),
                  key=lambda x: x[0])


def _claim_step(datas: Mapping[str, KindData], out: Selection,
                found: dict[tuple[str, int], list[dict[str, Any]]], thr: float,
                step: Candidate, p: float, key: tuple[str, int], rec: dict[str, Any]) -> bool:
    """Try the step at one probe's time; claim it when it explains the sensor
    (:func:`_promote_steps`).

    Parameters
    ----------
    datas, out, found, thr, step
        As :func:`_promote_steps`; ``out`` and ``found`` are updated on a claim.
    p : float
        The probe's p.
    key : (str, int)
        (kind, sensor) of the probe.
    rec : dict
        The probe's record (``time_s``).

    Returns
    -------
    bool
        Claimed.
    """
    kind, i = key
    d = datas[kind]
    keys = [(kind, j) for j in range(d.n)]
    shared_noise = {id(m.noise): m.noise for k in keys
                    if isinstance(m := out.models[k], GlsModel)}
    trial = copy.deepcopy({k: out.models[k] for k in keys}, shared_noise)
    params = {"time_s": float(rec["time_s"])}
    if not trial[(kind, i)].add(step.columns(d, i, params)):
        return False
    shared = shared_regressors(d)
    new = {k: r for k in keys
           if (r := _sensor_probes(d, kind, k[1], trial[k], out, thr, shared))}
    if (kind, i) in new or any(k not in found for k in new):
        return False
    out.models.update(trial)
    for k in keys:
        found.pop(k, None)
    found.update(new)
    out.claimed.append(Selected(step, kind, i, params, float(p), thr, (),
                                float(np.log(max(p, 1e-300)))))
    out.promoted.append({"kind": kind, "sensor": i + 1, "name": step.name,
                         "p_value": float(p), "time_s": params["time_s"]})
    return True
