"""Run-time compensation of a calibration's effect terms (``rimu.calibration/2`` ``effects``).

A calibration may carry effect terms beyond the linear sensor model (``rimu calibrate
--effects``, ``rimu diagnose``): each adds ``estimate · g(inputs; params)`` to one sensor's
SI output, with ``g`` the regressor of :mod:`calibration.diagnose.library` (the SI output
gained per unit of the estimate, the estimate in the term's ``unit``). The monitor takes a
run-time correction ``c`` (rad/s or m/s²) subtracted from the compensated outputs,
``y = SF·u − b − c`` (:meth:`fdi.monitor.Monitor.run`); this module computes ``c`` from the
terms whose inputs the stream carries, and says which terms it cannot apply and why.

Compensated terms and their run-time input (``ŝ_i`` the sensor's own compensated output,
``h̃_i`` its calibrated axis)::

    scale_asymmetry     fraction          c = a·|ŝ|/2                    rate sign
    scale_nonlinearity  fraction          c = k·(ŝ² − σ²)/w              rate squared
    g_sensitivity       deg/h per g       c = k·DPH·(h̃·f)/g0             specific force
    temperature         deg/h (mg) per °C c = k·DPH (MG)·(T − T_ref)     temperature

``w`` the table rate of the calibration session (``params.table_rate_dps``), ``T_ref`` the
term's ``params.reference_degC``, ``f`` the specific force (m/s², MB frame) from the
accelerometers in the stream, ``T`` the sensor's temperature (°C) from the stream.

**Which rate.** The regressors of the rate terms are written in the true input along the
axis, ``s = h̃·x``, which the monitor does not know. The sensor's own compensated output
``ŝ = SF·u − b`` is the causal choice that keeps the sensors independent: sensor i's
correction depends on sensor i's sample (and the auxiliary channels) only, so a fault on
another sensor cannot leak into it, and the correction is available at the same sample.
(The reconstructed rate ω̂ would average the noise down but couples every sensor's
correction to every other's output, faulty or not.) Its cost: ``ŝ = s + η`` (noise sd
``σ_i``, the calibration's ``noise_covariance`` diagonal) and ``ŝ`` still contains the
effect itself. For the quadratic term ``E[ŝ²] = s² + σ²``, so ``σ²`` is subtracted and the
correction is unbiased; for the asymmetry ``E|ŝ| − |s|`` is at most ``σ·√(2/π)`` at zero
rate and vanishes for ``|s| ≫ σ``, a residual bias of at most ``a·σ·0.4`` (``0.0004 σ`` for
``a = 0.001``). The effect inside ``ŝ`` changes the correction by a relative ``a/2`` or
``k·s/w``: second order.

**Not compensated** (listed with the reason): ``bias_step``, ``bias_drift``,
``periodic_line``, ``misalignment`` and ``no_earth_rate`` describe the calibration session
(a jump at a session time, a drift over the session length, a line of unknown phase, a
re-mounting on the table, the Earth-rate model), not a sensor property that carries into
the run; ``warmup`` needs the time since switch-on, which no stream carries; ``time_skew``
needs the input's rate of change; user effects have no run-time form; a term of the other
sensor kind is not monitored; a term whose unit or parameters the evaluator does not
recognise is refused rather than guessed.

Bad inputs never raise: a non-finite output, force or temperature gives that term 0 for
that sample, and the samples are counted (:attr:`Compensator.missing`).
"""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from fdi.calfile import Calibration, EffectTerm
from fdi.units import DPH, DPS, G0, MG

__all__ = [
    "COMPENSABLE",
    "EFFECTS_RUNTIME_SCHEMA",
    "INPUTS",
    "NOT_COMPENSABLE",
    "AppliedTerm",
    "Compensator",
    "SkippedTerm",
    "term_correction",
]

EFFECTS_RUNTIME_SCHEMA = "rimu.effects-runtime/1"
"""Version of :meth:`Compensator.to_dict` (in reports)."""

INPUTS = ("rate", "specific_force", "temperature")
"""Run-time inputs a term can need (the rate is the sensor's own output, always there)."""

_BIAS_SI = {"gyro": ("deg/h", DPH), "accel": ("mg", MG)}

COMPENSABLE: dict[str, tuple[str, str]] = {
    "scale_asymmetry": ("rate", "rate sign"),
    "scale_nonlinearity": ("rate", "rate squared"),
    "g_sensitivity": ("specific_force", "specific force"),
    "temperature": ("temperature", "temperature"),
}
"""Compensable effect: (run-time input, what it reads)."""

