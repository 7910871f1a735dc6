"""Simulate a turntable calibration session from a sequence and true sensor parameters.

Sensor model (seed 000 Eq. 13, seed 001 Eq. 1), per sensor i of each kind::

    u_i = (h̃_i·x + b_i + e_i + η_i) / SF_i

``u_i`` the raw output, ``x`` the input in the body (MB) frame — for gyros the table rate
plus Earth rate (15.041 °/h at the latitude), for accelerometers the specific force
``f_b`` (local gravity, Up) — ``h̃_i``, ``SF_i`` (input per raw unit) and ``b_i`` the true
values from a :class:`fdi.calfile.Calibration`, ``e_i`` the effects switched on
(:mod:`calibration.effects`) and ``η_i`` the noise: white with the truth's per-sample
``noise_covariance`` (SI², correlations allowed), plus optionally a first-order Gauss-Markov
bias instability and a bias random walk (:class:`SessionNoise`). Inputs come from the one
kinematic model, :func:`calibration.turntable.body_inputs`, step by step.

Time: each step of the sequence lasts ``round(duration_s·fs)`` samples at ``t = t0 + k/fs``
(rate steps of whole turns therefore cover each turn exactly, uniformly sampled); steps
follow each other without a gap and the table angles restart at each step's start angles.

Random numbers: ``np.random.default_rng(seed)`` draws the white noise of the gyros, then of
the accelerometers, then the optional bias processes; effects draw nothing, so the same seed
gives the same noise with and without effects.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.signal import lfilter

from calibration.effects import (
    DELAY_KNOB,
    EARTH_RATE_KNOB,
    EFFECTS,
    TEMPERATURE_KNOB,
    resolve_effect_sensors,
    temperature_profile,
)
from calibration.sequence import Sequence
from calibration.session import Session
from calibration.session_io import MIN_STEP_SAMPLES
from calibration.turntable import body_inputs, gravity_local
from fdi.calfile import Calibration, SensorSet
from fdi.errors import ConfigError
from fdi.geometry import Configuration, load_configuration
from fdi.units import EARTH_RATE_DPH

__all__ = ["EffectContext", "NoiseDraw", "SessionNoise", "SimSetup", "TimeBase", "accel_outputs",
           "configuration_of", "draw_noise", "gyro_outputs", "sampled_inputs",
           "save_simulation", "sim_setup", "simulate_session", "time_base", "true_raw_means",
           "truth_of_session"]


@dataclass(frozen=True)
class SessionNoise:
    """The noise of a simulated session beyond the white noise held in the truth's
    ``noise_covariance`` (the simulator's input; the fitted record is
    :class:`fdi.extras.NoiseModel`).

    Attributes
    ----------
    white : bool
        Add the white noise of the truth (False: noise-free outputs, for tests).
    bias_instability : dict of kind to float
        Standard deviation of a first-order Gauss-Markov bias (SI: rad/s, m/s²) per kind.
    bias_correlation_s : float
        Its correlation time (s).
    random_walk : dict of kind to float
        Bias random walk density (SI per √s: rad/s/√s, m/s²/√s) per kind.
    """

    white: bool = True
    bias_instability: Mapping[str, float] = field(default_factory=dict)
    bias_correlation_s: float = 100.0
    random_walk: Mapping[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict:
        """JSON-ready description (SI)."""
        return {"white": self.white, "bias_instability": dict(self.bias_instability),
                "bias_correlation_s": self.bias_correlation_s,
                "random_walk": dict(self.random_walk)}


def configuration_of(s: SensorSet, name: str) -> Configuration:
    """The nominal :class:`fdi.geometry.Configuration` of a sensor set."""
    names = tuple(c.name for c in s.sensors)
    return Configuration(name, s.H_nominal, names, tuple(s.groups))


def _raw_unit(s: SensorSet) -> str:
    units = {c.raw_unit for c in s.sensors}
    if len(units) != 1:
        raise ConfigError(f"{s.kind} sensors have different raw units {sorted(units)}; a "
                          "session holds one raw unit per kind")
    return units.pop()


def _std_normal_to_cov(z: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """Correlate standard normals z (N, n) to covariance ``cov`` (n, n)."""
    cov = np.asarray(cov, float)
    if not np.any(cov):
        return np.zeros_like(z)
    try:
        L = np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        w, U = np.linalg.eigh(cov)
        L = U * np.sqrt(np.clip(w, 0.0, None))
    return z @ L.T


@dataclass(frozen=True)
class SimSetup:
    """What a simulation simulates: configurations, truth sets, rate, place, effects.

    Attributes
    ----------
    gyro_config, accel_config : Configuration (accel: or None)
    gyros, accels : SensorSet (accels: or None)
        True parameters.
    sample_rate_hz, latitude_deg, latitude_rad : float
    gravity : float
        Local gravity (m/s²).
    effects : dict of name to value
    touched : dict of name to 1-based sensors
        Active effects (value ≠ 0) and the sensors they touch.
    """

    gyro_config: Configuration
    accel_config: Configuration | None
    gyros: SensorSet
    accels: SensorSet | None
    sample_rate_hz: float
    latitude_deg: float
    latitude_rad: float
    gravity: float
    effects: dict[str, float]
    touched: dict[str, tuple[int, ...]]


def _configurations(config: Configuration | str | None, truth: Calibration,
                    accel_config: Configuration | None
                    ) -> tuple[Configuration, Configuration | None]:
    """Nominal gyro and accelerometer configurations, checked against the truth."""
    gset = truth.kind("gyro")
    aset = truth.sets.get("accel")
    if config is None:
        gcfg = configuration_of(gset, truth.configuration or "truth")
    elif isinstance(config, Configuration):
        gcfg = config
    else:
        gcfg = load_configuration(config)
    if gcfg.n != gset.n:
        raise ConfigError(f"configuration {gcfg.name!r} has {gcfg.n} gyros, the truth has "
                          f"{gset.n}")
    acfg = None if aset is None else configuration_of(aset, gcfg.name)
    if accel_config is not None:
        if aset is None or accel_config.n != aset.n:
            raise ConfigError(f"accelerometer configuration {accel_config.name!r} has "
                              f"{accel_config.n} sensors, the truth has "
                              f"{0 if aset is None else aset.n}")
        acfg = accel_config
    return gcfg, acfg


def sim_setup(config: Configuration | str | None, truth: Calibration, *,
              effects: Mapping[str, float] | None = None,
              effect_sensors: Mapping[str, Iterable[int]] | Iterable[int] | None = None,
              sample_rate_hz: float | None = None, latitude_deg: float | None = None,
              gravity: float | None = None,
              accel_config: Configuration | None = None) -> SimSetup:
    """Check and resolve the arguments of :func:`simulate_session` (stage 1).

    Raises
    ------
    ConfigError
        Inconsistent configuration and truth, no latitude, bad effect or sensor number.
    """
    gset = truth.kind("gyro")
    aset = truth.sets.get("accel")
    gcfg, acfg = _configurations(config, truth, accel_config)
    fs = float(sample_rate_hz or truth.sample_rate_hz)
    if not fs > 0:
        raise ConfigError(f"sample rate must be positive, got {fs}")
    lat_deg = latitude_deg if latitude_deg is not None else truth.latitude_deg
    if lat_deg is None:
        raise ConfigError("no latitude: give latitude_deg or put it in the truth")
    lat = np.deg2rad(float(lat_deg))
    g = gravity_local(lat) if gravity is None else float(gravity)
    eff = {k: float(v) for k, v in (effects or {}).items()}
    n_by_kind = {"gyro": gset.n, "accel": 0 if aset is None else aset.n}
    touched = resolve_effect_sensors(eff, effect_sensors, n_by_kind)
    return SimSetup(gyro_config=gcfg, accel_config=acfg, gyros=gset, accels=aset,
                    sample_rate_hz=fs, latitude_deg=float(lat_deg), latitude_rad=float(lat),
                    gravity=g, effects=eff, touched=touched)


@dataclass(frozen=True)
class TimeBase:
    """Samples of a sequence: time, step, table angles and rates (stage 2).

    Attributes
    ----------
    counts : tuple of int
        Samples per step.
    t, tau : ndarray, shape (N,)
        Time since the session start and since the step start (s).
    step : ndarray of int, shape (N,)
    inner, outer, inner_rate, outer_rate : ndarray, shape (N,)
        Table angles (rad) and rates (rad/s).
    """

    counts: tuple[int, ...]
    t: np.ndarray
    tau: np.ndarray
    step: np.ndarray
    inner: np.ndarray
    outer: np.ndarray
    inner_rate: np.ndarray
    outer_rate: np.ndarray

    @property
    def n_samples(self) -> int:
        """N."""
        return self.t.size


def time_base(sequence: Sequence, fs: float) -> TimeBase:
    """Each step ``round(duration_s·fs)`` samples at ``t = k/fs``, angles from the step start.

    Raises
    ------
    ConfigError
        A step shorter than :data:`calibration.session_io.MIN_STEP_SAMPLES` samples.
    """
    counts = [round(s.duration_s * fs) for s in sequence.steps]
    for s, n in zip(sequence.steps, counts, strict=True):
        if n < MIN_STEP_SAMPLES:
            raise ConfigError(f"sequence {sequence.name!r} step {s.index} lasts {s.duration_s:g} s"
                              f", {n} samples at {fs:g} Hz; a step needs at least "
                              f"{MIN_STEP_SAMPLES}")
    N = int(sum(counts))
    step = np.repeat([s.index for s in sequence.steps], counts).astype(np.int64)
    inner, outer = np.zeros(N), np.zeros(N)
    wi, wo = np.zeros(N), np.zeros(N)
    tau_all = np.zeros(N)
    start = 0
    for s, n in zip(sequence.steps, counts, strict=True):
        sl = slice(start, start + n)
        tau = np.arange(n) / fs
        tau_all[sl] = tau
        inner[sl], outer[sl] = s.angles_at(tau)
        wi[sl], wo[sl] = s.inner_rate, s.outer_rate
        start += n
    return TimeBase(counts=tuple(counts), t=np.arange(N) / fs, tau=tau_all, step=step,
                    inner=inner, outer=outer, inner_rate=wi, outer_rate=wo)


def sampled_inputs(sequence: Sequence, tb: TimeBase, lat: float, g: float,
                   skew: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Body inputs (ω_table, ω_earth, f_b), each (N, 3), with the input ``skew`` s late."""
    N = tb.n_samples
    wt, we, fb = np.zeros((N, 3)), np.zeros((N, 3)), np.zeros((N, 3))
    start = 0
    for s, n in zip(sequence.steps, tb.counts, strict=True):
        sl = slice(start, start + n)
        a_i, a_o = s.angles_at(tb.tau[sl] - skew)
        wt[sl], we[sl], fb[sl] = body_inputs(a_i, a_o, tb.inner_rate[sl], tb.outer_rate[sl],
                                             s.mat_pb, lat, g)
        start += n
    return wt, we, fb


