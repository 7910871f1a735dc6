"""A simulated flight of several three-axis IMUs on one airframe, with a truth record.

Every IMU ``j`` (``imu1`` … ``imuK``) sees the same body motion through its own true
model; its gyro output (rad/s, already in engineering units as a flight log stores it) is::

    u_j(t) = G_j·ω(t + τ_j) + b_j + g_j·f(t + τ_j) + w_j·exp(−t/t_w) + k_j·(T_j(t) − T₀)
             + a_j·sin(2π f_v t + φ_j) + d_j(t) + η_j(t)

- ``G_j = diag(1 + s_j)·(I + N_j)·R(θ_j)``: scale errors ``s_j``, symmetric
  non-orthogonality ``N_j`` (zero diagonal), misalignment rotation ``θ_j`` (small-angle
  vector, rad), all drawn per IMU;
- ``b_j`` bias; ``τ_j`` the IMU's time offset (its samples are stamped ``t`` but measure
  the motion at ``t + τ_j``);
- the *undeclared effects* (off by default; what an in-flight calibration does not model
  and ``rimu diagnose`` should find): g-sensitivity ``g_j`` (3×3, rad/s per m/s²) times the
  specific force ``f``; a warm-up transient ``w_j`` decaying with ``t_w``; a temperature
  coefficient ``k_j`` (rad/s per °C) on a logged temperature ``T_j(t)`` that rises by
  ``ΔT`` with time constant ``t_T``; a vibration line of frequency ``f_v`` (aliased when
  above Nyquist, as a sampled sensor does) and amplitude ``a_j`` per axis; a bias random
  walk ``d_j``; broadband vibration in bursts: an envelope ``v(t)`` in [0, 1] (smoothed
  random, :data:`VIBRATION_CORR_S`) scales white noise of sd ``vibration_accel`` on every
  accelerometer and of sd ``vibration_noise`` on the gyros of the IMUs with effects (the
  gyro residual power then follows the accelerometers' vibration level);
- ``η_j`` white noise, sd ``noise_sd`` per sample.

Specific force: ``f = Rᵀ·(0, 0, g) + a_lin``, ``R`` the attitude integrated from the true
rates, ``a_lin`` a smooth random linear acceleration; each IMU's accelerometers record
``f(t + τ_j) + noise`` beside its gyros (aux channels ``accel:imuj.x``), and its
temperature ``T_j`` when the temperature effect is on.

Random streams: ``default_rng([seed, 11, j])`` for IMU j's parameters, ``[seed, 12, j]``
for its noise, ``[seed, 13]`` for the linear acceleration; motion from
:func:`replay.motion.body_rates` (the same seed).

The truth record (``rimu.flight-truth/1``) holds every drawn parameter and, under
``"relative_to_reference"``, what an in-flight calibration against the reference IMU should
recover: ``A_j = G_j·G_ref⁻¹``, ``c_j = b_j − A_j·b_ref`` and ``τ_j − τ_ref``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from fdi.effect_specs.builtin import G_SENSITIVITY
from fdi.errors import ConfigError
from fdi.units import G0
from replay.flight_data import FLIGHT_TRUTH_SCHEMA, AuxChannels, Flight
from replay.motion import body_rates

__all__ = ["IMU_SET_MODEL", "ImuEffects", "ImuSetSpec", "attitude_gravity", "simulate_imu_set",
           "skew"]

IMU_SET_MODEL = "replay.imu_set/1"
"""Name of the sensor model in the truth record."""

_AXES = ("x", "y", "z")
VIBRATION_CORR_S = 5.0
"""Correlation time (s) of the vibration envelope."""


@dataclass(frozen=True)
class ImuEffects:
    """Undeclared-effect knobs (all off by default), SI.

    Attributes
    ----------
    g_sensitivity : float
        Sd of each entry of the per-IMU g-sensitivity matrix (rad/s per m/s²).
    warm_up : float
        Sd of the per-axis warm-up bias at t = 0 (rad/s).
    warm_up_s : float
        Its decay time constant (s).
    temperature_coeff : float
        Sd of the per-axis bias temperature coefficient (rad/s per °C).
    temperature_rise_c, temperature_tau_s : float
        The logged temperature rises by this much (°C) with this time constant (s).
    vibration_hz : float
        Frequency of a vibration line (Hz; aliased by the sampling when above Nyquist).
    vibration : float
        Sd of its per-axis amplitude (rad/s).
    random_walk : float
        Bias random walk density (rad/s per √s).
    vibration_noise : float
        Gyro noise sd (rad/s) added at full vibration (envelope 1).
    vibration_accel : float
        Accelerometer noise sd (m/s²) at full vibration.
    imus : tuple of int
        1-based IMUs that carry the effects (empty: all).
    """

    g_sensitivity: float = 0.0
    warm_up: float = 0.0
    warm_up_s: float = 60.0
    temperature_coeff: float = 0.0
    temperature_rise_c: float = 15.0
    temperature_tau_s: float = 120.0
    vibration_hz: float = 0.0
    vibration: float = 0.0
    random_walk: float = 0.0
    vibration_noise: float = 0.0
    vibration_accel: float = 5.0
    imus: tuple[int, ...] = ()

    def on(self, j: int) -> bool:
        """True when IMU ``j`` (1-based) carries the effects."""
        return not self.imus or j in self.imus


@dataclass(frozen=True)
class ImuSetSpec:
    """What to simulate.

    Attributes
    ----------
    imus : int
        Number K of three-axis IMUs (≥ 2).
    duration_s, sample_rate_hz : float
    seed : int
    time_offset_s : tuple of float
        Per IMU (K values, or empty: none).
    timing_jitter_s : tuple of float
        Per IMU the sd of a random sampling-time error, independent per sample (K values,
        or empty: none): IMU j samples the motion at ``t + τ_j + δt``, δt ~ N(0, σ_j²).
    misalignment_sd : float
        Sd of each misalignment angle (rad).
    nonorthogonality_sd : float
        Sd of each non-orthogonality term (rad).
    scale_sd : float
        Sd of each scale error (fraction).
    bias_sd : float
        Sd of each bias (rad/s).
    noise_sd : float
        Gyro white noise per sample (rad/s).
    noise_scale : tuple of float
        Per IMU factor on ``noise_sd`` (K values, or empty: all 1).
    accel_noise_sd : float
        Accelerometer white noise per sample (m/s²).
    max_rate_dps : float
        Largest body rate per axis (°/s).
    linear_accel : float
        Sd of the smooth linear acceleration (m/s²).
    effects : ImuEffects
    """

    imus: int = 2
    duration_s: float = 60.0
    sample_rate_hz: float = 50.0
    seed: int = 0
    time_offset_s: tuple[float, ...] = ()
    timing_jitter_s: tuple[float, ...] = ()
    misalignment_sd: float = 10e-3
    nonorthogonality_sd: float = 1e-3
    scale_sd: float = 5e-3
    bias_sd: float = 0.01
    noise_sd: float = 2e-3
    noise_scale: tuple[float, ...] = ()
    accel_noise_sd: float = 0.05
    max_rate_dps: float = 200.0
    linear_accel: float = 1.0
    effects: ImuEffects = field(default_factory=ImuEffects)

    def check(self) -> None:
        """Raise ConfigError naming the first bad field."""
        if self.imus < 2:
            raise ConfigError(f"--imus must be at least 2, got {self.imus}")
        for name in ("duration_s", "sample_rate_hz"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"{name} must be positive, got {v}")
        self._check_per_imu()
        for name in ("misalignment_sd", "nonorthogonality_sd", "scale_sd", "bias_sd",
                     "noise_sd", "accel_noise_sd", "linear_accel"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ConfigError(f"{name} must be a non-negative number, got {v}")
        if any(not 1 <= j <= self.imus for j in self.effects.imus):
            raise ConfigError(f"effect IMUs {self.effects.imus} out of range 1..{self.imus}")

    def _check_per_imu(self) -> None:
        """The per-IMU tuples: one value per IMU (or none), finite, scales and jitter ≥ 0."""
        if self.time_offset_s and len(self.time_offset_s) != self.imus:
            raise ConfigError(f"time offsets: {len(self.time_offset_s)} values for "
                              f"{self.imus} IMUs (give one per IMU)")
        if self.noise_scale and not _per_imu_ok(self.noise_scale, self.imus):
            raise ConfigError(f"noise_scale: expected {self.imus} non-negative numbers, got "
                              f"{self.noise_scale}")
        if self.timing_jitter_s and not _per_imu_ok(self.timing_jitter_s, self.imus):
            raise ConfigError(f"timing jitter: expected {self.imus} finite values ≥ 0, got "
                              f"{self.timing_jitter_s}")
        if not all(math.isfinite(x) for x in self.time_offset_s):
            raise ConfigError(f"time offsets must be finite, got {self.time_offset_s}")


def _per_imu_ok(values: tuple[float, ...], imus: int) -> bool:
    """One finite value ≥ 0 per IMU."""
    return len(values) == imus and all(math.isfinite(x) and x >= 0 for x in values)


def skew(v: np.ndarray) -> np.ndarray:
    """The cross-product matrix [v]× of a 3-vector."""
    x, y, z = np.asarray(v, float)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def attitude_gravity(t: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """Gravity reaction ``Rᵀ·(0, 0, g)`` in the body frame along the flight, shape (N, 3)."""
    dt = np.diff(t, prepend=t[0])
    q = Rotation.from_rotvec(omega * dt[:, None]).as_quat()
    step = 1
    while step < q.shape[0]:             # prefix product R_k = R_{k-1}·exp(ω dt) (scan)
        q[step:] = (Rotation.from_quat(q[:-step]) * Rotation.from_quat(q[step:])).as_quat()
        step *= 2
    return Rotation.from_quat(q).inv().apply(np.array([0.0, 0.0, G0]))


def _smooth_noise(rng: np.random.Generator, n: int, fs: float, sd: float,
                  corr_s: float = 1.0) -> np.ndarray:
    """First-order low-passed Gaussian noise, shape (n, 3), stationary sd ``sd``."""
    from scipy.signal import lfilter

    if sd == 0 or n == 0:
        return np.zeros((n, 3))
    phi = math.exp(-1.0 / (fs * corr_s))
    w = rng.standard_normal((n, 3)) * sd * math.sqrt(1 - phi * phi)
    out, _ = lfilter([1.0], [1.0, -phi], w, axis=0, zi=np.full((1, 3), 0.0))
    return out


@dataclass(frozen=True)
class _Imu:
    """Drawn parameters of one IMU."""

    G: np.ndarray
    theta: np.ndarray
    nonorth: np.ndarray
    scale: np.ndarray
    bias: np.ndarray
    tau: float
    gsens: np.ndarray
    warm: np.ndarray
    tcoef: np.ndarray
    vib_amp: np.ndarray
    vib_phase: np.ndarray

    def to_dict(self) -> dict[str, Any]:
        return {"gain_matrix": self.G.tolist(), "misalignment_rad": self.theta.tolist(),
                "nonorthogonality_rad": self.nonorth.tolist(),
                "scale_error": self.scale.tolist(), "bias": self.bias.tolist(),
                "time_offset_s": self.tau, G_SENSITIVITY: self.gsens.tolist(),
                "warm_up": self.warm.tolist(), "temperature_coeff": self.tcoef.tolist(),
                "vibration_amplitude": self.vib_amp.tolist(),
                "vibration_phase_rad": self.vib_phase.tolist()}


def _draw_imu(spec: ImuSetSpec, j: int) -> _Imu:
    rng = np.random.default_rng([int(spec.seed), 11, j])
    theta = spec.misalignment_sd * rng.standard_normal(3)
    no = spec.nonorthogonality_sd * rng.standard_normal(3)
    N = np.array([[0.0, no[0], no[1]], [no[0], 0.0, no[2]], [no[1], no[2], 0.0]])
    s = spec.scale_sd * rng.standard_normal(3)
    G = np.diag(1.0 + s) @ (np.eye(3) + N) @ Rotation.from_rotvec(theta).as_matrix()
    b = spec.bias_sd * rng.standard_normal(3)
    e = spec.effects
    on = 1.0 if e.on(j) else 0.0
    er = np.random.default_rng([int(spec.seed), 14, j])     # effects: own stream
    return _Imu(G=G, theta=theta, nonorth=no, scale=s, bias=b,
                tau=float(spec.time_offset_s[j - 1]) if spec.time_offset_s else 0.0,
                gsens=on * e.g_sensitivity * er.standard_normal((3, 3)),
                warm=on * e.warm_up * er.standard_normal(3),
                tcoef=on * e.temperature_coeff * er.standard_normal(3),
                vib_amp=on * e.vibration * er.standard_normal(3),
                vib_phase=er.uniform(0, 2 * math.pi, 3))


def simulate_imu_set(spec: ImuSetSpec) -> Flight:
    """Simulate ``spec.imus`` three-axis IMUs in one flight.

    Parameters
    ----------
    spec : ImuSetSpec

    Returns
    -------
    Flight
        ``kind="gyro"``, sensors ``imu1.x … imuK.z`` (raw unit rad/s), IMU groups, aux
        channels (accelerometers, and temperatures when that effect is on), the true rates
        and the truth record (module docstring).
    """
    spec.check()
    fs = float(spec.sample_rate_hz)
    N = round(spec.duration_s * fs)
    t = np.arange(N) / fs
    K = spec.imus
    imus = [_draw_imu(spec, j) for j in range(1, K + 1)]
    omega = body_rates(t, seed=spec.seed, max_rate_dps=spec.max_rate_dps)
    f_at = _specific_force(spec, N, [m.tau for m in imus])
    env = _vibration_envelope(spec, N)
    cols = [_imu_outputs(spec, j, m, t, f_at, env) for j, m in enumerate(imus, start=1)]
    raw = np.hstack([u for u, _, _ in cols])
    names = tuple(f"imu{j}.{a}" for j in range(1, K + 1) for a in _AXES)
    groups = tuple(f"imu{j}" for j in range(1, K + 1) for _ in _AXES)
    aux = _aux_channels(spec, names, groups, [a for _, a, _ in cols],
                        [T for _, _, T in cols])
    truth = _truth(spec, imus, N)
    return Flight(t=t, raw=raw, valid=np.ones(raw.shape, bool), sample_rate_hz=fs,
                  sensor_names=names, raw_unit="rad/s", omega_true=omega, truth=truth,
                  source="<simulated>", kind="gyro", imu=groups, aux=aux)


def _specific_force(spec: ImuSetSpec, N: int, taus: Sequence[float]
                    ) -> Callable[[np.ndarray], np.ndarray]:
    """The specific force (N', 3) at any times: computed on a grid four times finer than
    the samples, padded beyond both ends, so that it can be read at t + τ_j."""
    fs = float(spec.sample_rate_hz)
    pad = max(1.0, max(abs(x) for x in taus) * 2)
    up = 4
    tf = np.arange(-round(pad * fs) * up, (N + round(pad * fs)) * up) / (fs * up)
    wf = body_rates(np.maximum(tf, 0.0), seed=spec.seed, max_rate_dps=spec.max_rate_dps)
    grav = attitude_gravity(tf, wf)
    lin = _smooth_noise(np.random.default_rng([int(spec.seed), 13]), tf.shape[0], fs * up,
                        spec.linear_accel)
    ff = grav + lin

    def f_at(tt: np.ndarray) -> np.ndarray:
        return np.column_stack([np.interp(tt, tf, ff[:, a]) for a in range(3)])

    return f_at


def _vibration_envelope(spec: ImuSetSpec, N: int) -> np.ndarray:
    """The vibration envelope v(t) in [0, 1], shape (N,) (zeros without vibration noise)."""
    env = np.zeros(N)
    if spec.effects.vibration_noise > 0:
        env = np.abs(_smooth_noise(np.random.default_rng([int(spec.seed), 15]), N,
                                   float(spec.sample_rate_hz), 1.0, VIBRATION_CORR_S)[:, 0])
        env = np.clip(env - 0.5, 0.0, None)
        env /= max(float(env.max()), 1e-12)
    return env


_T0 = 25.0
"""Temperature (°C) at t = 0 and of the temperature coefficient's reference."""


def _imu_outputs(spec: ImuSetSpec, j: int, m: _Imu, t: np.ndarray,
                 f_at: Callable[[np.ndarray], np.ndarray], env: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """IMU j's gyro outputs (N, 3), accelerometer outputs (N, 3) and logged temperature
    (N,) (module docstring)."""
    fs = float(spec.sample_rate_hz)
    N = t.shape[0]
    e = spec.effects
    ts = t + m.tau
    if spec.timing_jitter_s and spec.timing_jitter_s[j - 1] > 0:
        jr = np.random.default_rng([int(spec.seed), 17, j])
        ts = ts + spec.timing_jitter_s[j - 1] * jr.standard_normal(N)
    w = body_rates(ts, seed=spec.seed, max_rate_dps=spec.max_rate_dps)
    f = f_at(ts)
    u = w @ m.G.T + m.bias + f @ m.gsens.T
    if e.warm_up_s > 0:
        u += np.exp(-t / e.warm_up_s)[:, None] * m.warm
    temp = _T0 + e.temperature_rise_c * (1 - np.exp(-t / e.temperature_tau_s))
    u += (temp - _T0)[:, None] * m.tcoef
    if e.vibration_hz > 0:
        u += m.vib_amp * np.sin(2 * math.pi * e.vibration_hz * t[:, None] + m.vib_phase)
    nr = np.random.default_rng([int(spec.seed), 12, j])
    ns = spec.noise_sd * (spec.noise_scale[j - 1] if spec.noise_scale else 1.0)
    u += ns * nr.standard_normal((N, 3))
    if e.random_walk > 0 and e.on(j):
        u += np.cumsum(nr.standard_normal((N, 3)), axis=0) * (e.random_walk / math.sqrt(fs))
    vr = np.random.default_rng([int(spec.seed), 16, j])
    if e.vibration_noise > 0 and e.on(j):
        u += env[:, None] * e.vibration_noise * vr.standard_normal((N, 3))
    acc = (f + spec.accel_noise_sd * nr.standard_normal((N, 3))
           + env[:, None] * e.vibration_accel * vr.standard_normal((N, 3)))
    return u, acc, temp + 0.05 * nr.standard_normal(N)


def _aux_channels(spec: ImuSetSpec, names: tuple[str, ...], groups: tuple[str, ...],
                  acc_cols: list[np.ndarray], temp_cols: list[np.ndarray]) -> AuxChannels:
    """The accelerometers of every IMU, and its temperature when that effect is on."""
    K = spec.imus
    kinds = ["accel"] * (3 * K)
    aux_names = list(names)
    aux_imu = list(groups)
    vals = [np.hstack(acc_cols)]
    if spec.effects.temperature_coeff > 0:
        kinds += ["temperature"] * K
        aux_names += [f"imu{j}" for j in range(1, K + 1)]
        aux_imu += [f"imu{j}" for j in range(1, K + 1)]
        vals.append(np.column_stack(temp_cols))
    values = np.hstack(vals)
    return AuxChannels(tuple(kinds), tuple(aux_names), tuple(aux_imu), values,
                       np.ones(values.shape, bool))


def _jitter(spec: ImuSetSpec, js: Sequence[int]) -> list[float]:
    """The timing jitter (s) of IMUs ``js`` (1-based)."""
    return [float(spec.timing_jitter_s[j - 1]) if spec.timing_jitter_s else 0.0 for j in js]


def _truth(spec: ImuSetSpec, imus: Sequence[_Imu], N: int) -> dict[str, Any]:
    ref = imus[0]
    Ginv = np.linalg.inv(ref.G)
    rel = {}
    for j, m in enumerate(imus[1:], start=2):
        A = m.G @ Ginv
        rel[f"imu{j}"] = {"A": A.tolist(), "c": (m.bias - A @ ref.bias).tolist(),
                          "time_offset_s": m.tau - ref.tau,
                          "timing_jitter_s": math.hypot(*_jitter(spec, (1, j)))}
    e = spec.effects
    return {"schema": FLIGHT_TRUTH_SCHEMA, "model": IMU_SET_MODEL, "seed": int(spec.seed),
            "kind": "gyro", "sample_rate_hz": float(spec.sample_rate_hz), "samples": N,
            "max_rate_dps": float(spec.max_rate_dps),
            "motion": "replay.motion: sin^2 rate pulses per 2-s segment and axis",
            "noise_sd": spec.noise_sd, "noise_scale": list(spec.noise_scale),
            "accel_noise_sd": spec.accel_noise_sd,
            "effects": {G_SENSITIVITY: e.g_sensitivity, "warm_up": e.warm_up,
                        "warm_up_s": e.warm_up_s, "temperature_coeff": e.temperature_coeff,
                        "temperature_rise_c": e.temperature_rise_c,
                        "temperature_tau_s": e.temperature_tau_s,
                        "vibration_hz": e.vibration_hz, "vibration": e.vibration,
                        "random_walk": e.random_walk, "vibration_noise": e.vibration_noise,
                        "vibration_accel": e.vibration_accel, "imus": list(e.imus)},
            "imus": {f"imu{j}": m.to_dict() for j, m in enumerate(imus, start=1)},
            "relative_to_reference": {"reference": "imu1", **rel},
            "units": {"gyro": "rad/s", G_SENSITIVITY: "rad/s per m/s^2",
                      "temperature_coeff": "rad/s per degC", "random_walk":
                          "rad/s per sqrt(s)"}}
