"""Simulated flights whose sensors carry a calibration's effect terms, with their inputs.

``rimu simulate flight --effects-from-cal`` makes the true sensors of a simulated flight
carry the calibration's own effect terms (``rimu.calibration/2`` ``effects``) at their
estimates, so that a replay with those terms should remove them: the true input of sensor i
gains ``c_i = estimate · g(inputs)`` (:func:`fdi.effects.term_correction`, the run-time form
the monitor subtracts), evaluated on the *true* inputs::

    scale_asymmetry, scale_nonlinearity   the true input along the true axis, s = h_i·ω
    g_sensitivity                         the true specific force (gravity reaction of the
                                          flight's attitude), along the true axis
    temperature                           the true temperature profile T(t)

and the raw output gains ``c_i / SF_i`` (SF_i the true scale factor). A stuck sensor keeps
its held value, a dropped sample stays NaN. Terms without a run-time form (``bias_step``,
``warmup``, …) and terms of the other sensor kind are not simulated (listed with the reason).

The inputs are written beside the sensors as auxiliary channels
(:class:`replay.flight_data.AuxChannels`):

- a body-frame accelerometer triad ``accel:imu.x/.y/.z`` (m/s²): the true specific force
  plus white noise of sd ``accel_noise`` (default: the calibration's accelerometer noise,
  the RMS of its per-sample sd scaled to the flight's rate); when the calibration has no
  accelerometers the triad must be asked for with an explicit ``accel_noise``;
- a board temperature ``temperature:board`` (°C): ``T(t)`` plus white noise of sd
  ``temperature_noise``, ``T(t) = T0 + (T1 − T0)·(1 − exp(−t/τ))``
  (:class:`TemperatureProfile`).

Random streams: accelerometer noise ``default_rng([seed, 11])``, temperature noise
``default_rng([seed, 12])`` (the flight's own streams are untouched: the same flight
without effects has the same noise).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from fdi.calfile import Calibration, EffectTerm
from fdi.effects import COMPENSABLE, Compensator, term_correction
from fdi.errors import ConfigError
from replay.flight_data import AuxChannels, Flight
from replay.imu_set import attitude_gravity

__all__ = [
    "EffectPlan",
    "TemperatureProfile",
    "add_effects",
    "parse_temperature_profile",
    "plan_effects",
]

_EPS_T = 1e-12


@dataclass(frozen=True)
class TemperatureProfile:
    """``T(t) = start + (end − start)·(1 − exp(−t/τ))`` (°C, t in s from the flight start)."""

    start_degC: float
    end_degC: float
    tau_s: float

    def __call__(self, t_s: Any) -> np.ndarray:
        t = np.asarray(t_s, float)
        return self.start_degC + (self.end_degC - self.start_degC) * -np.expm1(-t / self.tau_s)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (truth record)."""
        return {"form": "start + (end - start)*(1 - exp(-t/tau))",
                "start_degC": self.start_degC, "end_degC": self.end_degC, "tau_s": self.tau_s}


def parse_temperature_profile(spec: str, duration_s: float) -> TemperatureProfile:
    """``START:END[:TAU]`` (°C, °C, s; TAU defaults to a third of the flight).

    Raises
    ------
    ConfigError
        Naming the part that is not a finite number (or a non-positive TAU).
    """
    parts = str(spec).split(":")
    if len(parts) not in (2, 3):
        raise ConfigError(f"--temperature {spec!r}: expected START:END[:TAU] "
                          "(degC, degC, s), e.g. 20:40:100")
    vals = []
    for name, p in zip(("START", "END", "TAU"), parts, strict=False):
        try:
            v = float(p)
        except ValueError:
            v = math.nan
        if not math.isfinite(v) or abs(v) > 1e4:
            raise ConfigError(f"--temperature {spec!r}: {name} {p!r} is not a number "
                              "within +-1e4")
        vals.append(v)
    tau = vals[2] if len(vals) == 3 else duration_s / 3.0
    if not tau > 0:
        raise ConfigError(f"--temperature {spec!r}: TAU must be positive (s)")
    return TemperatureProfile(vals[0], vals[1], tau)