@dataclass(frozen=True)
class NoiseDraw:
    """The noise of every sensor (stage 3), SI, per kind: ``{"gyro": (N, n), ...}``.

    Attributes
    ----------
    white : dict of kind to ndarray
        White noise with the truth's per-sample covariance (zeros when switched off).
    slow : dict of kind to ndarray
        Gauss-Markov bias instability plus bias random walk.
    """

    white: dict[str, np.ndarray]
    slow: dict[str, np.ndarray]


def _slow_noise(rng: np.random.Generator, noise: SessionNoise, kind: str, N: int, n: int,
                fs: float) -> np.ndarray:
    extra = np.zeros((N, n))
    sd = float(noise.bias_instability.get(kind, 0.0))
    if sd > 0:
        phi = np.exp(-1.0 / (fs * noise.bias_correlation_s))
        w = rng.standard_normal((N, n)) * sd * np.sqrt(1 - phi**2)
        x0 = rng.standard_normal(n) * sd
        extra += lfilter([1.0], [1.0, -phi], w, axis=0, zi=(phi * x0)[None, :])[0]
    q = float(noise.random_walk.get(kind, 0.0))
    if q > 0:
        extra += np.cumsum(rng.standard_normal((N, n)) * q / np.sqrt(fs), axis=0)
    return extra


