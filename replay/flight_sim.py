"""Flight simulation: a manoeuvring vehicle seen through a true sensor model.

Simulation
----------
:func:`simulate_flight` (and :func:`iter_flight` for long flights, chunk by chunk) makes
the body rates of a manoeuvring vehicle (:mod:`replay.motion`, up to ``max_rate_dps`` on
each axis) and passes them through a *true* sensor model that differs from the
calibration the way real sensors do (seed 000 Eq. 13, seed 001 Eq. 1)::

    raw_i = (h_i·ω + b_i + f_i(t)) / SF_i + η_i / SF_i,   η ~ N(0, Σ)

- with a truth calibration (a calibration session's truth sidecar) its axes ``h_i``, scale
  factors ``SF_i`` and biases ``b_i`` are used as they are;
- otherwise they are drawn from the calibration file's own uncertainty: the gain-normalised
  axis ``h_i/SF_i`` errs by ``δ_i ~ N(0, input_error_cov_i)`` (in units of the calibrated
  gain), and the bias so that the calibrated output at rest is ``b̂_i + e_i``,
  ``e_i ~ N(0, bias_sd_i²)`` (:func:`draw_true_model`), so calibration error is present in
  every flight;
- ``Σ`` is the calibration's per-sample noise covariance (the truth's when it has one),
  scaled by ``fs/fs_cal`` when the flight's sample rate differs (white noise of the same
  density);
- the truth's extra *effects* (``calibration.effects``: g-sensitivity, ...) are not
  simulated in flight; their names are listed in the truth record
  (``"effects_not_simulated"``);
- optionally an in-run bias drift (first-order Gauss-Markov and/or random walk,
  ``bias_instability``/``random_walk``; streams ``default_rng([seed, 4, c])``), off by default;
- ``f_i(t)`` are the injected faults (:mod:`replay.faults`); ``stuck`` replaces the raw
  output, ``dropout`` clears ``valid`` (raw NaN).

The gyros sense ω, the total inertial rate of the body (Earth rate is not added separately).
Random streams are keyed on the seed and the absolute sample index, so a flight is the same
however it is chunked: true parameters from ``default_rng([seed, 1])``, the noise of
internal chunk c (:data:`CHUNK_SAMPLES` samples) from ``default_rng([seed, 2, c])``, the
motion as in :mod:`replay.motion`.

:func:`iter_flight` runs in named stages: :func:`plan_flight` (checks, true model, truth
record), then per chunk :func:`true_input` (motion through the true axes),
:func:`chunk_noise`, :func:`additive_faults`, the bias drift, :func:`raw_output`,
:func:`hold_stuck` and :func:`drop_samples`. The folder format is in :mod:`replay.flight_io`.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from fdi.calfile import Calibration
from fdi.effect_specs.builtin import BIAS_DRIFT
from fdi.errors import ConfigError
from replay.faults import Fault
from replay.flight_data import FLIGHT_TRUTH_SCHEMA, Flight, concat_flights
from replay.motion import body_rates

__all__ = [
    "CHUNK_SAMPLES",
    "FLIGHT_TRUTH_SCHEMA",
    "FlightPlan",
    "TrueModel",
    "additive_faults",
    "chunk_noise",
    "draw_true_model",
    "drop_samples",
    "hold_stuck",
    "iter_flight",
    "iter_planned",
    "plan_flight",
    "raw_output",
    "simulate_flight",
    "true_input",
    "true_model_from_calibration",
]

CHUNK_SAMPLES = 65536
"""Samples per internal simulation chunk (the noise stream is keyed on the chunk index)."""

_EPS_T = 1e-12
"""Tolerance (s) on fault window edges, so that ``t = k/fs`` at an onset is inside."""


@dataclass(frozen=True, eq=False)
class TrueModel:
    """The true sensor model a flight is simulated through.

    Attributes
    ----------
    axis : ndarray, shape (n, 3)
        True unit input axes.
    scale_factor : ndarray, shape (n,)
        True SF (SI input per raw unit).
    bias : ndarray, shape (n,)
        True bias (SI).
    noise_covariance : ndarray, shape (n, n)
        Per-sample noise covariance of the true input (SI²).
    source : str
        ``"truth"`` or ``"drawn from calibration covariance"``.
    """

    axis: np.ndarray
    scale_factor: np.ndarray
    bias: np.ndarray
    noise_covariance: np.ndarray
    source: str = ""

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary (SI)."""
        return {"axis": self.axis.tolist(), "scale_factor": self.scale_factor.tolist(),
                "bias": self.bias.tolist(), "noise_covariance": self.noise_covariance.tolist(),
                "units": {"scale_factor": "SI input per raw unit", "bias": "SI input",
                          "noise_covariance": "SI input^2 per sample"},
                "source": self.source}