@dataclass(frozen=True)
class EffectPlan:
    """Which terms a flight simulates and the inputs it writes.

    Attributes
    ----------
    terms : tuple of EffectTerm
        Simulated at their estimates.
    skipped : tuple of (EffectTerm, str)
        Not simulated, with the reason.
    temperature : TemperatureProfile or None
        None: no temperature channel.
    accel_noise_mps2 : float or None
        Per-sample sd of the accelerometer triad (m/s²); None: no triad.
    temperature_noise_degC : float
        Per-sample sd of the temperature channel (°C).
    """

    terms: tuple[EffectTerm, ...]
    skipped: tuple[tuple[EffectTerm, str], ...]
    temperature: TemperatureProfile | None
    accel_noise_mps2: float | None
    temperature_noise_degC: float

    def summary(self, names: Any = None) -> str:
        """One line, terms grouped by effect and skipped terms by reason:
        ``simulated effects (...): g_sensitivity on x1, y1; not simulated: …``."""
        def who(t: EffectTerm) -> str:
            if names is not None and t.kind == self._kind and 0 <= t.sensor < len(names):
                return str(names[t.sensor])
            return f"{t.kind} {t.sensor + 1}"

        on: dict[str, list[str]] = {}
        for t in self.terms:
            on.setdefault(t.name, []).append(who(t))
        off: dict[str, list[str]] = {}
        for t, why in self.skipped:
            off.setdefault(why, []).append(f"{t.name} on {who(t)}")
        text = ("simulated effects (true value = the calibration's estimate): "
                + "; ".join(f"{k} on {', '.join(v)}" for k, v in on.items()))
        if off:
            text += "; not simulated: " + "; ".join(
                f"{', '.join(v)} ({why})" for why, v in off.items())
        return text

    @property
    def _kind(self) -> str:
        return self.terms[0].kind if self.terms else "gyro"

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready truth record (sensors 1-based)."""
        def term(t: EffectTerm) -> dict[str, Any]:
            return {"name": t.name, "kind": t.kind, "sensor": t.sensor + 1,
                    "estimate": t.estimate, "unit": t.unit, "params": dict(t.params)}

        return {"terms": [term(t) for t in self.terms],
                "not_simulated": [{**term(t), "reason": why} for t, why in self.skipped],
                "temperature_profile": (None if self.temperature is None
                                        else self.temperature.to_dict()),
                "accel_noise_mps2": self.accel_noise_mps2,
                "temperature_noise_degC": self.temperature_noise_degC,
                "aux_channels": {"specific_force": "accel:imu.x/.y/.z (body axes, m/s^2)",
                                 "temperature": "temperature:board (degC, all sensors)"}}


def _accel_noise_of(cal: Calibration, fs: float) -> float | None:
    """RMS per-sample sd (m/s²) of the calibration's accelerometers at ``fs``, or None."""
    if "accel" not in cal.sets:
        return None
    var = np.diag(np.asarray(cal.kind("accel").noise_covariance, float))
    scale = fs / cal.sample_rate_hz if cal.sample_rate_hz > 0 else 1.0
    return float(math.sqrt(max(float(var.mean()), 0.0) * scale))


def plan_effects(cal: Calibration, kind: str, *, duration_s: float, sample_rate_hz: float,
                 temperature: TemperatureProfile | None = None,
                 accel_noise_mps2: float | None = None,
                 temperature_noise_degC: float = 0.05) -> EffectPlan:
    """The terms of ``cal`` a flight of ``kind`` sensors simulates, and its inputs.

    Parameters
    ----------
    cal : Calibration
        With effect terms.
    kind : str
        The flight's sensor kind.
    duration_s, sample_rate_hz : float
    temperature : TemperatureProfile, optional
        Default when a temperature term is simulated: from 10 °C below the lowest term
        reference to 10 °C above the highest, τ a third of the flight.
    accel_noise_mps2 : float, optional
        Default: the calibration's accelerometer noise; required when a ``g_sensitivity``
        term is simulated and the calibration has no accelerometers. Given, a triad is
        written even without such a term.
    temperature_noise_degC : float

    Raises
    ------
    ConfigError
        The calibration has no effect terms, none of them can be simulated for ``kind``, or a
        ``g_sensitivity`` term needs accelerometers the calibration does not have.
    """
    if not cal.effects:
        raise ConfigError("--effects-from-cal: the calibration has no effect terms "
                          "(fit them with rimu calibrate turntable --effects NAME,... or rimu "
                          "diagnose)")
    n = cal.kind(kind).n
    everything = {"specific_force": range(n), "temperature": range(n)}
    comp = Compensator(cal, kind, available=everything)
    terms = tuple(a.term for a in comp.applied)
    skipped = tuple((s.term, s.reason) for s in comp.skipped)
    if not terms:
        why = "; ".join(f"{t.name} on {t.kind} {t.sensor + 1}: {r}" for t, r in skipped)
        raise ConfigError(f"--effects-from-cal: none of the calibration's {len(skipped)} "
                          f"effect term(s) has a run-time form for a {kind} flight ({why})")
    needs = {COMPENSABLE[t.name][0] for t in terms}
    if accel_noise_mps2 is None and "specific_force" in needs:
        accel_noise_mps2 = _accel_noise_of(cal, sample_rate_hz)
        if accel_noise_mps2 is None:
            force_terms = [t for t in terms if COMPENSABLE[t.name][0] == "specific_force"]
            who = "; ".join(f"{nm} on " + ", ".join(f"{kind} {t.sensor + 1}" for t in force_terms
                                                    if t.name == nm)
                            for nm in dict.fromkeys(t.name for t in force_terms))
            raise ConfigError(
                f"--effects-from-cal: {who} needs the specific force, and "
                f"the calibration ({cal.configuration}) has no accelerometers; give "
                "--accel-noise SD (m/s^2 per sample) to simulate a body-frame accelerometer "
                "triad beside the gyros")
    if temperature is None and "temperature" in needs:
        refs = [float(t.params["reference_degC"]) for t in terms
                if COMPENSABLE[t.name][0] == "temperature"]
        temperature = TemperatureProfile(min(refs) - 10.0, max(refs) + 10.0, duration_s / 3.0)
    return EffectPlan(terms, skipped, temperature, accel_noise_mps2,
                      float(temperature_noise_degC))


