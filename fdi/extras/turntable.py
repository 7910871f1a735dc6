"""Typed records of a turntable calibration: its noise model (``extra.noise_model``) and the
fit's checks (``rate_test``, ``step_residual_chi2_dof``, ``residual_steps``,
``earth_rate_fit``, ``gyro_bias``, ``parity_calibrated_sd``). SI inside (``_dph``, ``_deg``
and the bias unit in the file)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fdi.errors import ConfigError
from fdi.extras.read import floats, ints, matrix, optional_number
from fdi.fileio import Fields
from fdi.units import DEG, DPH, input_unit_factor

__all__ = ["PARITY_SD_KEYS", "RESIDUAL_UNITS", "SD_FACTOR_KEYS", "EarthRateRecord", "GyroBias",
           "NoiseFit", "NoiseModel", "RateTest", "ResidualStep", "parity_sd_to_dict",
           "read_earth_rate", "read_gyro_bias", "read_noise_model", "read_parity_sd",
           "read_rate_test", "read_residual_steps", "residual_steps_to_dict"]


# -- noise model -------------------------------------------------------------------------
SD_FACTOR_KEYS = ("bias", "scale_factor", "misalignment")
"""The estimates whose sd the coloured noise widens (``sd_factor`` keys)."""


@dataclass(frozen=True)
class NoiseFit:
    """What the noise model did to one sensor set (``extra.noise_model.<kind>``).

    Attributes
    ----------
    applied : bool
        The first-order Gauss-Markov bias was kept (else white noise).
    bias_instability : float
        σ_b of the fit (SI: rad/s or m/s²; 0 when not fitted).
    correlation_s : float or None
        Its correlation time (s).
    likelihood_ratio : float or None
        The likelihood-ratio statistic against white noise.
    sigma_bias_instability : float or None
        σ_b (SI) of the pair the estimates' sds were computed with (None: not applied).
    sigma_correlation_s : float or None
        The correlation time (s) of that pair.
    sigma_cut : bool
        The correlation time's profile interval was cut at a quarter of the record.
    record_s : float or None
        Length of the residual record the fit saw (s).
    sd_factor : dict of str to tuple of float
        Per :data:`SD_FACTOR_KEYS`, per sensor: sd with the model over the white-noise sd.
    """

    applied: bool = False
    bias_instability: float = 0.0
    correlation_s: float | None = None
    likelihood_ratio: float | None = None
    sigma_bias_instability: float | None = None
    sigma_correlation_s: float | None = None
    sigma_cut: bool = False
    record_s: float | None = None
    sd_factor: Mapping[str, tuple[float, ...]] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """The JSON record (``extra.noise_model.<kind>``). Without a fit (white noise asked
        for: ``likelihood_ratio`` None) only ``applied`` and ``sd_factor`` are written."""
        fit = {} if self.likelihood_ratio is None else {
            "bias_instability": self.bias_instability, "correlation_s": self.correlation_s,
            "likelihood_ratio": self.likelihood_ratio}
        rest = {} if self.likelihood_ratio is None else {
            "sigma_bias_instability": self.sigma_bias_instability,
            "sigma_correlation_s": self.sigma_correlation_s, "sigma_cut": self.sigma_cut,
            "record_s": self.record_s}
        return {**fit, "applied": self.applied, **rest,
                "sd_factor": {k: list(v) for k, v in self.sd_factor.items()}}


@dataclass(frozen=True)
class NoiseModel:
    """The noise model of a turntable calibration (``extra.noise_model``).

    Attributes
    ----------
    method : str
        What was fitted and how (one line).
    sets : dict of str to NoiseFit
        Per sensor kind (``"gyro"``, ``"accel"``).
    """

    method: str = ""
    sets: Mapping[str, NoiseFit] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """The JSON record (``extra.noise_model``)."""
        return {"method": self.method, **{k: f.to_dict() for k, f in self.sets.items()}}


def _noise_fit(r: Fields) -> NoiseFit:
    sdf = r.mapping("sd_factor", {})
    factors = {k: tuple(float(x) for x in sdf.array(k, (None,), finite=False))
               for k in sdf.keys()}
    return NoiseFit(applied=r.boolean("applied", False),
                    bias_instability=r.number("bias_instability", 0.0, finite=False),
                    correlation_s=optional_number(r, "correlation_s"),
                    likelihood_ratio=optional_number(r, "likelihood_ratio"),
                    sigma_bias_instability=optional_number(r, "sigma_bias_instability"),
                    sigma_correlation_s=optional_number(r, "sigma_correlation_s"),
                    sigma_cut=r.boolean("sigma_cut", False),
                    record_s=optional_number(r, "record_s"),
                    sd_factor=factors)


def read_noise_model(r: Fields) -> NoiseModel | None:
    """``extra.noise_model`` (None when absent)."""
    if "noise_model" not in r:
        return None
    m = r.mapping("noise_model")
    return NoiseModel(method=m.string("method", "", nonempty=False),
                      sets={k: _noise_fit(m.mapping(k)) for k in m.keys() if k != "method"})


# -- turntable fit checks -----------------------------------------------------------------
@dataclass(frozen=True)
class RateTest:
    """The rate-step pairs of a turntable calibration (``extra.rate_test``).

    Attributes
    ----------
    pairs : tuple of (int, int)
        1-based step numbers of each pair.
    rates : tuple of (float, float, float)
        The input rate of each pair (rad/s, MB frame; file: ``R_rad_s``).
    chi2_dof : tuple of float
        Per sensor, χ²/dof of the step differences about the fit.
    """

    pairs: tuple[tuple[int, int], ...] = ()
    rates: tuple[tuple[float, ...], ...] = ()
    chi2_dof: tuple[float, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        """The record ``extra.rate_test`` (``R_rad_s`` and ``chi2_dof`` as arrays, as the fit
        gives them; :func:`fdi.fileio.to_jsonable` writes them)."""
        return {"pairs": [list(p) for p in self.pairs], "R_rad_s": np.array(self.rates, float),
                "chi2_dof": np.array(self.chi2_dof, float)}


@dataclass(frozen=True)
class ResidualStep:
    """Residual (compensated output − model) statistics of one step
    (``extra.residual_steps.<kind>[k]``).

    Attributes
    ----------
    step : int
        1-based step number.
    label, kind : str
        The step's label and kind (``"rate"``, ``"position"``).
    n : int
        Samples used.
    mean, rms : tuple of float
        Per sensor (SI: rad/s or m/s²).
    """

    step: int
    label: str
    kind: str
    n: int
    mean: tuple[float, ...]
    rms: tuple[float, ...]

    def to_dict(self) -> dict[str, Any]:
        """The JSON record (``extra.residual_steps.<kind>[k]``)."""
        return {"step": self.step, "label": self.label, "kind": self.kind, "n": self.n,
                "mean": list(self.mean), "rms": list(self.rms)}


@dataclass(frozen=True)
class EarthRateRecord:
    """The Earth rate recovered from the outer-axis modulation (``extra.earth_rate_fit``,
    :meth:`calibration.earth_rate.EarthRateFit.to_dict`; deg/h and deg in the file).

    Attributes
    ----------
    rate, rate_sd : float
        Magnitude and sd (rad/s).
    horizontal : float or None
        Horizontal component (rad/s); None when not recorded.
    horizontal_sd, scatter_sd : float
        Its sd and the per-step scatter sd (rad/s; 0 when not recorded).
    heading_offset, heading_offset_sd : float
        Heading of the table's zero and its sd (rad).
    steps : tuple of int
        1-based outer-axis steps used.
    per_step : tuple of float
        Rate per step (rad/s).
    n_samples : int
    denoised : bool
    """

    rate: float = float("nan")
    rate_sd: float = float("nan")
    horizontal: float | None = None
    horizontal_sd: float = 0.0
    heading_offset: float = float("nan")
    heading_offset_sd: float = float("nan")
    steps: tuple[int, ...] = ()
    per_step: tuple[float, ...] = ()
    scatter_sd: float = 0.0
    n_samples: int = 0
    denoised: bool = False

    def to_dict(self) -> dict[str, Any]:
        """The JSON record (``extra.earth_rate_fit``; deg/h and deg)."""
        h = None if self.horizontal is None else self.horizontal / DPH
        return {"rate_dph": self.rate / DPH, "rate_dph_sd": self.rate_sd / DPH,
                "horizontal_dph": h, "horizontal_dph_sd": self.horizontal_sd / DPH,
                "heading_offset_deg": self.heading_offset / DEG,
                "heading_offset_deg_sd": self.heading_offset_sd / DEG,
                "steps": list(self.steps), "per_step_dph": [x / DPH for x in self.per_step],
                "scatter_sd_dph": self.scatter_sd / DPH, "n_samples": self.n_samples,
                "denoised": self.denoised}


@dataclass(frozen=True)
class GyroBias:
    """The gyro biases by both methods of a turntable calibration (``extra.gyro_bias``).

    Attributes
    ----------
    unit : str
        The unit the file writes them in (the calibration file's bias unit).
    model, model_sd : tuple of float
        Per sensor, the bias of the Earth-rate model and its sd (rad/s).
    turns, turns_sd : tuple of float or None
        By seed 000's whole outer-axis turns (rad/s); None without whole turns.
    turns_steps, turns_per_step : tuple of int
        The steps with whole turns and their number of turns.
    vertical_correction : tuple of float or None
        The vertical Earth rate removed from the turns estimate (rad/s).
    """

    unit: str
    model: tuple[float, ...]
    model_sd: tuple[float, ...]
    turns: tuple[float, ...] | None = None
    turns_sd: tuple[float, ...] | None = None
    turns_steps: tuple[int, ...] = ()
    turns_per_step: tuple[int, ...] = ()
    vertical_correction: tuple[float, ...] | None = None

    def to_dict(self) -> dict[str, Any]:
        """The JSON record (``extra.gyro_bias``): rates divided by the factor of
        :attr:`unit`; the whole-turn entries only when :attr:`turns` is set."""
        f = input_unit_factor(self.unit)

        def out(v: tuple[float, ...] | None) -> list[float] | None:
            return None if v is None else [x / f for x in v]

        rec: dict[str, Any] = {"unit": self.unit, "model": out(self.model),
                               "model_sd": out(self.model_sd)}
        if self.turns is not None:
            rec.update({"turns": out(self.turns), "turns_sd": out(self.turns_sd),
                        "turns_steps": list(self.turns_steps),
                        "turns_per_step": list(self.turns_per_step),
                        "vertical_correction": out(self.vertical_correction)})
        return rec


def read_rate_test(r: Fields) -> RateTest | None:
    """``extra.rate_test`` (None when absent)."""
    if "rate_test" not in r:
        return None
    t = r.mapping("rate_test")
    pairs = matrix(t, "pairs")
    if any(len(p) != 2 or any(not float(x).is_integer() for x in p) for p in pairs):
        raise t.error("pairs", "expected pairs of step numbers")
    return RateTest(pairs=tuple((int(a), int(b)) for a, b in pairs), rates=matrix(t, "R_rad_s"),
                    chi2_dof=floats(t, "chi2_dof"))


def read_residual_steps(r: Fields) -> dict[str, tuple[ResidualStep, ...]]:
    """``extra.residual_steps`` per sensor kind (empty when absent)."""
    if "residual_steps" not in r:
        return {}
    m = r.mapping("residual_steps")
    m.accept("unit")
    return {k: tuple(ResidualStep(step=e.integer("step"), label=e.string("label", "",
                                                                         nonempty=False),
                                  kind=e.string("kind", "", nonempty=False),
                                  n=e.integer("n", 0, lo=0), mean=floats(e, "mean"),
                                  rms=floats(e, "rms"))
                     for e in m.tables(k, [], nonempty=False))
            for k in m.keys() if k != "unit"}


def read_earth_rate(r: Fields) -> EarthRateRecord | None:
    """``extra.earth_rate_fit`` (None when absent)."""
    if "earth_rate_fit" not in r:
        return None
    e = r.mapping("earth_rate_fit")
    nan = float("nan")

    def dph(key: str, default: float | None) -> float | None:
        v = e.number(key, None, finite=False)
        return default if v is None else v * DPH

    def deg(key: str) -> float:
        return e.number(key, nan, finite=False) * DEG

    return EarthRateRecord(
        rate=dph("rate_dph", nan), rate_sd=dph("rate_dph_sd", nan),
        horizontal=dph("horizontal_dph", None), horizontal_sd=dph("horizontal_dph_sd", 0.0),
        heading_offset=deg("heading_offset_deg"), heading_offset_sd=deg("heading_offset_deg_sd"),
        steps=ints(e, "steps"), per_step=floats(e, "per_step_dph", scale=DPH),
        scatter_sd=dph("scatter_sd_dph", 0.0), n_samples=e.integer("n_samples", 0, lo=0),
        denoised=e.boolean("denoised", False))


def read_gyro_bias(r: Fields) -> GyroBias | None:
    """``extra.gyro_bias`` (None when absent)."""
    if "gyro_bias" not in r:
        return None
    g = r.mapping("gyro_bias")
    unit = g.string("unit")
    try:
        f = input_unit_factor(unit)
    except ConfigError as exc:
        raise g.error("unit", str(exc)) from None
    turns = floats(g, "turns", None, f)
    return GyroBias(unit=unit, model=floats(g, "model", (), f),
                    model_sd=floats(g, "model_sd", (), f), turns=turns,
                    turns_sd=floats(g, "turns_sd", None, f),
                    turns_steps=ints(g, "turns_steps"),
                    turns_per_step=ints(g, "turns_per_step"),
                    vertical_correction=floats(g, "vertical_correction", None, f))


PARITY_SD_KEYS = {"gyro": "parity_calibrated_sd", "accel": "parity_accel_calibrated_sd"}
"""The ``extra`` key of the calibrated parity matrix's sd per sensor kind."""

RESIDUAL_UNITS = {"gyro": "rad/s", "accel": "m/s^2"}
"""``extra.residual_steps.unit``: the unit of the residual statistics per kind."""


def read_parity_sd(r: Fields) -> dict[str, tuple[tuple[float, ...], ...]]:
    """``extra.parity_calibrated_sd`` and ``parity_accel_calibrated_sd`` per kind."""
    out = {}
    for kind, key in PARITY_SD_KEYS.items():
        if key in r:
            out[kind] = matrix(r, key)
    return out


def parity_sd_to_dict(parity_sd: Mapping[str, tuple[tuple[float, ...], ...]]
                      ) -> dict[str, Any]:
    """The entries of the parity sds per kind (``parity_calibrated_sd``, ...): an array of
    shape (n-3, n), ``[]`` for a set of three."""
    return {PARITY_SD_KEYS[k]: np.array(v, float) if v else [] for k, v in parity_sd.items()}


def residual_steps_to_dict(steps: Mapping[str, tuple[ResidualStep, ...]]) -> dict[str, Any]:
    """The JSON record ``extra.residual_steps`` (with its ``unit`` table)."""
    return {"unit": dict(RESIDUAL_UNITS),
            **{k: [e.to_dict() for e in v] for k, v in steps.items()}}