def draw_noise(setup: SimSetup, noise: SessionNoise, N: int, seed: int | None) -> NoiseDraw:
    """White noise of the gyros, then the accelerometers, then the slow processes."""
    rng = np.random.default_rng(seed)
    kinds = [(k, s) for k, s in (("gyro", setup.gyros), ("accel", setup.accels))
             if s is not None]
    white = {}
    for kind, sset in kinds:
        z = rng.standard_normal((N, sset.n))
        white[kind] = _std_normal_to_cov(z, sset.noise_covariance) if noise.white else 0.0 * z
    slow = {kind: _slow_noise(rng, noise, kind, N, sset.n, setup.sample_rate_hz)
            for kind, sset in kinds}
    return NoiseDraw(white=white, slow=slow)


@dataclass(frozen=True)
class EffectContext:
    """What the gyro effects read: time, session length, table rate, specific force."""

    t: np.ndarray
    duration_s: float
    table_rate: float
    f_along: np.ndarray


_OUTPUT_EFFECTS = tuple(sorted((e for e in EFFECTS.values() if e.form.apply is not None),
                               key=lambda e: e.form.order))
"""Gyro effects on the output, in the order they are applied (gains, then biases; the
spec's ``simulator.order``); the others act on the inputs (``DELAY_KNOB``,
``EARTH_RATE_KNOB``)."""


