"""Run-time compensation of a calibration's effect terms (``effects``, ``rimu.calibration/2`` on).

A calibration may carry effect terms beyond the linear sensor model (``rimu calibrate
turntable --effects``, ``rimu diagnose``): each adds ``estimate · g(inputs; params)`` to
one sensor's SI output, with ``g`` the session regressor of the effect's spec
(:mod:`fdi.effect_specs`; the SI output gained per unit of the estimate, the estimate in
the term's ``unit``). The
monitor takes a run-time correction ``c`` (rad/s or m/s²) subtracted from the compensated outputs,
``y = SF·u − b − c`` (:meth:`fdi.monitor.Monitor.run`); this module computes ``c`` from the
terms whose inputs the stream carries, and says which terms it cannot apply and why.

Each compensated effect's run-time form is its spec's
:class:`~fdi.effect_specs.RuntimeForm` (:mod:`fdi.effect_specs.builtin` tabulates which
effects have one, the input each reads, and why the others have none): an elementwise
``apply(k, x, e)`` with the constants folded into ``k`` and ``e`` once, shared by the block
path, the one-sample path and :func:`term_correction`. The rate terms read ``ŝ_i`` the
sensor's own compensated output, ``g_sensitivity`` the specific force ``f`` (m/s², MB
frame) from the accelerometers in the stream along ``h̃_i`` its calibrated axis,
``temperature`` the sensor's temperature ``T`` (°C) from the stream against the term's
``params.reference_degC``; ``scale_nonlinearity`` divides by the table rate of the
calibration session (``params.table_rate_dps``).

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

**Not compensated**: the effects whose spec gives ``no_runtime`` (the reason is listed
with the term), user effects without a run-time form, a term of the other sensor kind, and a
term whose unit or parameters the run-time form does not recognise (refused rather than
guessed).

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
from fdi.effect_specs import INPUT_LACKING, RUNTIME_INPUTS, EffectSpec, effect_specs, get_spec

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

INPUTS = RUNTIME_INPUTS
"""Run-time inputs a term can need (the rate is the sensor's own output, always there)."""

_RUNTIME = {sp.name: sp for sp in sorted((sp for sp in effect_specs() if sp.runtime),
                                         key=lambda sp: sp.runtime.code)}

COMPENSABLE: dict[str, tuple[str, str]] = {
    n: (sp.runtime.input, sp.runtime.reads) for n, sp in _RUNTIME.items()}
"""Compensable built-in effect: (run-time input, what it reads), in the order of the
run-time codes."""

NOT_COMPENSABLE: dict[str, str] = {sp.name: sp.no_runtime for sp in effect_specs()
                                   if sp.runtime is None and sp.no_runtime}
"""Known effects the monitor does not compensate, with the reason."""


def _form(name: str) -> EffectSpec | None:
    """The spec of a term's effect when it has a run-time form (user specs included)."""
    sp = _RUNTIME.get(name) or get_spec(name)
    return sp if sp is not None and sp.runtime is not None else None


def term_correction(term: EffectTerm, axis: np.ndarray, *, s: Any = None,
                    force: Any = None, temperature: Any = None) -> np.ndarray:
    """The SI output a term adds, ``estimate · g(inputs)``, for N samples.

    The spec's run-time form (:class:`~fdi.effect_specs.RuntimeForm`, the session
    regressor times the estimate, with no noise variance subtracted); non-finite inputs
    give NaN rows (the :class:`Compensator` turns them into 0 and counts them).

    Parameters
    ----------
    term : EffectTerm
        A compensable term (:data:`COMPENSABLE`) with its library unit.
    axis : ndarray, shape (3,)
        The sensor's calibrated axis h̃ (terms reading the specific force).
    s : array_like, shape (N,)
        Input along the axis (SI; terms reading the rate).
    force : array_like, shape (N, 3)
        Specific force, MB frame (m/s²).
    temperature : array_like, shape (N,)
        Sensor temperature (°C).

    Returns
    -------
    ndarray, shape (N,)
        rad/s for gyros, m/s² for accelerometers.

    Raises
    ------
    ValueError
        Not a compensable term, or parameters its form needs missing (a programming
        error, not data).
    """
    sp = _form(term.name)
    if sp is None:
        raise ValueError(f"effect {term.name!r} has no run-time form")
    rt = sp.runtime
    why = rt.check(term.params)
    if why is not None:
        raise ValueError(f"{term.name}: {why}")
    k = rt.coefficient(float(term.estimate), term.params, term.kind)
    e = rt.extra(term.params, np.asarray(axis, float), 0.0)
    if rt.input == "rate":
        return rt.apply(k, np.asarray(s, float), e)
    if rt.input == "specific_force":
        f = np.asarray(force, float)
        return rt.apply(k, (f[..., 0], f[..., 1], f[..., 2]), e)
    return rt.apply(k, np.asarray(temperature, float), e)


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
    sp = _form(term.name)
    if sp is None:
        return "user effect: no run-time form"
    rt = sp.runtime
    if kind not in rt.kinds:
        return f"no run-time form for {kind} sensors"
    want = sp.unit_for(kind)
    if term.unit != want:
        return f"unit {term.unit!r}, the run-time form expects {want!r}"
    if not math.isfinite(float(term.estimate)):
        return "the estimate is not finite"
    if "components" in term.params:
        return "a multi-column term (no run-time form)"
    why = rt.check(term.params)
    if why is not None:
        return why
    need = rt.input
    if need != "rate" and term.sensor not in available.get(need, ()):
        return (f"needs {need.replace('_', ' ')}: "
                + (lacking or {}).get(need, INPUT_LACKING.get(need, "not in the stream")))
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
                rt = _form(t.name).runtime
                applied.append(AppliedTerm(t, rt.input, rt.reads))
            else:
                skipped.append(SkippedTerm(t, why))
        self.applied: tuple[AppliedTerm, ...] = tuple(applied)
        self.skipped: tuple[SkippedTerm, ...] = tuple(skipped)
        self.missing: dict[tuple[str, int], int] = {
            (a.term.name, a.term.sensor): 0 for a in self.applied if a.input != "rate"}
        self._grouped = self._groups()
        rate = sorted({int(i) for rt, _, idx, _, _ in self._grouped
                       if rt.input == "rate" for i in idx})
        self._rate_idx = np.array(rate, dtype=np.intp)
        self._rate_pos = {nm: np.searchsorted(self._rate_idx, idx)
                          for rt, nm, idx, _, _ in self._grouped if rt.input == "rate"}
        self._forms = {rt.code: rt for rt, *_ in self._grouped}
        self._scalar = [(rt.code, nm, int(idx[j]), float(k[j]),
                         extra[j].tolist() if extra.ndim == 2 else float(extra[j]))
                        for rt, nm, idx, k, extra in self._grouped for j in range(idx.size)]
        self._scalar_forms = [(self._forms[code].apply, self._forms[code].input)
                              for code, *_ in self._scalar]
        self._sf_list, self._b_list = self._sf.tolist(), self._b.tolist()

    @property
    def active(self) -> bool:
        """Whether any term is applied (False: the correction is always 0)."""
        return bool(self.applied)

    @property
    def needs(self) -> frozenset[str]:
        """Run-time inputs the applied terms read."""
        return frozenset(a.input for a in self.applied)

    def _groups(self) -> list[tuple[Any, str, np.ndarray, np.ndarray, np.ndarray]]:
        """Applied terms by effect, in the order of the run-time codes: (run-time form,
        name, sensors, coefficients ``k``, extras ``e``) with the constants of the form
        folded in once (``e``: the axes of a force term, (m, 3); else (m,))."""
        out = []
        names = list(dict.fromkeys(a.term.name for a in self.applied))
        for name in sorted(names, key=lambda nm: _form(nm).runtime.code):
            rt = _form(name).runtime
            ts = [a.term for a in self.applied if a.term.name == name]
            idx = np.array([t.sensor for t in ts], dtype=np.intp)
            k = np.array([rt.coefficient(float(t.estimate), t.params, t.kind) for t in ts])
            extra = np.array([rt.extra(t.params, self._H[t.sensor], self._var[t.sensor])
                              for t in ts], float)
            out.append((rt, name, idx, k, extra))
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
            for rt, name, idx, k, extra in self._grouped:
                if rt.input == "rate":
                    v = rt.apply(k, s_hat[:, self._rate_pos[name]], extra)
                elif rt.input == "specific_force":
                    f = _force_of(force, N, self.n, idx)                  # (N, m, 3)
                    v = rt.apply(k, (f[..., 0], f[..., 1], f[..., 2]),
                                 (extra[:, 0], extra[:, 1], extra[:, 2]))
                else:
                    v = rt.apply(k, _temp_of(temperature, N, self.n, idx), extra)
                bad = ~np.isfinite(v)
                if bad.any():
                    v = np.where(bad, 0.0, v)
                    if rt.input != "rate":                 # a bad output: the monitor's
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
        for (_, name, i, k, e), (apply, inp) in zip(self._scalar, self._scalar_forms,
                                                   strict=True):
            if inp == "rate":
                v = apply(k, r[i] * sf[i] - b[i], e)
            elif inp == "specific_force":
                fi = f if f is None or not isinstance(f[0], list) else f[i]
                v = apply(k, fi, e) if fi is not None else math.nan
            else:
                v = apply(k, T[i], e) if T is not None else math.nan
            if not math.isfinite(v):
                v = 0.0
                if inp != "rate":
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