NOT_COMPENSABLE: dict[str, str] = {
    "bias_step": "session-specific (a jump at a time of the calibration session), not a "
                 "sensor property",
    "bias_drift": "session-specific (a drift over the calibration session's length), not a "
                  "sensor property",
    "periodic_line": "session-specific (a line whose phase at run time is unknown)",
    "misalignment": "session-specific (a re-mounting on the turntable)",
    "no_earth_rate": "a flaw of the session's Earth-rate model, not of the sensor",
    "warmup": "needs the time since switch-on, which the stream does not carry",
    "time_skew": "needs the input's rate of change (no run-time form)",
}
"""Known effects the monitor does not compensate, with the reason."""

_UNITS = {
    "scale_asymmetry": {"gyro": "fraction"},
    "scale_nonlinearity": {"gyro": "fraction"},
    "g_sensitivity": {"gyro": "deg/h per g"},
    "temperature": {"gyro": "deg/h per degC", "accel": "mg per degC"},
}
"""The unit each compensable term must carry (the library's), per kind."""


def _finite_param(params: Mapping[str, Any], key: str) -> float | None:
    try:
        v = float(params[key])
    except (KeyError, TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def term_correction(term: EffectTerm, axis: np.ndarray, *, s: Any = None, s_sq: Any = None,
                    force: Any = None, temperature: Any = None) -> np.ndarray:
    """The SI output a term adds, ``estimate · g(inputs)``, for N samples.

    The same arithmetic as the library regressor times the estimate
    (:mod:`calibration.diagnose.library`); non-finite inputs give NaN rows (the
    :class:`Compensator` turns them into 0 and counts them).

    Parameters
    ----------
    term : EffectTerm
        A compensable term (:data:`COMPENSABLE`) with its library unit.
    axis : ndarray, shape (3,)
        The sensor's calibrated axis h̃ (g_sensitivity).
    s : array_like, shape (N,)
        Input along the axis (SI; scale_asymmetry).
    s_sq : array_like, shape (N,)
        Its square (SI²; scale_nonlinearity; default ``s**2``).
    force : array_like, shape (N, 3)
        Specific force, MB frame (m/s²; g_sensitivity).
    temperature : array_like, shape (N,)
        Sensor temperature (°C; temperature).

    Returns
    -------
    ndarray, shape (N,)
        rad/s for gyros, m/s² for accelerometers.

    Raises
    ------
    ValueError
        Not a compensable term, or its input not given (a programming error, not data).
    """
    est = float(term.estimate)
    name = term.name
    if name == "scale_asymmetry":
        return est * 0.5 * np.abs(np.asarray(s, float))
    if name == "scale_nonlinearity":
        w = _finite_param(term.params, "table_rate_dps")
        if w is None or w <= 0:
            raise ValueError("scale_nonlinearity: params.table_rate_dps missing")
        sq = np.asarray(s, float) ** 2 if s_sq is None else np.asarray(s_sq, float)
        return est * sq / (w * DPS)
    if name == "g_sensitivity":
        f = np.asarray(force, float)
        return est * DPH * (f @ np.asarray(axis, float)) / G0
    if name == "temperature":
        ref = _finite_param(term.params, "reference_degC")
        unit_si = _BIAS_SI[term.kind][1]
        return est * unit_si * (np.asarray(temperature, float) - (ref or 0.0))
    raise ValueError(f"effect {name!r} has no run-time form")


@dataclass(frozen=True)
class AppliedTerm:
    """A term the monitor compensates."""

    term: EffectTerm
    input: str
    reads: str

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (sensor 1-based)."""
        t = self.term
        return {"name": t.name, "kind": t.kind, "sensor": t.sensor + 1,
                "estimate": t.estimate, "estimate_sd": t.estimate_sd, "unit": t.unit,
                "input": self.reads}


@dataclass(frozen=True)
class SkippedTerm:
    """A term the monitor cannot apply, and why."""

    term: EffectTerm
    reason: str

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (sensor 1-based)."""
        t = self.term
        return {"name": t.name, "kind": t.kind, "sensor": t.sensor + 1,
                "estimate": t.estimate, "unit": t.unit, "reason": self.reason}


def _why_not(term: EffectTerm, kind: str, n: int,
             available: Mapping[str, Collection[int]],
             lacking: Mapping[str, str] | None = None) -> str | None:
    """None when ``term`` can be applied, else the reason."""
    if term.kind != kind:
        return (f"{'an accelerometer' if term.kind == 'accel' else 'a gyro'} term; this "
                f"stream monitors {kind} sensors")
    if not 0 <= term.sensor < n:
        return f"sensor {term.sensor + 1} is not in the calibration's {n} sensors"
    if term.name in NOT_COMPENSABLE:
        return NOT_COMPENSABLE[term.name]
    if term.name not in COMPENSABLE:
        return "user effect: no run-time form"
    want = _UNITS[term.name].get(kind)
    if want is None:
        return f"no run-time form for {kind} sensors"
    if term.unit != want:
        return f"unit {term.unit!r}, the run-time form expects {want!r}"
    if not math.isfinite(float(term.estimate)):
        return "the estimate is not finite"
    if "components" in term.params:
        return "a multi-column term (no run-time form)"
    if term.name == "scale_nonlinearity":
        w = _finite_param(term.params, "table_rate_dps")
        if w is None or w <= 0:
            return ("the term does not record the table rate (params.table_rate_dps); "
                    "refit it with this version")
    if term.name == "temperature" and _finite_param(term.params, "reference_degC") is None:
        return "the term does not record its reference temperature (params.reference_degC)"
    need = COMPENSABLE[term.name][0]
    lacking = lacking or {}
    if need == "specific_force" and term.sensor not in available.get(need, ()):
        return "needs specific force: " + lacking.get(need, "no accelerometers in the stream")
    if need == "temperature" and term.sensor not in available.get(need, ()):
        return "needs temperature: " + lacking.get(
            need, "the stream carries none for this sensor")
    return None


class Compensator:
    """The run-time correction of a calibration's effect terms for one sensor kind.

    Parameters
    ----------
    cal : Calibration
    kind : str
        The monitored kind (``"gyro"`` or ``"accel"``).
    available : mapping of input name to collection of int, optional
        Which sensors (0-based) have ``"specific_force"`` and ``"temperature"`` at run
        time (the rate is always there). Default: neither.
    enabled : bool
        False: no term applied (``--no-effects``); every term listed as switched off.
    lacking : mapping of input name to str, optional
        What a term whose input is not available is told lacks it (default: "no
        accelerometers in the stream", "the stream carries none for this sensor"); e.g. the
        channel map that names no such channel.

    Attributes
    ----------
    applied : tuple of AppliedTerm
    skipped : tuple of SkippedTerm
    missing : dict of (str, int) to int
        Per applied term (name, 0-based sensor): samples whose input was not finite (that
        term contributed 0 there).

    Notes
    -----
    :meth:`block` (N samples, numpy, vectorised over the terms of each effect) and
    :meth:`one` (one sample, Python floats) perform the same elementwise operations in the
    same order (no BLAS reductions), so the block and step paths of the monitor get the
    same correction to the bit (tested).
    """

    def __init__(self, cal: Calibration, kind: str = "gyro", *,
                 available: Mapping[str, Collection[int]] | None = None,
                 enabled: bool = True, lacking: Mapping[str, str] | None = None) -> None:
        s = cal.kind(kind)
        self.kind = kind
        self.n = s.n
        self.enabled = enabled
        self._sf = np.asarray(s.scale_factors, float)
        self._b = np.asarray(s.biases, float)
        self._H = np.asarray(s.H, float)
        self._var = np.diag(np.asarray(s.noise_covariance, float)).copy()
        av = {k: frozenset(int(i) for i in v) for k, v in (available or {}).items()}
        applied, skipped = [], []
        for t in cal.effects:
            why = ("switched off (--no-effects)" if not enabled
                   else _why_not(t, kind, s.n, av, lacking))
            if why is None:
                inp, reads = COMPENSABLE[t.name]
                applied.append(AppliedTerm(t, inp, reads))
            else:
                skipped.append(SkippedTerm(t, why))
        self.applied: tuple[AppliedTerm, ...] = tuple(applied)
        self.skipped: tuple[SkippedTerm, ...] = tuple(skipped)
        self.missing: dict[tuple[str, int], int] = {
            (a.term.name, a.term.sensor): 0 for a in self.applied if a.input != "rate"}
        self._grouped = self._groups()
        rate = sorted({int(i) for nm, idx, _, _ in self._grouped
                       if COMPENSABLE[nm][0] == "rate" for i in idx})
        self._rate_idx = np.array(rate, dtype=np.intp)
        self._rate_pos = {nm: np.searchsorted(self._rate_idx, idx)
                          for nm, idx, _, _ in self._grouped if COMPENSABLE[nm][0] == "rate"}
        code = {"scale_asymmetry": 0, "scale_nonlinearity": 1, "g_sensitivity": 2,
                "temperature": 3}
        self._scalar = [(code[nm], nm, int(idx[j]), float(k[j]),
                         extra[j].tolist() if extra.ndim == 2 else
                         float(extra[j]) if extra.size else 0.0)
                        for nm, idx, k, extra in self._grouped for j in range(idx.size)]
        self._sf_list, self._b_list = self._sf.tolist(), self._b.tolist()

    @property
    def active(self) -> bool:
        """Whether any term is applied (False: the correction is always 0)."""
        return bool(self.applied)

    @property
    def needs(self) -> frozenset[str]:
        """Run-time inputs the applied terms read."""
        return frozenset(a.input for a in self.applied)

    def _groups(self) -> list[tuple[str, np.ndarray, np.ndarray, np.ndarray]]:
        """Applied terms by effect: (name, sensors, coefficients, extra) with the constants
        of :func:`term_correction` folded into one coefficient per term (``extra``: the
        axes of g_sensitivity, the reference temperatures)."""
        out = []
        for name in COMPENSABLE:
            ts = [a.term for a in self.applied if a.term.name == name]
            if not ts:
                continue
            idx = np.array([t.sensor for t in ts], dtype=np.intp)
            est = np.array([float(t.estimate) for t in ts])
            if name == "scale_asymmetry":
                k, extra = est * 0.5, np.zeros(0)
            elif name == "scale_nonlinearity":
                w = np.array([_finite_param(t.params, "table_rate_dps") for t in ts]) * DPS
                k, extra = est / w, self._var[idx]
            elif name == "g_sensitivity":
                k, extra = est * DPH / G0, self._H[idx]
            else:
                k = est * np.array([_BIAS_SI[t.kind][1] for t in ts])
                extra = np.array([_finite_param(t.params, "reference_degC") for t in ts])
            out.append((name, idx, k, extra))
        return out

    def _compute(self, raw: np.ndarray, force: np.ndarray | None,
                 temperature: np.ndarray | None) -> np.ndarray:
        """The correction (N, n); vectorised over the terms of each effect, elementwise
        only (no BLAS reductions), so one row gives the same bits as a block."""
        N = raw.shape[0]
        c = np.zeros((N, self.n))
        if not self.applied:
            return c
        with np.errstate(all="ignore"):
            s_hat = raw[:, self._rate_idx] * self._sf[self._rate_idx] - self._b[self._rate_idx]
            for name, idx, k, extra in self._grouped:
                if name == "scale_asymmetry":
                    v = k * np.abs(s_hat[:, self._rate_pos[name]])
                elif name == "scale_nonlinearity":
                    x = s_hat[:, self._rate_pos[name]]
                    v = k * (x * x - extra)
                elif name == "g_sensitivity":
                    f = _force_of(force, N, self.n, idx)                  # (N, m, 3)
                    v = k * (f[..., 0] * extra[:, 0] + f[..., 1] * extra[:, 1]
                             + f[..., 2] * extra[:, 2])
                else:
                    v = k * (_temp_of(temperature, N, self.n, idx) - extra)
                bad = ~np.isfinite(v)
                if bad.any():
                    v = np.where(bad, 0.0, v)
                    if name in ("g_sensitivity", "temperature"):   # a bad output: the monitor's
                        for j, cnt in zip(idx, bad.sum(axis=0), strict=True):
                            self.missing[(name, int(j))] += int(cnt)
                if np.unique(idx).size == idx.size:
                    c[:, idx] += v
                else:                                   # two terms of one effect on a sensor
                    for j in range(idx.size):
                        c[:, idx[j]] += v[:, j]
        return c

    def block(self, raw: Any, force: Any = None, temperature: Any = None) -> np.ndarray:
        """The correction for N samples, shape (N, n), finite (rad/s or m/s²).

        Parameters
        ----------
        raw : array_like, shape (N, n)
            Raw outputs (the monitor's input).
        force : array_like, shape (N, 3) or (N, n, 3), optional
            Specific force (m/s², MB frame), one vector per sample or one per sensor and
            sample; NaN where none.
        temperature : array_like, shape (N,) or (N, n), optional
            Temperature (°C) of the set or of each sensor; NaN where none.
        """
        r = _arr(raw)
        if r is None or r.ndim != 2 or r.shape[1] != self.n:
            return np.zeros((r.shape[0] if r is not None and r.ndim else 0, self.n))
        return self._compute(r, _arr(force), _arr(temperature))

    def one(self, raw: Any, force: Any = None, temperature: Any = None) -> np.ndarray:
        """The correction for one sample, shape (n,) (see :meth:`block`).

        Python floats, term by term in the order of :meth:`block`, with the same
        operations in the same order: the same bits as the block's row, at a few µs.
        """
        c = [0.0] * self.n
        if not self._scalar:
            return np.array(c)
        r = _arr(raw)
        if r is None or r.size != self.n:
            return np.array(c)
        r = r.ravel().tolist()
        f = _arr(force)
        f = (None if f is None else f.tolist() if f.shape == (3,)
             else f.tolist() if f.shape == (self.n, 3) else None)
        T = _arr(temperature)
        T = (None if T is None else [float(T)] * self.n if T.shape == ()
             else T.tolist() if T.shape == (self.n,) else None)
        sf, b = self._sf_list, self._b_list
        for code, name, i, k, e in self._scalar:
            if code == 0:
                v = k * abs(r[i] * sf[i] - b[i])
            elif code == 1:
                x = r[i] * sf[i] - b[i]
                v = k * (x * x - e)
            elif code == 2:
                fi = f if f is None or not isinstance(f[0], list) else f[i]
                v = k * (fi[0] * e[0] + fi[1] * e[1] + fi[2] * e[2]) if fi is not None \
                    else math.nan
            else:
                v = k * (T[i] - e) if T is not None else math.nan
            if not math.isfinite(v):
                v = 0.0
                if code >= 2:
                    self.missing[(name, i)] += 1
            c[i] += v
        return np.array(c)

    def summary(self, names: Any = None) -> str:
        """One line: ``compensating: …; not applied: … (why)``."""
        def who(t: EffectTerm) -> str:
            if names is not None and t.kind == self.kind and 0 <= t.sensor < len(names):
                return f"{t.name} on {names[t.sensor]}"
            return f"{t.name} on {t.kind} {t.sensor + 1}"

        if not self.applied and not self.skipped:
            return "compensating: nothing (the calibration has no effect terms)"
        if not self.enabled:
            return (f"compensating: nothing (--no-effects: {len(self.skipped)} effect term(s) "
                    "switched off: " + ", ".join(who(s.term) for s in self.skipped) + ")")
        on = ", ".join(f"{who(a.term)} (from {a.reads})" for a in self.applied) or "nothing"
        off = "; ".join(f"{who(s.term)} ({s.reason})" for s in self.skipped)
        return f"compensating: {on}" + (f"; not applied: {off}" if off else "")

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready record for reports (``rimu.effects-runtime/1``)."""
        return {"schema": EFFECTS_RUNTIME_SCHEMA, "enabled": self.enabled,
                "applied": [a.to_dict() for a in self.applied],
                "not_applied": [s.to_dict() for s in self.skipped],
                "samples_without_input": [
                    {"name": k[0], "sensor": k[1] + 1, "samples": v}
                    for k, v in self.missing.items()]}


def _arr(x: Any) -> np.ndarray | None:
    if x is None:
        return None
    try:
        return np.asarray(x, float)
    except (TypeError, ValueError):
        return None


def _force_of(force: np.ndarray | None, N: int, n: int, idx: np.ndarray) -> np.ndarray:
    """The specific force of sensors ``idx``, shape (N, m, 3) (NaN when none or
    malformed)."""
    if force is not None:
        if force.shape == (N, 3):
            return force[:, None, :]
        if force.shape == (N, n, 3):
            return force[:, idx]
    return np.full((N, idx.size, 3), np.nan)


def _temp_of(temperature: np.ndarray | None, N: int, n: int, idx: np.ndarray) -> np.ndarray:
    """The temperature of sensors ``idx``, shape (N, m) (NaN when none or malformed)."""
    if temperature is not None:
        if temperature.shape == (N,):
            return temperature[:, None]
        if temperature.shape == (N, n):
            return temperature[:, idx]
    return np.full((N, idx.size), np.nan)