def gyro_outputs(setup: SimSetup, sequence: Sequence, tb: TimeBase,
                 base: tuple[np.ndarray, ...], skewed: tuple[np.ndarray, ...],
                 draw: NoiseDraw) -> np.ndarray:
    """Raw gyro outputs with the effects (stage 4), shape (N, n_g)."""
    gset, eff, touched = setup.gyros, setup.effects, setup.touched
    Hg = gset.H
    earth = 0.0 if eff.get(EARTH_RATE_KNOB, 0.0) else 1.0

    def sel(name: str) -> np.ndarray:
        return np.isin(np.arange(1, gset.n + 1), touched.get(name, ()))

    sg = (base[0] + earth * base[1]) @ Hg.T             # input along the true axes
    f_g = base[2] @ Hg.T                                 # specific force along h̃_i
    if skewed is not base:
        m = sel(DELAY_KNOB)
        sg[:, m] = ((skewed[0] + earth * skewed[1]) @ Hg.T)[:, m]
        f_g[:, m] = (skewed[2] @ Hg.T)[:, m]
    ctx = EffectContext(t=tb.t, duration_s=tb.n_samples / setup.sample_rate_hz,
                        table_rate=sequence.table_rate, f_along=f_g)
    for e in _OUTPUT_EFFECTS:
        if e.name in touched:
            m = sel(e.name)
            sg[:, m] = e.form.apply(sg[:, m], eff[e.name],
                                    dataclasses.replace(ctx, f_along=f_g[:, m]))
    return (sg + gset.biases + draw.white["gyro"] + draw.slow["gyro"]) / gset.scale_factors


