"""Repeated calibration sessions: run-to-run repeatability and stacking.

One 576 s session under a Gauss-Markov bias wander often cannot rule out a slow effect
(verdict "effects not ruled out", :mod:`calibration.diagnose.detect`), and when the wander
is slower than a quarter of the record the single-session σ are too small
(:mod:`calibration.uncertainty`, ``sigma_cut``). Repeating the session answers both:

1. **Repeatability** (:func:`repeatability`). For every parameter (bias, scale factor, two
   misalignment angles of every sensor) over N sessions ``x_j ± s_j``: the weighted mean
   ``x̄ = Σw_j x_j / Σw_j`` (``w_j = 1/s_j²``), Cochran's ``Q = Σ w_j (x_j − x̄)²``, χ² with
   N − 1 degrees of freedom when the reported σ are right, its p-value, and a Holm
   correction over all parameters tested: "repeatable" or "scatters beyond its σ" (the
   single-session σ are too small for run to run: a wander slower than the record, or
   turn-on bias repeatability, the datasheet's "bias repeatability"). The run-to-run σ
   beyond the reported σ is the random-effects τ of ``x_j = μ + δ_j + ε_j``,
   ``δ_j ~ N(0, τ²)``, ``ε_j ~ N(0, s_j²)``: DerSimonian-Laird's moment estimate
   ``τ² = max(0, (Q − (N−1)) / (Σw − Σw²/Σw))`` with the Q-profile confidence interval
   (Viechtbauer 2007: the τ² where the generalised ``Q(τ²) = Σ(x_j − x̄_τ)²/(s_j² + τ²)``
   equals the χ²_{N−1} quantiles).
2. **Stacking** (:mod:`calibration.stack`): sessions of one sequence averaged sample by
   sample; a repeating effect keeps its size while the noise drops by √N. The stack is
   calibrated and checked as one session (why that test is valid: :mod:`calibration.stack`).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.optimize
import scipy.stats

from calibration.session import Session
from calibration.stack import configuration_mismatch, stack_mismatch, stack_sessions
from fdi.calfile import Calibration
from fdi.errors import ConfigError
from fdi.units import input_unit_factor

__all__ = ["CI_LEVEL", "REPEAT_SCHEMA", "ParameterRepeat", "RepeatResult", "Repeatability",
           "StackResult", "repeat_sessions", "repeatability", "run_to_run_sd"]

REPEAT_SCHEMA = "rimu.repeat/1"
"""Schema name of the ``rimu repeat --json`` document."""
CI_LEVEL = 0.95
"""Confidence level of the run-to-run σ interval."""

_PARAMS = ("bias", "scale_factor", "misalignment_1", "misalignment_2")


@dataclass(frozen=True)
class ParameterRepeat:
    """One parameter over N sessions (values in ``unit``).

    Attributes
    ----------
    kind : str
        ``"gyro"`` or ``"accel"``.
    sensor : int
        0-based sensor index (1-based in JSON and text).
    sensor_name : str
    parameter : str
        ``bias``, ``scale_factor`` (in ppm of the mean), ``misalignment_1`` or
        ``misalignment_2`` (mrad; the calibration file's two angles).
    unit : str
    values, sds : ndarray, shape (N,)
        Per-session estimates and their reported σ.
    mean, mean_sd : float
        Weighted mean with the random-effects weights ``1/(s_j² + τ²)`` and its σ.
    chi2 : float
        Cochran's Q about the fixed-effect weighted mean; χ²(N − 1) when the σ are right.
    dof : int
    p_value : float
    threshold : float
        Holm level this p-value was compared with.
    run_sd : float
        Run-to-run σ beyond the reported σ (τ, moment estimate; 0 when not needed).
    run_sd_ci : tuple of float
        Its :data:`CI_LEVEL` Q-profile interval.
    verdict : str
        ``"repeatable"`` or ``"scatters beyond its σ"``.
    """

    kind: str
    sensor: int
    sensor_name: str
    parameter: str
    unit: str
    values: np.ndarray
    sds: np.ndarray
    mean: float
    mean_sd: float
    chi2: float
    dof: int
    p_value: float
    threshold: float
    run_sd: float
    run_sd_ci: tuple[float, float]
    verdict: str

    @property
    def scatters(self) -> bool:
        """True when the scatter is beyond the reported σ."""
        return self.verdict != "repeatable"

    def to_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, "sensor": self.sensor + 1, "sensor_name": self.sensor_name,
                "parameter": self.parameter, "unit": self.unit,
                "values": [float(v) for v in self.values],
                "sds": [float(v) for v in self.sds], "mean": self.mean,
                "mean_sd": self.mean_sd, "chi2": self.chi2, "dof": self.dof,
                "p_value": self.p_value, "threshold": self.threshold,
                "run_sd": self.run_sd, "run_sd_ci": list(self.run_sd_ci),
                "verdict": self.verdict}


@dataclass(frozen=True)
class Repeatability:
    """Run-to-run repeatability of every parameter (:func:`repeatability`)."""

    alpha: float
    n_sessions: int
    parameters: tuple[ParameterRepeat, ...]
    ci_level: float = CI_LEVEL

    def flagged(self) -> list[ParameterRepeat]:
        """The parameters that scatter beyond their σ."""
        return [p for p in self.parameters if p.scatters]

    def to_dict(self) -> dict[str, Any]:
        return {"alpha": self.alpha, "n_sessions": self.n_sessions,
                "ci_level": self.ci_level, "correction": "holm",
                "n_tested": len(self.parameters), "n_flagged": len(self.flagged()),
                "parameters": [p.to_dict() for p in self.parameters]}


@dataclass(frozen=True)
class StackResult:
    """The stacked session's calibration and adequacy (:mod:`calibration.stack`)."""

    n_sessions: int
    session: Session
    calibration: Calibration

    @property
    def adequacy(self) -> Mapping[str, Any]:
        return self.calibration.adequacy or {}

    def to_dict(self) -> dict[str, Any]:
        a = self.adequacy
        return {"n_sessions": self.n_sessions, "verdict": a.get("verdict"),
                "where": list(a.get("where", [])),
                "not_ruled_out": list(a.get("not_ruled_out", [])),
                "sequence_limits": list(a.get("sequence_limits", [])),
                "noise_model_applied": a.get("noise_model_applied")}


@dataclass(frozen=True)
class RepeatResult:
    """What ``rimu repeat`` reports (schema :data:`REPEAT_SCHEMA`)."""

    sources: tuple[str, ...]
    calibrations: tuple[Calibration, ...]
    repeatability: Repeatability
    stack: StackResult | None
    stack_skipped: str | None = None
    schema: str = field(default=REPEAT_SCHEMA)

    def to_dict(self) -> dict[str, Any]:
        return {"schema": self.schema, "sessions": list(self.sources),
                "session_verdicts": [(c.adequacy or {}).get("verdict")
                                     for c in self.calibrations],
                "repeatability": self.repeatability.to_dict(),
                "stack": None if self.stack is None else self.stack.to_dict(),
                "stack_skipped": self.stack_skipped}


def _q(x: np.ndarray, v: np.ndarray) -> float:
    w = 1.0 / v
    m = float(np.sum(w * x) / np.sum(w))
    return float(np.sum(w * (x - m) ** 2))


def run_to_run_sd(x: Iterable[float], sd: Iterable[float], level: float = CI_LEVEL
                  ) -> tuple[float, tuple[float, float]]:
    """Run-to-run σ τ beyond the reported σ, and its confidence interval.

    Parameters
    ----------
    x, sd : array_like, shape (N,)
        Estimates and their reported σ (same unit, σ > 0).
    level : float
        Confidence level of the interval.

    Returns
    -------
    tau : float
        DerSimonian-Laird moment estimate (module docstring), 0 when Q ≤ N − 1.
    (lo, hi) : tuple of float
        Q-profile interval (Viechtbauer 2007, Eq. 5): Q(τ²) is decreasing in τ², so each end
        solves Q(τ²) = a χ²_{N−1} quantile; an end is 0 when Q(0) is already below it.
    """
    x, v = np.asarray(x, float), np.asarray(sd, float) ** 2
    n = x.size
    w = 1.0 / v
    Q = _q(x, v)
    tau2 = max(0.0, (Q - (n - 1)) / (w.sum() - (w**2).sum() / w.sum()))
    ends = []
    for q in (scipy.stats.chi2.isf((1 - level) / 2, n - 1),
              scipy.stats.chi2.ppf((1 - level) / 2, n - 1)):
        if Q <= q:
            ends.append(0.0)
            continue
        hi = max(float(np.var(x, ddof=1)), float(v.max()))
        while _q(x, v + hi) > q:
            hi *= 4.0
        ends.append(float(scipy.optimize.brentq(lambda t2, q=q: _q(x, v + t2) - q, 0.0, hi,
                                                xtol=1e-14 * hi)))
    return float(np.sqrt(tau2)), (float(np.sqrt(ends[0])), float(np.sqrt(ends[1])))


def _values(cal: Calibration, kind: str, i: int) -> dict[str, tuple[float, float]]:
    c = cal.sets[kind].sensors[i]
    m, msd = np.asarray(c.misalignment, float), np.asarray(c.misalignment_sd, float)
    return {"bias": (c.bias, c.bias_sd), "scale_factor": (c.scale_factor, c.scale_factor_sd),
            "misalignment_1": (m[0], msd[0]), "misalignment_2": (m[1], msd[1])}


def repeatability(cals: Sequence[Calibration], *, alpha: float = 0.01) -> Repeatability:
    """Compare the parameters of N ≥ 2 calibrations of one IMU (module docstring, part 1).

    Parameters
    ----------
    cals : sequence of Calibration
        Same sensor sets (kinds, sensor names).
    alpha : float
        Family-wise level over all parameters tested (Holm).

    Returns
    -------
    Repeatability
        Bias in the sensor's bias unit (deg/h, mg, ...), scale factor in ppm of its mean,
        misalignment in mrad.

    Raises
    ------
    ConfigError
        Fewer than two calibrations, different sensor sets, a σ that is not positive.
    """
    if len(cals) < 2:
        raise ConfigError(f"repeatability needs at least two sessions, got {len(cals)}")
    if not 0 < alpha < 1:
        raise ConfigError(f"alpha must be between 0 and 1, got {alpha!r}")
    rows = _parameter_rows(cals)
    stats = [_parameter_stats(x, s) for *_, x, s in rows]
    thr, flag = _holm([st[1] for st in stats], alpha)
    out = []
    for j, ((kind, i, name, p, unit, x, s), (Q, pv, tau, ci, mu, musd)) in enumerate(
            zip(rows, stats, strict=True)):
        out.append(ParameterRepeat(kind, i, name, p, unit, x, s, mu, musd, Q, x.size - 1, pv,
                                   float(thr[j]), tau, ci,
                                   "scatters beyond its σ" if flag[j] else "repeatable"))
    return Repeatability(alpha, len(cals), tuple(out))


_Row = tuple[str, int, str, str, str, np.ndarray, np.ndarray]


def _parameter_rows(cals: Sequence[Calibration]) -> list[_Row]:
    """Every parameter of every sensor over the sessions, in its reporting unit.

    Parameters
    ----------
    cals : sequence of Calibration

    Returns
    -------
    list of (kind, index, name, parameter, unit, values, sds)

    Raises
    ------
    ConfigError
        A session's sensors differ from the first's, or a value or σ is not usable.
    """
    ref = cals[0]
    rows = []
    for kind, sset in ref.sets.items():
        names = [c.name for c in sset.sensors]
        for k, cal in enumerate(cals[1:], 2):
            if kind not in cal.sets or [c.name for c in cal.sets[kind].sensors] != names:
                raise ConfigError(f"session {k}: {kind} sensors differ from session 1's "
                                  f"{names}")
        for i, c in enumerate(sset.sensors):
            vals = [_values(cal, kind, i) for cal in cals]
            for p in _PARAMS:
                x = np.array([v[p][0] for v in vals])
                s = np.array([v[p][1] for v in vals])
                f, unit = _reporting_unit(p, c.bias_unit, x)
                if not np.all(np.isfinite(s) & (s > 0)) or not np.all(np.isfinite(x)):
                    raise ConfigError(f"{kind} {c.name} {p}: every session needs a finite "
                                      f"value and a positive sd, got {x.tolist()} ± "
                                      f"{s.tolist()}")
                rows.append((kind, i, c.name, p, unit, x / f, s / f))
    return rows


def _reporting_unit(p: str, bias_unit: str, x: np.ndarray) -> tuple[float, str]:
    """Factor (SI per unit) and name of the unit parameter ``p`` is reported in.

    Parameters
    ----------
    p : str
        One of :data:`_PARAMS`.
    bias_unit : str
        The sensor's bias unit.
    x : ndarray
        The sessions' values (SI): the scale factor is reported in ppm of their mean.

    Returns
    -------
    (float, str)
    """
    if p == "bias":
        return input_unit_factor(bias_unit), bias_unit
    if p == "scale_factor":
        return abs(float(np.mean(x))) * 1e-6, "ppm of mean"
    return 1e-3, "mrad"


def _parameter_stats(x: np.ndarray, s: np.ndarray
                     ) -> tuple[float, float, float, tuple[float, float], float, float]:
    """Cochran's Q, its p-value, the run-to-run sd with its interval, and the
    random-effects mean with its sd, of one parameter over the sessions.

    Parameters
    ----------
    x, s : ndarray
        Values and sds.

    Returns
    -------
    (Q, p, tau, (lo, hi), mean, mean_sd)
    """
    n = x.size
    Q = _q(x, s**2)
    pv = float(scipy.stats.chi2.sf(Q, n - 1))
    tau, ci = run_to_run_sd(x, s)
    w = 1.0 / (s**2 + tau**2)
    return Q, pv, tau, ci, float(np.sum(w * x) / w.sum()), float(1 / np.sqrt(w.sum()))


def _holm(pvalues: Sequence[float], alpha: float) -> tuple[np.ndarray, np.ndarray]:
    """Holm over all parameters: the k-th smallest p against α/(m − k), stop at the first
    pass.

    Parameters
    ----------
    pvalues : sequence of float
    alpha : float
        Family-wise level.

    Returns
    -------
    thr : ndarray
        Each test's threshold.
    flag : ndarray of bool
        Rejected.
    """
    m = len(pvalues)
    order = np.argsort(pvalues, kind="stable")
    thr = np.empty(m)
    flag = np.zeros(m, bool)
    going = True
    for k, j in enumerate(order):
        thr[j] = alpha / (m - k)
        going = going and pvalues[j] <= thr[j]
        flag[j] = going
    return thr, flag


def repeat_sessions(sessions: Sequence[Session], *, alpha: float = 0.01,
                    stack: bool | None = None, detectability: bool = True,
                    calibrations: Sequence[Calibration] | None = None,
                    progress: bool = False, **kw: Any) -> RepeatResult:
    """Calibrate N sessions, compare their parameters, and check their stack.

    Parameters
    ----------
    sessions : sequence of Session, N ≥ 2
    alpha : float
        Level of the repeatability tests (Holm) and of each adequacy check.
    stack : bool or None
        None: stack when the sessions have one sequence, else say why not; True: the
        sessions must stack (ConfigError naming the session and field otherwise); False:
        no stacking.
    detectability : bool
        Passed to :func:`calibration.calibrate_checked.calibrate_checked` (False: no "effects not
        ruled out" limits; faster).
    calibrations : sequence of Calibration, optional
        The sessions' calibrations when already made (otherwise ``calibrate_checked``).
    progress : bool
        A progress bar over the calibrations (each takes 1-3 s; :mod:`fdi.progress`).
    **kw
        Passed to ``calibrate_checked`` (``noise_model``, ``allan``, ``earth_rate``, ...).

    Raises
    ------
    ConfigError
        Fewer than two sessions, sessions of different configurations, or ``stack=True``
        with sessions of different sequences.
    """
    from calibration.calibrate_checked import calibrate_checked

    if len(sessions) < 2:
        raise ConfigError("rimu repeat: give at least two sessions to compare, got "
                          f"{len(sessions)}" + (f" ({sessions[0].source})" if sessions else ""))
    for s in sessions[1:]:
        why = configuration_mismatch(sessions[0], s)
        if why:
            raise ConfigError(why)
    why = stack_mismatch(sessions) if stack is not False else "not asked for"
    if stack and why:
        raise ConfigError(f"{why}; stacking needs identical sequences")
    from fdi.progress import Progress, current

    total = (len(sessions) if calibrations is None else 0) + (why is None)
    prog = current() if progress else Progress("repeat", enabled=False)
    with prog.bar(total, "calibrations", unit="calibrations") as bar:
        if calibrations is None:
            calibrations = []
            for s in sessions:
                calibrations.append(calibrate_checked(s, alpha=alpha,
                                                      detectability=detectability, **kw))
                bar.update()
        rep = repeatability(calibrations, alpha=alpha)
        res = None
        if why is None:
            st = stack_sessions(sessions)
            res = StackResult(len(sessions), st,
                              calibrate_checked(st, alpha=alpha, detectability=detectability,
                                                **kw))
            bar.update()
    return RepeatResult(tuple(s.source for s in sessions), tuple(calibrations), rep, res,
                        None if why is None else why)
