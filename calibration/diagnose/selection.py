"""Forward selection of effects by nested-model tests, then the adequacy probes.

Each sensor's model is a :class:`.linmodel.LinModel` (white-noise F-tests) or, for a kind
whose residual the calibration's noise-model selection reads as coloured, a
:class:`.coloured.GlsModel` (profile-likelihood tests against white + Gauss-Markov noise,
``(ρ, τ)`` common to the set: accepting an effect on one sensor re-tests the whole set).

Family: every testable (candidate, sensor) pair of every kind. At each round every pair not
yet accepted is tested against its sensor's current model (:class:`.linmodel.LinModel`);
the smallest p-value is accepted when ``p < (α/2) / m`` with ``m`` the pairs still in the
family (Holm's step-down, which stops at the first non-rejection). The remaining ``α/2``
goes to the adequacy probes (:mod:`.probes`), Bonferroni over probes × sensors: the chance
that a session whose model is complete gets any effect or "unexplained" is at most α.

A sensor whose probes still fail after selection is *unexplained*: effects accepted on it
are not claimed (they are reported as partial fits), since picking the best of a bad lot
would name an effect the data do not show. Candidates whose regressor is collinear with
the calibration model on this sequence are "not testable" (rank 0); a candidate whose
projected regressor is almost collinear (canonical correlation > 0.95) with the accepted
one is listed as its alias (this sequence cannot tell them apart).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from calibration.diagnose.coloured import GlsModel, NoiseSet, block_noise, needs_coloured
from calibration.diagnose.context import KindData
from calibration.diagnose.library import Candidate, testable
from calibration.diagnose.linmodel import LinModel
from calibration.diagnose.probes import PROBES, run_probes, shared_regressors

__all__ = ["ALIAS_CORRELATION", "Selected", "Selection", "base_columns", "noise_sets", "select"]

ALIAS_CORRELATION = 0.95


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
    _probe(datas, out, alpha)
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


def _probe(datas: Mapping[str, KindData], out: Selection, alpha: float, *,
           demote: bool = True) -> None:
    """Adequacy probes on every sensor; demote effects of sensors that still fail."""
    n_sensors = sum(d.n for d in datas.values())
    thr = (alpha / 2) / (len(PROBES) * max(n_sensors, 1))
    bad: set[tuple[str, int]] = set()
    for kind, d in datas.items():
        shared = shared_regressors(d)
        for i in range(d.n):
            for rec in run_probes(d, i, out.models[(kind, i)], thr, shared):
                bad.add((kind, i))
                out.unexplained.append({"kind": kind, "sensor": i + 1,
                                        "sensor_name": d.names[i], **rec})
    if not demote:
        return
    keep = []
    for s in out.claimed:
        (out.partial if (s.kind, s.sensor) in bad else keep).append(s)
    out.claimed = keep
    for rec in out.unexplained:
        rec["partial_fits"] = [s.candidate.name for s in out.partial
                               if (s.kind, s.sensor + 1) == (rec["kind"], rec["sensor"])]
