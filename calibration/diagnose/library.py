"""The candidate effects ``rimu diagnose`` tries: regressor, meaning, unit, inputs needed.

Each candidate turns the session (:class:`calibration.diagnose.context.KindData`) into
regressor columns ``Z`` for one sensor, scaled so that the sensor's SI output gains
``Z @ β`` when the effect's value is ``β`` in the candidate's unit. The diagnosis tests
``Z`` as a nested-model extension of the calibration model (:mod:`.selection`).

Built-in candidates (the simulator's knob names where they match,
:mod:`calibration.effects`)::

    g_sensitivity       gyro   deg/h per g     k·(h̃·f)/g0
    scale_asymmetry     gyro   fraction        (a/2)·|s|
    scale_nonlinearity  gyro   fraction        k·s²/w          (w the table rate)
    warmup              gyro   deg/h           A·exp(−t/300 s)
    time_skew           both   s               −τ·h̃·ẋ          (input sampled τ late)
    bias_drift          gyro   deg/h           D·t/T           (T the session length)
    no_earth_rate       gyro   fraction        −e·h̃·ω_earth    (1: Earth rate absent)
    temperature         both   deg/h or mg /°C k·(T − T̄)       (needs a temperature column)
    bias_step           both   deg/h or mg     c·[t ≥ t₀]      (t₀ searched)
    periodic_line       both   deg/h or mg     A·cos(2πf·t+φ)  (f searched)
    misalignment        both   mrad            δ·(E·x)         (E ⟂ h̃, two angles)

``s = h̃·x`` is the input along the calibrated axis. Users add candidates with
:func:`register_effect` or through the entry-point group ``rimu.effects`` (each entry
point names a :class:`Candidate` or a callable returning one or a list); see
``docs/diagnose.md``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from importlib import metadata
from typing import Any

import numpy as np
import scipy.optimize

from calibration.diagnose.context import KindData
from calibration.effects import WARMUP_TAU_S
from fdi.calfile import tangent_basis
from fdi.errors import ConfigError
from fdi.units import DPH, DPS, G0, MG

__all__ = [
    "BIAS_UNITS",
    "CHANGE_POINT_GRID",
    "ENTRY_POINT_GROUP",
    "LINE_MIN_CYCLES",
    "OUTSIDE_ALIASES",
    "Candidate",
    "candidates",
    "change_point_scan",
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

ENTRY_POINT_GROUP = "rimu.effects"
OUTSIDE_ALIASES = {
    "g_sensitivity": "a bias that follows the table's orientation for another reason (a "
                     "magnetic or thermal gradient)",
    "scale_asymmetry": "a dead zone or any other gain change even in the rate",
    "scale_nonlinearity": "a gain that varies with |rate| in another law (at one table "
                          "rate any such law looks the same)",
    "warmup": "any early transient of another time constant, or a curved drift",
    "time_skew": "a low-pass lag (sensor bandwidth) at the table's accelerations",
    "bias_drift": "a curved or late-starting drift, a slow wander (measured: a quadratic "
                  "drift from 40 % of the session, absorbed with warmup; the held-out "
                  "check refuses that refit)",
    "no_earth_rate": "a bias that depends on the heading or the table position",
    "temperature": "any slow drift that correlates with the temperature profile "
                   "(warm-up, time)",
    "bias_step": "a fast ramp, several steps, or a transient that does not recover",
    "periodic_line": "a line whose amplitude or frequency varies, or a non-sinusoidal "
                     "periodic signal (measured: a line whose amplitude grows 7-fold, "
                     "which the held-out check does not see)",
    "misalignment": "a bias or gain that changes with the mounting",
}
"""Effects outside the library that each built-in candidate can absorb when it is fitted
(printed with each effect found; ``tests/calibration/test_closure_injected.py`` measured
the two marked). The calibration's own terms alias too: a bias that follows the rate sign
is mostly a scale factor on a sequence of one table rate."""
BIAS_UNITS = {"gyro": ("deg/h", DPH), "accel": ("mg", MG)}
"""Display unit and its SI factor of bias-like effects, per kind."""

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
_LOADED_ENTRY_POINTS = False


def register_effect(candidate: Candidate | None = None, /, **kw: Any) -> Candidate:
    """Add a candidate effect (or replace one of the same name).

    Either pass a :class:`Candidate` or its fields as keywords::

        register_effect(name="humidity", kinds=("gyro",), unit="deg/h per %",
                        meaning="bias proportional to humidity",
                        regressor=lambda d, i, p: DPH * humidity)
    """
    c = candidate if candidate is not None else Candidate(**kw)
    if not isinstance(c, Candidate):
        raise ConfigError(f"register_effect: expected a Candidate, got {type(c).__name__}")
    _REGISTRY[c.name] = c
    return c


def _load_entry_points() -> None:
    global _LOADED_ENTRY_POINTS
    if _LOADED_ENTRY_POINTS:
        return
    _LOADED_ENTRY_POINTS = True
    for ep in metadata.entry_points(group=ENTRY_POINT_GROUP):
        try:
            obj = ep.load()
        except Exception as exc:  # a broken plug-in must name itself
            raise ConfigError(f"entry point {ep.name!r} of group {ENTRY_POINT_GROUP}: cannot "
                              f"load {ep.value} ({exc})") from None
        if callable(obj) and not isinstance(obj, Candidate):
            obj = obj()
        for c in (obj if isinstance(obj, list | tuple) else [obj]):
            register_effect(c)


def candidates(kind: str | None = None) -> list[Candidate]:
    """Registered candidates (built-in first, then users'), optionally for one kind."""
    _load_entry_points()
    return [c for c in _REGISTRY.values() if kind is None or kind in c.kinds]


def get_candidate(name: str) -> Candidate:
    """The candidate of that name.

    Raises
    ------
    ConfigError
        Unknown name (the message lists the known ones).
    """
    _load_entry_points()
    try:
        return _REGISTRY[name]
    except KeyError:
        raise ConfigError(f"unknown effect {name!r}; expected one of "
                          f"{', '.join(_REGISTRY)}") from None


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


# -- built-in regressors -------------------------------------------------------------------
def _bias_si(d: KindData) -> float:
    return BIAS_UNITS[d.kind][1]


def _needs_rates(d: KindData) -> str | None:
    return None if d.table_rate > 0 else "the session has no rate steps"


def _needs_temperature(d: KindData) -> str | None:
    if d.temperature is None:
        return ("the session has no temperature column (add temp_degC, or "
                "temp_degC.<sensor>, to samples.csv)")
    return None


def _needs_force_change(d: KindData) -> str | None:
    f = d.force
    return None if np.ptp(f, axis=0).max() > 0.1 * G0 else \
        "the specific force does not change direction during the session"


def _needs_motion(d: KindData) -> str | None:
    return None if np.max(np.abs(d.x_dot)) > 0 else "the input never changes within a step"


def _line(d: KindData, i: int, p: Mapping[str, Any]) -> np.ndarray:
    ph = 2 * np.pi * float(p["frequency_hz"]) * d.t
    return _bias_si(d) * np.column_stack([np.cos(ph), np.sin(ph)])


def _misalignment(d: KindData, i: int, p: Mapping[str, Any]) -> np.ndarray:
    m = d.mount == int(p["mount"])
    return 1e-3 * (d.x @ tangent_basis(d.H[i]).T) * m[:, None]


def _needs_mounts(d: KindData) -> str | None:
    return None if d.mount.max() > 0 else "the session uses one mounting only"


def mount_search(data: KindData, sensor: int, Q: np.ndarray,
                 e: np.ndarray) -> tuple[dict[str, Any], int]:
    """The mounting (after the first) whose axis tilt explains most of ``e``."""
    best, arg = -1.0, 1
    for m in range(1, int(data.mount.max()) + 1):
        z = _misalignment(data, sensor, {"mount": m})
        z = z - Q @ (Q.T @ z)
        g = z.T @ z
        if np.linalg.cond(g) > 1e12:
            continue
        ss = float(e @ z @ np.linalg.solve(g, z.T @ e))
        if ss > best:
            best, arg = ss, m
    return {"mount": arg}, int(data.mount.max())


_BUILTIN = (
    Candidate("g_sensitivity", ("gyro",), "gyro bias proportional to the specific force "
              "along the sensor axis", "deg/h per g",
              lambda d, i, p: DPH * (d.force @ d.H[i]) / G0, ("specific_force",),
              needs=_needs_force_change, monitor_input="specific force (accelerometers)"),
    Candidate("scale_asymmetry", ("gyro",), "gain differs for positive and negative inputs "
              "(1 ± a/2)", "fraction", lambda d, i, p: 0.5 * np.abs(d.s[:, i]),
              ("rate_sign",), needs=_needs_rates, monitor_input="rate sign"),
    Candidate("scale_nonlinearity", ("gyro",), "quadratic scale-factor term, k·s²/w (k·w at "
              "the table rate w)", "fraction",
              lambda d, i, p: d.s[:, i] ** 2 / max(d.table_rate, 1e-300), ("table_rate",),
              needs=_needs_rates, monitor_input="rate squared",
              fixed_params=lambda d, i: {"table_rate_dps": d.table_rate / DPS}),
    Candidate("warmup", ("gyro",), f"bias transient after switch-on, A·exp(-t/{WARMUP_TAU_S:g}"
              " s)", "deg/h", lambda d, i, p: DPH * np.exp(-d.t / WARMUP_TAU_S), ("time",),
              monitor_input="time since switch-on"),
    Candidate("time_skew", ("gyro", "accel"), "the sensor samples its input tau late",
              "s", lambda d, i, p: -(d.x_dot @ d.H[i]), ("table_motion",),
              needs=_needs_motion, monitor_input=None),
    Candidate("bias_drift", ("gyro",), "bias drifts linearly by D over the session",
              "deg/h", lambda d, i, p: DPH * d.t / d.duration_s, ("time",)),
    Candidate("no_earth_rate", ("gyro",), "the Earth rate is missing from the output (1) or "
              "scaled wrongly (fraction missing)", "fraction",
              lambda d, i, p: -(d.earth @ d.H[i]), ("latitude",)),
    Candidate("temperature", ("gyro", "accel"), "bias proportional to the temperature, "
              "k·(T − T_ref), T_ref the session mean", "{bias} per degC",
              lambda d, i, p: _bias_si(d) * (d.temperature[:, i]
                                            - float(p.get("reference_degC", 0.0))),
              ("temperature",), needs=_needs_temperature,
              monitor_input="temperature in the stream",
              fixed_params=lambda d, i: {"reference_degC": temperature_reference(d, i)}),
    Candidate("bias_step", ("gyro", "accel"), "bias jumps by c at an unknown time t0",
              "{bias}", lambda d, i, p: _bias_si(d) * (d.t >= float(p["time_s"])),
              ("time",), search=step_search),
    Candidate("periodic_line", ("gyro", "accel"), "sinusoid of amplitude A at an unknown "
              "frequency f", "{bias}", _line, ("time",), search=line_search),
    Candidate("misalignment", ("gyro", "accel"), "input axis tilted by two small angles in "
              "the steps of one mounting (re-mounting error; the first mounting is the "
              "reference)", "mrad", _misalignment, ("mounting",), search=mount_search,
              needs=_needs_mounts),
)
for _c in _BUILTIN:
    register_effect(_c)


def temperature_reference(data: KindData, sensor: int) -> float:
    """The reference temperature of the ``temperature`` effect (session mean, °C)."""
    return float(np.mean(data.temperature[:, sensor])) if data.temperature is not None \
        else 0.0


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