def draw_true_model(cal: Calibration, seed: int, *, kind: str = "gyro") -> TrueModel:
    """True parameters drawn from the calibration's own uncertainty.

    ``h_i/SF_i = (ĥ_i + δ_i)/ŜF_i`` with ``δ_i ~ N(0, input_error_cov_i)`` (the
    gain-normalised error of the file's ``input_error_cov``), and the bias such that the
    raw offset at rest is the calibrated one up to the bias uncertainty:
    ``b_i/SF_i = (b̂_i + e_i)/ŜF_i``, ``e_i ~ N(0, bias_sd_i²)``.

    The calibration measured its bias on the output it calibrated (``ŜF·u`` at zero input,
    seed 000 Eq. 13), so a scale-factor error does not move the output at rest. Drawing the
    true bias around b̂ in input units instead would add ``(g − 1)·b̂`` (g the gain error)
    at rest: with a MEMS bias of 3 °/s and a datasheet scale-factor tolerance of 3 %, a
    0.09 °/s offset the calibration's ``bias_sd`` does not state.
    """
    s = cal.kind(kind)
    rng = np.random.default_rng([int(seed), 1])
    axes, sfs, bs = [], [], []
    for c in s.sensors:
        C = np.asarray(c.input_error_cov, float)
        delta = _sqrtm(C) @ rng.standard_normal(3)
        a = np.asarray(c.axis, float) + delta            # gain-normalised true axis
        g = float(np.linalg.norm(a))
        axes.append(a / g)
        sfs.append(c.scale_factor / g)                   # h·x/SF_true = a·x/SF_cal
        bs.append((c.bias + c.bias_sd * rng.standard_normal()) / g)
    return TrueModel(np.array(axes), np.array(sfs), np.array(bs),
                     np.array(s.noise_covariance, float), "drawn from calibration covariance")


def true_model_from_calibration(truth: Calibration | Sequence[Any], cal: Calibration, *,
                                kind: str = "gyro") -> TrueModel:
    """True parameters from a truth calibration (or the tuple ``load_truth`` returns).

    The noise covariance is the truth's when it is non-zero, else the calibration's.
    """
    tc = truth if isinstance(truth, Calibration) else truth[0]
    if not isinstance(tc, Calibration):
        raise ConfigError("truth must be a Calibration or (Calibration, effects, ...)")
    ts, cs = tc.kind(kind), cal.kind(kind)
    if ts.n != cs.n:
        raise ConfigError(f"truth has {ts.n} {kind} sensors, the calibration {cs.n}")
    noise = np.array(ts.noise_covariance, float)
    if noise.shape != (cs.n, cs.n) or not np.any(noise):
        noise = np.array(cs.noise_covariance, float)
    return TrueModel(ts.H.copy(), ts.scale_factors.copy(), ts.biases.copy(), noise, "truth")


def _sqrtm(C: np.ndarray) -> np.ndarray:
    """A square root L (L·Lᵀ = C) of a symmetric positive semi-definite matrix."""
    C = 0.5 * (np.asarray(C, float) + np.asarray(C, float).T)
    w, V = np.linalg.eigh(C)
    return V * np.sqrt(np.clip(w, 0.0, None))