def accel_outputs(setup: SimSetup, base: tuple[np.ndarray, ...],
                  skewed: tuple[np.ndarray, ...], draw: NoiseDraw) -> np.ndarray | None:
    """Raw accelerometer outputs (stage 5), shape (N, n_a), or None without them."""
    aset = setup.accels
    if aset is None:
        return None
    sa = base[2] @ aset.H.T
    if skewed is not base:
        m = np.isin(np.arange(1, aset.n + 1), setup.touched[DELAY_KNOB])
        sa[:, m] = (skewed[2] @ aset.H.T)[:, m]
    return (sa + aset.biases + draw.white["accel"] + draw.slow["accel"]) / aset.scale_factors


def simulate_session(config: Configuration | str | None, sequence: Sequence,
                     truth: Calibration, *, seed: int | None = 0,
                     effects: Mapping[str, float] | None = None,
                     effect_sensors: Mapping[str, Iterable[int]] | Iterable[int] | None = None,
                     noise: SessionNoise | None = None, sample_rate_hz: float | None = None,
                     latitude_deg: float | None = None, gravity: float | None = None,
                     accel_config: Configuration | None = None) -> Session:
    """Simulate the raw outputs of every sensor over a test sequence.

    Stages: :func:`sim_setup`, :func:`time_base`, :func:`sampled_inputs`,
    :func:`draw_noise`, :func:`gyro_outputs`, :func:`accel_outputs`, then the session.

    Parameters
    ----------
    config : Configuration, str or None
        Nominal gyro configuration (a name or file for
        :func:`fdi.geometry.load_configuration`); None takes it from ``truth`` (nominal axes,
        names and groups of the gyro set). Its sensor count must match the truth's gyros.
    sequence : Sequence
    truth : Calibration
        True parameters: ``truth.sets["gyro"]`` and optionally ``truth.sets["accel"]``.
    seed : int or None
        Seed of ``np.random.default_rng``.
    effects : mapping of name to value, optional
        See :mod:`calibration.effects` (units there); all off by default. With
        ``temperature`` given (any value), the session carries the temperature profile.
    effect_sensors : mapping of name to 1-based sensors, or sensors for every effect
        Default: every sensor of the kinds each effect acts on.
    noise : SessionNoise, optional
        Default: white noise only.
    sample_rate_hz : float, optional
        Default ``truth.sample_rate_hz``.
    latitude_deg : float, optional
        Default ``truth.latitude_deg`` (required from one of them).
    gravity : float, optional
        Local gravity (m/s²); default normal gravity at the latitude.
    accel_config : Configuration, optional
        Nominal accelerometer configuration; default from ``truth.sets["accel"]``. Must
        match the truth's accelerometer count.

    Returns
    -------
    Session
        ``meta`` holds the sequence name, the seed, the mounting names, the effects and the
        sensors they touch.

    Raises
    ------
    ConfigError
        Inconsistent configuration and truth, no latitude, bad effect or sensor number.
    """
    noise = SessionNoise() if noise is None else noise
    su = sim_setup(config, truth, effects=effects, effect_sensors=effect_sensors,
                   sample_rate_hz=sample_rate_hz, latitude_deg=latitude_deg, gravity=gravity,
                   accel_config=accel_config)
    tb = time_base(sequence, su.sample_rate_hz)
    draw = draw_noise(su, noise, tb.n_samples, seed)
    base = sampled_inputs(sequence, tb, su.latitude_rad, su.gravity)
    skew = su.effects.get(DELAY_KNOB, 0.0) if DELAY_KNOB in su.touched else 0.0
    skewed = sampled_inputs(sequence, tb, su.latitude_rad, su.gravity, skew) \
        if skew != 0.0 else base
    meta = {
        "generator": "calibration.simulate.simulate_session",
        "sequence": sequence.name,
        "sequence_source": sequence.source,
        "table_rate_dps": sequence.table_rate_dps,
        "seed": seed,
        "mounts": {str(s.index): s.mount for s in sequence.steps},
        "effects": dict(su.effects),
        "effect_sensors": {k: list(v) for k, v in su.touched.items()},
        "effect_units": {k: EFFECTS[k].unit for k in su.effects},
        "noise": noise.to_dict(),
    }
    return Session(
        gyro_config=su.gyro_config, accel_config=su.accel_config,
        sample_rate_hz=su.sample_rate_hz, latitude_deg=su.latitude_deg,
        steps=sequence.session_steps(), t=tb.t, step=tb.step, inner=tb.inner,
        outer=tb.outer, inner_rate=tb.inner_rate, outer_rate=tb.outer_rate,
        raw_gyro=gyro_outputs(su, sequence, tb, base, skewed, draw),
        raw_accel=accel_outputs(su, base, skewed, draw), gyro_raw_unit=_raw_unit(su.gyros),
        accel_raw_unit=_raw_unit(su.accels) if su.accels is not None else "raw",
        gravity=su.gravity, source="<simulated>", meta=meta,
        temperature_degC=temperature_profile(tb.t) if TEMPERATURE_KNOB in su.effects else None)