def add_effects(flight: Flight, plan: EffectPlan, *, seed: int) -> Flight:
    """The flight with ``plan``'s terms on its true sensors and the input channels.

    Parameters
    ----------
    flight : Flight
        A simulated flight (``omega_true`` and ``truth["true_parameters"]`` filled in).
    plan : EffectPlan
    seed : int

    Returns
    -------
    Flight
        ``raw`` with the effects, ``aux`` with the triad and/or the temperature, ``truth``
        with ``"effects_simulated"`` (:meth:`EffectPlan.to_dict`).
    """
    if flight.omega_true is None or "true_parameters" not in flight.truth:
        raise ConfigError("add_effects needs a simulated flight (true rates and parameters)")
    tp = flight.truth["true_parameters"]
    axis = np.asarray(tp["axis"], float)
    sf = np.asarray(tp["scale_factor"], float)
    t = np.asarray(flight.t, float)
    omega = np.asarray(flight.omega_true, float)
    N = t.shape[0]
    x = omega @ axis.T
    needs = {COMPENSABLE[tm.name][0] for tm in plan.terms}
    force = (attitude_gravity(t, omega) if "specific_force" in needs
             or plan.accel_noise_mps2 is not None else None)
    temp = plan.temperature(t - t[0]) if plan.temperature is not None and N else None
    add = np.zeros_like(flight.raw)
    for tm in plan.terms:
        i = tm.sensor
        add[:, i] += term_correction(tm, axis[i], s=x[:, i], force=force, temperature=temp)
    keep = np.zeros(flight.raw.shape, bool)                 # stuck: the held value stays
    for f in flight.faults:
        if f.kind == "stuck":
            keep[(t >= f.onset - _EPS_T) & (t < f.end - _EPS_T), f.sensor - 1] = True
    raw = np.where(keep, flight.raw, flight.raw + add / sf)
    kinds, names, vals = [], [], []
    if force is not None and plan.accel_noise_mps2 is not None:
        noise = np.random.default_rng([int(seed), 11]).standard_normal((N, 3))
        kinds += ["accel"] * 3
        names += ["imu.x", "imu.y", "imu.z"]
        vals.append(force + plan.accel_noise_mps2 * noise)
    if temp is not None:
        noise = np.random.default_rng([int(seed), 12]).standard_normal(N)
        kinds.append("temperature")
        names.append("board")
        vals.append((temp + plan.temperature_noise_degC * noise)[:, None])
    aux = None
    if kinds:
        v = np.column_stack(vals)
        aux = AuxChannels(tuple(kinds), tuple(names), ("",) * len(kinds), v,
                          np.ones(v.shape, bool))
    truth = dict(flight.truth)
    truth["effects_simulated"] = plan.to_dict()
    truth.pop("effects_not_simulated", None)
    return dataclasses.replace(flight, raw=raw, aux=aux, truth=truth)