def _check_faults(faults: Sequence[Fault], n: int) -> tuple[Fault, ...]:
    out = tuple(faults)
    for f in out:
        if not isinstance(f, Fault):
            raise ConfigError(f"faults must be replay.faults.Fault, got {type(f).__name__}")
        if not 1 <= f.sensor <= n:
            raise ConfigError(f"fault {f.spec or f.kind}: sensor {f.sensor} out of range 1..{n}")
    return out


@dataclass(frozen=True, eq=False)
class FlightPlan:
    """Everything a simulated flight needs before its first sample (stage 1).

    Attributes
    ----------
    seed : int
    fs : float
        Sample rate (Hz).
    samples : int
        N = round(duration·fs).
    model : TrueModel
        With the noise covariance scaled to ``fs``.
    noise_sqrt : ndarray, shape (n, n)
        L with L·Lᵀ = the per-sample noise covariance.
    faults : tuple of Fault
    onset_index : dict
        ``id(fault) → ceil(onset·fs)``, the first sample of each fault.
    gm_sd, rw_q : ndarray, shape (n,)
        Gauss-Markov bias sd and random-walk density per sensor (0: none).
    phi : float
        Gauss-Markov coefficient exp(−dt/τ).
    names : tuple of str
    raw_unit : str
    kind : str
    max_rate_dps : float
    truth_doc : dict
        The truth record every chunk carries.
    """

    seed: int
    fs: float
    samples: int
    model: TrueModel
    noise_sqrt: np.ndarray
    faults: tuple[Fault, ...]
    onset_index: dict[int, int]
    gm_sd: np.ndarray
    rw_q: np.ndarray
    phi: float
    names: tuple[str, ...]
    raw_unit: str
    kind: str
    max_rate_dps: float
    truth_doc: dict[str, Any] = field(default_factory=dict)

    @property
    def n(self) -> int:
        """Number of sensors."""
        return len(self.names)

    @property
    def drift(self) -> bool:
        """True when an in-run bias drift is simulated."""
        return bool(self.gm_sd.any() or self.rw_q.any())


@dataclass
class _CarryState:
    """What one chunk hands to the next: stuck values held, last raw row, drift states."""

    held: dict[int, float]
    last_raw: np.ndarray
    gm_state: np.ndarray
    rw_state: np.ndarray


def _positive(v: float, name: str) -> float:
    if not (math.isfinite(v) and v > 0):
        raise ConfigError(f"{name} must be positive, got {v}")
    return float(v)


def _truth_extras(truth: Calibration | Sequence[Any] | None, gm_sd: np.ndarray,
                  rw_q: np.ndarray, bias_correlation_s: float) -> dict[str, Any]:
    """Truth-record entries for effects left out and for a simulated bias drift."""
    out: dict[str, Any] = {}
    if truth is not None and not isinstance(truth, Calibration) and len(truth) > 1 \
            and truth[1]:
        out["effects_not_simulated"] = sorted(str(k) for k in truth[1])
    if gm_sd.any() or rw_q.any():
        out[BIAS_DRIFT] = {"bias_instability": gm_sd.tolist(),
                             "bias_correlation_s": float(bias_correlation_s),
                             "random_walk": rw_q.tolist(),
                             "units": "SI input; random walk per sqrt(s)"}
    return out