def true_raw_means(session: Session, truth: Calibration, *,
                   earth_rate: bool = True) -> dict[str, np.ndarray]:
    """Model step means of the raw outputs, ``mean((h̃·x + b)/SF)`` per step, no effects.

    Returns
    -------
    dict of kind to ndarray, shape (S, n)
        Rows in the order of ``session.steps``.
    """
    wt, we, fb = session.inputs()
    out = {}
    for kind, x in (("gyro", wt + (we if earth_rate else 0.0)), ("accel", fb)):
        if kind not in truth.sets:
            continue
        s = truth.sets[kind]
        u = (x @ s.H.T + s.biases) / s.scale_factors
        out[kind] = np.array([u[session.step == st.index].mean(axis=0)
                              for st in session.steps])
    return out


def truth_of_session(session: Session, truth: Calibration
                     ) -> tuple[Calibration, dict[str, float], dict[str, tuple[int, ...]],
                                dict]:
    """The truth of a simulated session as written to ``truth.json``.

    Returns
    -------
    cal : Calibration
        ``truth`` with the session's sample rate and latitude, the true Earth rate
        (0 with ``no_earth_rate``) and, under ``extra``, the sequence and seed.
    effects, effect_sensors : dict
        From ``session.meta``.
    details : dict
        Constants the active effects used (warm-up τ, table rate, session length).
    """
    meta = session.meta
    effects = {k: float(v) for k, v in meta.get("effects", {}).items() if v != 0.0}
    sensors = {k: tuple(v) for k, v in meta.get("effect_sensors", {}).items()}
    details: dict = {}
    given = meta.get("effects", {})
    info = {"table_rate_dps": meta.get("table_rate_dps"),
            "duration_s": float(session.t.size / session.sample_rate_hz)}
    for e in EFFECTS.values():
        if e.form.details is not None and (e.name in effects
                                           or (e.form.column and e.name in given)):
            details[e.name] = e.form.details(info)
    extra = dict(truth.extra)
    extra.update({"sequence": meta.get("sequence"), "seed": meta.get("seed"),
                  "noise": meta.get("noise")})
    cal = dataclasses.replace(
        truth, sample_rate_hz=session.sample_rate_hz, latitude_deg=session.latitude_deg,
        earth_rate_dph=0.0 if effects.get(EARTH_RATE_KNOB) else EARTH_RATE_DPH,
        earth_rate_dph_sd=0.0, extra=extra)
    return cal, effects, sensors, details


def save_simulation(session: Session, truth: Calibration, directory: str | Path) -> Path:
    """Write a simulated session and its truth sidecar (``DIR/truth.json``).

    Returns
    -------
    Path
        The directory.
    """
    from calibration.session_io import save_session
    from calibration.truth import save_truth

    d = save_session(session, directory)
    cal, effects, sensors, details = truth_of_session(session, truth)
    save_truth(cal, effects, sensors, d / "truth.json", details=details)
    return d
