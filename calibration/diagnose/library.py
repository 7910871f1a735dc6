"""The candidate effects ``rimu diagnose`` tries: regressor, meaning, unit, inputs needed.

Each candidate turns the session (:class:`calibration.diagnose.context.KindData`) into
regressor columns ``Z`` for one sensor, scaled so that the sensor's SI output gains
``Z @ β`` when the effect's value is ``β`` in the candidate's unit. The diagnosis tests
``Z`` as a nested-model extension of the calibration model (:mod:`.selection`).

The built-in candidates are the session forms of the effect specifications
(:mod:`fdi.effect_specs`; the table is in :mod:`fdi.effect_specs.builtin`):
:meth:`Candidate.from_spec` turns a spec into a candidate; the searches for an unknown
parameter (a time, a frequency, a mounting) are here.

Users add candidates with :func:`register_effect` or through the entry-point group
``rimu.effects`` (each entry point names a :class:`Candidate`, an
:class:`~fdi.effect_specs.EffectSpec` or a callable returning one or a list); see
``docs/diagnose.md`` and ``docs/effects.md``. The specs are read from the one effect
registry (:mod:`fdi.effect_specs.registry`, which also reads the entry-point group); kept
here are only the candidates that are not specs (a regressor the diagnosis alone knows).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.optimize

from calibration.diagnose.context import KindData
from fdi.effect_specs import (
    BIAS_UNITS,
    ENTRY_POINT_GROUP,
    EffectSpec,
    effect_specs,
    load_entry_points,
    register_spec,
)
from fdi.effect_specs.builtin import temperature_reference
from fdi.errors import ConfigError

__all__ = [
    "BIAS_UNITS",
    "CHANGE_POINT_GRID",
    "ENTRY_POINT_GROUP",
    "LINE_MIN_CYCLES",
    "OUTSIDE_ALIASES",
    "SEARCHES",
    "Candidate",
    "candidates",
    "change_point_scan",
    "effect_searching",
    "get_candidate",
    "line_search",
    "model_effects",
    "mount_search",
    "register_effect",
    "step_grid",
    "step_range",
    "step_search",
    "temperature_reference",
    "testable",
]

OUTSIDE_ALIASES = {sp.name: sp.could_absorb for sp in effect_specs() if sp.could_absorb}
"""Effects outside the library that each built-in candidate can absorb when it is fitted
(printed with each effect found; the spec's ``could_absorb``;
``tests/calibration/test_closure_injected.py`` measured the two marked). The calibration's
own terms alias too: a bias that follows the rate sign is mostly a scale factor on a
sequence of one table rate."""

Regressor = Callable[[KindData, int, Mapping[str, Any]], np.ndarray]


@dataclass(frozen=True)
class Candidate:
    """One effect the diagnosis can test.

    Attributes
    ----------
    name : str
    kinds : tuple of str
        Sensor kinds it applies to.
    meaning : str
        Physical meaning, one line.
    unit : str or mapping of kind to str
        Unit of its value (``"{bias}"`` in a string is replaced by the kind's bias unit).
    inputs : tuple of str
        Session inputs it needs (``"temperature"``, ``"time"``, ``"table_rate"``, ...).
    regressor : callable ``(data, sensor, params) -> ndarray (N,) or (N, p)``
        SI output per unit of the value, for sensor ``sensor`` (0-based).
    search : callable ``(data, sensor, Q, e) -> (params, multiplicity)`` or None
        For effects with an unknown parameter (a time, a frequency): picks it from the
        current residual ``e`` (orthogonal to the current model basis ``Q``); the test's
        p-value is multiplied by ``multiplicity`` (Bonferroni over the scan).
    needs : callable ``(data) -> str or None``
        Why the effect cannot be tested on this session (None: testable).
    monitor_input : str or None
        What the runtime monitor would need to compensate it (None: not compensable live).
    """

    name: str
    kinds: tuple[str, ...]
    meaning: str
    unit: str
    regressor: Regressor
    inputs: tuple[str, ...] = ()
    search: Callable[..., tuple[dict[str, Any], int]] | None = None
    needs: Callable[[KindData], str | None] = field(default=lambda d: None)
    monitor_input: str | None = None
    fixed_params: Callable[[KindData, int], dict[str, Any]] | None = None

    @classmethod
    def from_spec(cls, spec: EffectSpec) -> Candidate:
        """The diagnosis's form of an effect spec (its search by the parameter it
        searches, :data:`SEARCHES`)."""
        return cls(spec.name, spec.kinds, spec.meaning, spec.unit, spec.regressor,
                   spec.inputs, search=SEARCHES[spec.search] if spec.search else None,
                   needs=spec.needs, monitor_input=spec.monitor_input,
                   fixed_params=spec.fixed_params)

    def unit_for(self, kind: str) -> str:
        """The unit of the value for sensors of ``kind``."""
        return self.unit.replace("{bias}", BIAS_UNITS[kind][0])

    def columns(self, data: KindData, sensor: int, params: Mapping[str, Any]) -> np.ndarray:
        """Regressor columns, shape (N, p), finite."""
        z = np.asarray(self.regressor(data, sensor, params), float)
        if z.ndim == 1:
            z = z[:, None]
        if z.shape[0] != data.N or not np.all(np.isfinite(z)):
            raise ConfigError(f"effect {self.name!r}: regressor must be finite with one row "
                              f"per sample ({data.N}), got shape {z.shape}")
        return z


_REGISTRY: dict[str, Candidate] = {}
"""Candidates that are not effect specs, by name (one named as a spec stands in its place)."""
_FROM_SPEC: dict[str, tuple[EffectSpec, Candidate]] = {}
_LOADED_ENTRY_POINTS = False


def register_effect(candidate: Candidate | EffectSpec | None = None, /, **kw: Any
                    ) -> Candidate:
    """Add a candidate effect (or replace one of the same name).

    Either pass a :class:`Candidate`, an :class:`~fdi.effect_specs.EffectSpec` (registered
    in the one effect registry, so also for the simulator and the monitor,
    :func:`fdi.effect_specs.register_spec`) or the candidate's fields as keywords::

        register_effect(name="humidity", kinds=("gyro",), unit="deg/h per %",
                        meaning="bias proportional to humidity",
                        regressor=lambda d, i, p: DPH * humidity)
    """
    c = candidate if candidate is not None else Candidate(**kw)
    if isinstance(c, EffectSpec):
        _REGISTRY.pop(c.name, None)
        return _from_spec(register_spec(c))
    if not isinstance(c, Candidate):
        raise ConfigError(f"register_effect: expected a Candidate, got {type(c).__name__}")
    _REGISTRY[c.name] = c
    return c


def _from_spec(spec: EffectSpec) -> Candidate:
    """The candidate of a registered spec (made once per spec object)."""
    hit = _FROM_SPEC.get(spec.name)
    if hit is None or hit[0] is not spec:
        hit = _FROM_SPEC[spec.name] = (spec, Candidate.from_spec(spec))
    return hit[1]


def _load_entry_points() -> None:
    """The entry-point group, read strictly through the effect registry (a broken plug-in
    is named): its specs are registered there, its candidates here."""
    global _LOADED_ENTRY_POINTS
    if _LOADED_ENTRY_POINTS:
        return
    _LOADED_ENTRY_POINTS = True
    for c in load_entry_points(strict=True):
        register_effect(c)


def _all() -> dict[str, Candidate]:
    """Every candidate by name: the registry's specs (built-in first, then users'), then
    the candidates that are not specs."""
    _load_entry_points()
    out = {sp.name: _REGISTRY.get(sp.name) or _from_spec(sp) for sp in effect_specs()}
    for name, c in _REGISTRY.items():
        out.setdefault(name, c)
    return out


def candidates(kind: str | None = None) -> list[Candidate]:
    """Registered candidates (built-in first, then users'), optionally for one kind."""
    return [c for c in _all().values() if kind is None or kind in c.kinds]


def get_candidate(name: str) -> Candidate:
    """The candidate of that name.

    Raises
    ------
    ConfigError
        Unknown name (the message lists the known ones).
    """
    known = _all()
    try:
        return known[name]
    except KeyError:
        raise ConfigError(f"unknown effect {name!r}; expected one of "
                          f"{', '.join(known)}") from None


# -- searches for effects with an unknown parameter -------------------------------------
CHANGE_POINT_GRID = 200
"""Positions tried for a bias step (equally spaced), plus every step boundary."""
LINE_MIN_CYCLES = 4.0
"""Lowest frequency a periodic line is searched at, in cycles per session."""


def change_point_scan(e: np.ndarray, Q: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Sum of squares explained by ``1[k ≥ idx]`` added to the basis ``Q``, for each idx.

    ``e`` (N,) orthogonal to the columns of ``Q`` (N, k, orthonormal).
    """
    se = np.cumsum(e[::-1])[::-1]                       # suffix sums
    sq = np.cumsum(Q[::-1], axis=0)[::-1]
    num = se[idx] ** 2
    den = (e.size - idx) - np.sum(sq[idx] ** 2, axis=1)
    return np.where(den > 1e-9 * e.size, num / np.maximum(den, 1e-300), 0.0)


def step_range(n_samples: int) -> tuple[int, int]:
    """First and last sample index a bias step is searched at (1 % of the session, at
    least 10 samples, kept off each end)."""
    margin = max(int(0.01 * n_samples), 10)
    return margin, n_samples - margin


def step_grid(data: KindData) -> np.ndarray:
    """Sample indices a bias step is scanned at, shape (M,): :data:`CHANGE_POINT_GRID`
    equally spaced ones and every step boundary, inside :func:`step_range`. Its size is the
    scan's multiplicity (:func:`step_search`, and the detectability check of
    :mod:`.detect`)."""
    lo, hi = step_range(data.N)
    grid = np.unique(np.r_[np.linspace(lo, hi, CHANGE_POINT_GRID).astype(int),
                           np.flatnonzero(np.diff(data.step)) + 1])
    return grid[(grid >= lo) & (grid <= hi)]


def step_search(data: KindData, sensor: int, Q: np.ndarray,
                 e: np.ndarray) -> tuple[dict[str, Any], int]:
    """The time of the best bias step for ``e``; multiplicity: the grid scanned
    (:func:`step_grid`)."""
    N = data.N
    lo, hi = step_range(N)
    grid = step_grid(data)
    k = grid[int(np.argmax(change_point_scan(e, Q, grid)))]
    # refine inside the grid cell (estimation only; the test counts the grid)
    cell = max(N // CHANGE_POINT_GRID, 1)
    fine = np.arange(max(lo, k - cell), min(hi, k + cell) + 1)
    k = int(fine[int(np.argmax(change_point_scan(e, Q, fine)))])
    return {"time_s": float(data.t[k])}, int(grid.size)


def line_search(data: KindData, sensor: int, Q: np.ndarray,
                 e: np.ndarray) -> tuple[dict[str, Any], int]:
    """The frequency of the periodogram peak of ``e`` above :data:`LINE_MIN_CYCLES` per
    session; multiplicity: the Fourier frequencies scanned."""
    N = data.N
    fs = data.sample_rate_hz
    spec = np.abs(np.fft.rfft(e)) ** 2
    k0 = math.ceil(LINE_MIN_CYCLES)
    kk = np.arange(k0, spec.size - 1)
    k = int(kk[int(np.argmax(spec[kk]))])
    # a peak that could not pass any test (chi^2(2) tail of the periodogram ordinate,
    # Bonferroni over the grid, above 1 %) is not worth refining
    var = float(e @ e) / N
    if var <= 0 or kk.size * np.exp(-spec[k] / (N * var)) > 0.01:
        return {"frequency_hz": k * fs / N}, int(kk.size)
    # refine: the frequency whose sinusoid (projected off the model) explains most of e,
    # within one Fourier bin of the peak (estimation only; the test counts the Fourier grid)
    def neg_ss(f: float) -> float:
        ph = 2 * np.pi * f * data.t
        z = np.column_stack([np.cos(ph), np.sin(ph)])
        z -= Q @ (Q.T @ z)
        g = z.T @ z
        ze = z.T @ e
        try:
            return -float(ze @ np.linalg.solve(g, ze))
        except np.linalg.LinAlgError:
            return 0.0

    res = scipy.optimize.minimize_scalar(neg_ss, bounds=((k - 1) * fs / N, (k + 1) * fs / N),
                                         method="bounded",
                                         options={"xatol": 1e-4 * fs / N})
    fbest = float(res.x) if res.fun <= neg_ss(k * fs / N) else k * fs / N
    return {"frequency_hz": fbest}, int(kk.size)


def mount_search(data: KindData, sensor: int, Q: np.ndarray,
                 e: np.ndarray) -> tuple[dict[str, Any], int]:
    """The mounting (after the first) whose axis tilt explains most of ``e``."""
    regressor = next(s.regressor for s in effect_specs() if s.search == "mount")
    best, arg = -1.0, 1
    for m in range(1, int(data.mount.max()) + 1):
        z = regressor(data, sensor, {"mount": m})
        z = z - Q @ (Q.T @ z)
        g = z.T @ z
        if np.linalg.cond(g) > 1e12:
            continue
        ss = float(e @ z @ np.linalg.solve(g, z.T @ e))
        if ss > best:
            best, arg = ss, m
    return {"mount": arg}, int(data.mount.max())


SEARCHES: dict[str, Callable[..., tuple[dict[str, Any], int]]] = {
    "time_s": step_search, "frequency_hz": line_search, "mount": mount_search}
"""The search of each parameter a built-in spec searches (``EffectSpec.search``)."""


def effect_searching(parameter: str) -> str:
    """Name of the built-in effect whose unknown parameter is searched as ``parameter`` (a
    key of :data:`SEARCHES`: ``"time_s"`` the step, ``"frequency_hz"`` the line), so that
    probes tied to one effect name it without writing it."""
    for spec in effect_specs():
        if spec.search == parameter:
            return spec.name
    raise KeyError(f"no effect searches {parameter!r}")


def testable(c: Candidate, data: KindData) -> str | None:
    """None when ``c`` can be tested on ``data``, else the reason."""
    if data.kind not in c.kinds:
        return f"applies to {' and '.join(c.kinds)} only"
    return c.needs(data)



def model_effects(datas: Mapping[str, KindData], effects: Any) -> dict[str, KindData]:
    """``datas`` with the residual of the extended model: every effect term of a
    calibration (:class:`fdi.calfile.EffectTerm`) subtracted from ``y``.

    Raises
    ------
    ConfigError
        A term names an effect that is not registered (a user effect whose plug-in is not
        installed).
    """
    import dataclasses

    out = dict(datas)
    for t in effects:
        if t.kind not in out:
            continue
        d = out[t.kind]
        c = get_candidate(t.name)
        Z = c.columns(d, t.sensor, t.params)
        beta = np.asarray(t.params.get("components", [t.estimate]), float)
        y = d.y.copy()
        y[:, t.sensor] -= Z @ beta[:Z.shape[1]]
        out[t.kind] = dataclasses.replace(d, y=y)
    return out