def plan_flight(cal: Calibration, duration_s: float, *, seed: int,
                faults: Sequence[Fault] = (), truth: Calibration | Sequence[Any] | None = None,
                sample_rate_hz: float | None = None, max_rate_dps: float = 300.0,
                kind: str = "gyro", bias_instability: float | Sequence[float] = 0.0,
                bias_correlation_s: float = 100.0,
                random_walk: float | Sequence[float] = 0.0) -> FlightPlan:
    """Stage 1: check the arguments, fix the true model and the truth record.

    Same arguments as :func:`simulate_flight`.
    """
    s = cal.kind(kind)
    n = s.n
    fs = _positive(float(sample_rate_hz or cal.sample_rate_hz), "sample rate")
    _positive(duration_s, "duration")
    faults = _check_faults(faults, n)
    gm_sd = _per_sensor(bias_instability, n, "bias_instability")
    rw_q = _per_sensor(random_walk, n, "random_walk")
    phi = (math.exp(-1.0 / (fs * _positive(bias_correlation_s, "bias_correlation_s")))
           if gm_sd.any() else 0.0)
    model = (true_model_from_calibration(truth, cal, kind=kind) if truth is not None
             else draw_true_model(cal, seed, kind=kind))
    if cal.sample_rate_hz > 0 and fs != cal.sample_rate_hz:
        # white noise of a fixed density: per-sample variance grows with the sample rate
        model = replace(model, noise_covariance=model.noise_covariance * (fs /
                                                                          cal.sample_rate_hz))
    N = round(duration_s * fs)
    truth_doc = _truth_doc(cal, model, faults, seed=seed, fs=fs, N=N,
                           max_rate_dps=max_rate_dps, kind=kind)
    truth_doc.update(_truth_extras(truth, gm_sd, rw_q, bias_correlation_s))
    return FlightPlan(seed=int(seed), fs=fs, samples=N, model=model,
                      noise_sqrt=_sqrtm(model.noise_covariance), faults=faults,
                      onset_index={id(f): math.ceil(f.onset * fs - 1e-9) for f in faults},
                      gm_sd=gm_sd, rw_q=rw_q, phi=phi,
                      names=tuple(c.name for c in s.sensors),
                      raw_unit=s.sensors[0].raw_unit if n else "raw", kind=kind,
                      max_rate_dps=float(max_rate_dps), truth_doc=truth_doc)


def true_input(plan: FlightPlan, k: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stage 2: times, true body rates and true sensor inputs of samples ``k``.

    Returns
    -------
    t : ndarray, shape (m,)
        ``k/fs`` (s).
    omega : ndarray, shape (m, 3)
        Body rates (rad/s), :func:`replay.motion.body_rates`.
    x : ndarray, shape (m, n)
        ``h_i·ω`` (SI input).
    """
    t = k / plan.fs
    omega = body_rates(t, seed=plan.seed, max_rate_dps=plan.max_rate_dps)
    return t, omega, omega @ plan.model.axis.T


def chunk_noise(plan: FlightPlan, chunk: int, m: int) -> np.ndarray:
    """Stage 3: the noise η of internal chunk ``chunk`` (m samples), shape (m, n), SI."""
    rng = np.random.default_rng([plan.seed, 2, chunk])
    return rng.standard_normal((m, plan.n)) @ plan.noise_sqrt.T


def _window(f: Fault, t: np.ndarray) -> np.ndarray:
    return (t >= f.onset - _EPS_T) & (t < f.end - _EPS_T)


def additive_faults(plan: FlightPlan, k: np.ndarray, t: np.ndarray, x: np.ndarray,
                    eta: np.ndarray) -> np.ndarray:
    """Stage 4: the faults that add to the input, shape (m, n), SI.

    ``step``/``spike`` add their size, ``ramp`` size·(t − onset), ``scale`` size·x;
    ``noise`` multiplies ``eta`` in place by its size.
    """
    add = np.zeros_like(x)
    for f in plan.faults:
        i = f.sensor - 1
        if f.kind == "spike" and f.duration is None:
            m = k == plan.onset_index[id(f)]
        else:
            m = _window(f, t)
        if not m.any():
            continue
        if f.kind in ("step", "spike"):
            add[m, i] += f.size
        elif f.kind == "ramp":
            add[m, i] += f.size * (t[m] - f.onset)
        elif f.kind == "scale":
            add[m, i] += f.size * x[m, i]
        elif f.kind == "noise":
            eta[m, i] *= f.size
    return add


def raw_output(plan: FlightPlan, x: np.ndarray, add: np.ndarray, eta: np.ndarray
               ) -> np.ndarray:
    """Stage 6: ``raw = (x + b + f + η) / SF`` (seed 000 Eq. 13), shape (m, n)."""
    return (x + plan.model.bias + add + eta) / plan.model.scale_factor


def hold_stuck(plan: FlightPlan, k0: int, t: np.ndarray, raw: np.ndarray,
               state: _CarryState) -> None:
    """Stage 7: a ``stuck`` sensor repeats its last output before the onset (in place)."""
    for f in plan.faults:
        if f.kind != "stuck":
            continue
        i = f.sensor - 1
        m = _window(f, t)
        if not m.any():
            continue
        if id(f) not in state.held:
            ko = plan.onset_index[id(f)]
            if ko == 0:
                state.held[id(f)] = float(raw[0, i])
            elif ko - 1 >= k0:
                state.held[id(f)] = float(raw[ko - 1 - k0, i])
            else:
                state.held[id(f)] = float(state.last_raw[i])
        raw[m, i] = state.held[id(f)]


def drop_samples(plan: FlightPlan, t: np.ndarray, raw: np.ndarray) -> np.ndarray:
    """Stage 8: ``dropout`` clears ``valid`` (raw NaN there, in place); returns ``valid``."""
    valid = np.ones(raw.shape, bool)
    for f in plan.faults:
        if f.kind == "dropout":
            valid[_window(f, t), f.sensor - 1] = False
    raw[~valid] = np.nan
    return valid


def iter_flight(cal: Calibration, duration_s: float, *, seed: int,
                faults: Sequence[Fault] = (), truth: Calibration | Sequence[Any] | None = None,
                sample_rate_hz: float | None = None, max_rate_dps: float = 300.0,
                kind: str = "gyro", bias_instability: float | Sequence[float] = 0.0,
                bias_correlation_s: float = 100.0,
                random_walk: float | Sequence[float] = 0.0) -> Iterator[Flight]:
    """Simulate a flight in chunks of :data:`CHUNK_SAMPLES` samples.

    Same arguments as :func:`simulate_flight`; yields consecutive :class:`Flight` pieces
    whose concatenation equals ``simulate_flight(...)``. Memory stays bounded for flights
    of many hours.
    """
    plan = plan_flight(cal, duration_s, seed=seed, faults=faults, truth=truth,
                       sample_rate_hz=sample_rate_hz, max_rate_dps=max_rate_dps, kind=kind,
                       bias_instability=bias_instability,
                       bias_correlation_s=bias_correlation_s, random_walk=random_walk)
    yield from iter_planned(plan)


def iter_planned(plan: FlightPlan) -> Iterator[Flight]:
    """Run a :class:`FlightPlan` chunk by chunk (stages 2-8), yielding Flight pieces."""
    n = plan.n
    state = _CarryState(held={}, last_raw=np.full(n, np.nan),
                        gm_state=plan.gm_sd * np.random.default_rng(
                            [plan.seed, 5]).standard_normal(n),      # stationary start
                        rw_state=np.zeros(n))
    for c, k0 in enumerate(range(0, plan.samples, CHUNK_SAMPLES)):
        k = np.arange(k0, min(plan.samples, k0 + CHUNK_SAMPLES))
        t, omega, x = true_input(plan, k)
        eta = chunk_noise(plan, c, k.shape[0])
        add = additive_faults(plan, k, t, x, eta)
        if plan.drift:                                       # stage 5
            d, state.gm_state, state.rw_state = _bias_drift(
                np.random.default_rng([plan.seed, 4, c]), k.shape[0], plan.gm_sd, plan.phi,
                state.gm_state, plan.rw_q, plan.fs, state.rw_state)
            add += d
        raw = raw_output(plan, x, add, eta)
        hold_stuck(plan, k0, t, raw, state)
        valid = drop_samples(plan, t, raw)
        state.last_raw = raw[-1].copy()
        yield Flight(t=t, raw=raw, valid=valid, sample_rate_hz=plan.fs,
                     sensor_names=plan.names, raw_unit=plan.raw_unit, omega_true=omega,
                     faults=plan.faults, truth=plan.truth_doc, source="<simulated>",
                     kind=plan.kind)


def _per_sensor(v: float | Sequence[float], n: int, name: str) -> np.ndarray:
    a = np.broadcast_to(np.asarray(v, float), (n,)).copy() if np.ndim(v) == 0 \
        else np.asarray(v, float)
    if a.shape != (n,) or not np.all(np.isfinite(a)) or np.any(a < 0):
        raise ConfigError(f"{name} must be one non-negative number or {n}, got {v!r}")
    return a


def _bias_drift(rng: np.random.Generator, m: int, gm_sd: np.ndarray, phi: float,
                gm_state: np.ndarray, rw_q: np.ndarray, fs: float, rw_state: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gauss-Markov bias + bias random walk of one chunk, shape (m, n), and the new states.

    ``b[k] = φ·b[k−1] + √(1−φ²)·σ·w`` (φ = exp(−dt/τ), stationary sd σ) and
    ``r[k] = r[k−1] + q·√dt·w'``.
    """
    from scipy.signal import lfilter

    n = gm_sd.shape[0]
    w = rng.standard_normal((m, 2 * n))
    out = np.zeros((m, n))
    if gm_sd.any():
        g = math.sqrt(1.0 - phi * phi)
        gm, _ = lfilter([1.0], [1.0, -phi], w[:, :n] * (g * gm_sd), axis=0,
                        zi=(phi * gm_state)[None, :])
        out += gm
        gm_state = gm[-1].copy()
    if rw_q.any():
        rw = rw_state + np.cumsum(w[:, n:] * (rw_q / math.sqrt(fs)), axis=0)
        out += rw
        rw_state = rw[-1].copy()
    return out, gm_state, rw_state


def _truth_doc(cal: Calibration, model: TrueModel, faults: Sequence[Fault], *, seed: int,
               fs: float, N: int, max_rate_dps: float, kind: str) -> dict[str, Any]:
    s = cal.kind(kind)
    return {"schema": FLIGHT_TRUTH_SCHEMA, "seed": int(seed), "kind": kind,
            "configuration": cal.configuration, "sample_rate_hz": fs, "samples": N,
            "max_rate_dps": float(max_rate_dps),
            "motion": "replay.motion: sin^2 rate pulses per 2-s segment and axis",
            "sigma": s.noise_sd.tolist(),
            "faults": [f.to_dict() for f in faults],
            "true_parameters": model.to_dict()}


def simulate_flight(cal: Calibration, duration_s: float, *, seed: int,
                    faults: Sequence[Fault] = (),
                    truth: Calibration | Sequence[Any] | None = None,
                    sample_rate_hz: float | None = None, max_rate_dps: float = 300.0,
                    kind: str = "gyro", bias_instability: float | Sequence[float] = 0.0,
                    bias_correlation_s: float = 100.0,
                    random_walk: float | Sequence[float] = 0.0) -> Flight:
    """Simulate a manoeuvring flight with calibration error and injected faults.

    Parameters
    ----------
    cal : Calibration
        The calibration the monitor will use.
    duration_s : float
        Flight length (s); ``round(duration_s·fs)`` samples at ``t = k/fs``.
    seed : int
    faults : sequence of Fault
    truth : Calibration or tuple, optional
        True sensor parameters (a session's truth sidecar, ``calibration.truth.load_truth``);
        drawn from the calibration's covariance when None.
    sample_rate_hz : float, optional
        Defaults to the calibration's rate.
    max_rate_dps : float
        Largest body rate on each axis (°/s).
    kind : str
    bias_instability : float or sequence of float
        Stationary sd of a first-order Gauss-Markov bias per sensor (SI input units);
        0 (default): none. In-run bias drift that the calibration does not know.
    bias_correlation_s : float
        Its correlation time (s).
    random_walk : float or sequence of float
        Bias random walk density per sensor (SI per √s); 0: none.

    Returns
    -------
    Flight
        With ``omega_true``, ``faults`` and ``truth`` filled in.
    """
    return concat_flights(list(iter_flight(cal, duration_s, seed=seed, faults=faults,
                                           truth=truth, sample_rate_hz=sample_rate_hz,
                                           max_rate_dps=max_rate_dps, kind=kind,
                                           bias_instability=bias_instability,
                                           bias_correlation_s=bias_correlation_s,
                                           random_walk=random_walk)))
