"""True sensor parameters for simulated sessions: the two papers' presets and random ones.

``tetrad-paper`` (seed 000): tetrad of FOGs (:func:`fdi.geometry.tetrad`), scale factors and
biases of Table 2 ("tetrad calibration" columns, mV/(°/s) and °/s), true axes
H̃ = blockdiag(M₁, M₂)·H with M₁, M₂ of Eq. 26 (rows normalised to unit length), latitude
−23.2°, 100 Hz, sequence ``tetrad-paper`` (Table 1, 10 °/s). The paper gives no noise
figure; we use white noise of σ = 0.01 °/s per sample at 100 Hz (angle random walk
0.06 °/√h, a tactical-grade FOG), small enough that the Earth-rate modulation
(≤ 0.0042 °/s) is recoverable from the outer-axis steps.

``cone-paper`` (seed 001): orthogonal cone (:func:`fdi.geometry.cone6`) of MEMS gyros and
accelerometers (ADXRS150, ADXL202E), two sub-IMUs with the same axes for both kinds, values
of Table 3: gyro SF ≈ 0.38-0.40 (°/s)/LSB and bias ≈ 190 °/s (the raw offset of a 10-bit
converter at mid-scale); accelerometer SF ≈ 2e-4 g/LSB and bias ≈ 3.6 g. Misalignment
matrices from the printed off-diagonal terms m; each diagonal term is recomputed so that
every row is a unit vector (seed 001 Eq. 10). Table 3 prints gyro m¹_xy = −1.8872e-1, which
contradicts its own m¹_xx = 0.99981 (a unit row then needs |m_xy| ≈ 0.019): we read it as
−1.8872e-2, which restores the unit norm to the printed digits. Our copy of the accelerometer
part is partly garbled: SF²_z is missing (we use 1.8847e-4, the mean of SF²_x and SF²_y).
Noise: white, σ = 0.3 °/s and 1 mg per sample at 100 Hz (seed 001 Table 4's standard
deviations after calibration). Latitude 37.5° (Seoul), sequence ``cone-paper`` (30 °/s).

Without a preset, :func:`random_truth` draws nominal-ish parameters with a seed (see there).
"""

from __future__ import annotations

import math
from collections.abc import Sequence as Seq
from typing import NamedTuple

import numpy as np

from calibration.preset_names import PRESETS
from calibration.sequence import Sequence, load_sequence
from calibration.simulate import SessionNoise, configuration_of
from fdi.calfile import Calibration, SensorCal, SensorSet, tangent_basis
from fdi.errors import ConfigError
from fdi.geometry import Configuration, cone6, tetrad
from fdi.parity import calibrated_axes
from fdi.units import DPS, MG, input_unit_factor, scale_factor_to_si

__all__ = ["PRESETS", "Preset", "default_sequence_name", "make_sensor_set", "preset",
           "random_truth"]





class Preset(NamedTuple):
    """What :func:`preset` returns; unpacks as ``sequence, truth, noise``."""

    sequence: Sequence
    truth: Calibration
    noise: SessionNoise

    @property
    def config(self) -> Configuration:
        """Nominal gyro configuration (names, groups) of the truth."""
        return configuration_of(self.truth.gyro, self.truth.configuration)

    @property
    def accel_config(self) -> Configuration | None:
        """Nominal accelerometer configuration, or None without accelerometers."""
        a = self.truth.sets.get("accel")
        return None if a is None else configuration_of(a, self.truth.configuration)


# seed 000 Eq. 26
_M1 = np.array([[0.9999895, -0.0019974, 0.0041171],
                [0.0004597, 0.9999998, -0.0004378],
                [-0.0009892, 0.0003843, 0.9999994]])
_M2 = np.array([[0.99999, 0.0010024, 0.0016921]])
# seed 000 Table 2, tetrad calibration (+10 °/s)
_TETRAD_SF_MV_DPS = (26.6259, 26.0274, 26.0730, 26.7118)
_TETRAD_BIAS_DPS = (0.0015563, 0.0024357, 0.0031409, 0.0015402)
TETRAD_NOISE_DPS = 0.01
"""Per-sample white noise of the tetrad-paper FOGs (°/s at 100 Hz)."""

# seed 001 Table 3: off-diagonal misalignment terms (row i: m_ix, m_iy, m_iz; diagonal None)
_CONE_GYRO_M = (
    ((None, -1.8872e-2, -3.9341e-3),     # printed -1.8872e-1, see module docstring
     (-6.8270e-3, None, 3.6380e-3),
     (-8.5066e-5, -1.7047e-3, None)),
    ((None, -2.7609e-2, -9.7901e-3),
     (-6.5264e-3, None, -7.9822e-3),
     (-5.9459e-3, -1.0184e-2, None)),
)
_CONE_ACCEL_M = (
    ((None, 2.2858e-2, -1.6705e-2),
     (1.0886e-2, None, 4.4292e-3),
     (1.3533e-2, -3.6061e-3, None)),
    ((None, 1.2791e-2, -1.2181e-2),
     (-1.4933e-2, None, 2.1193e-2),
     (-2.3119e-3, 5.6244e-4, None)),
)
_CONE_GYRO_SF = (3.8228e-1, 3.9791e-1, 3.8469e-1, 3.8673e-1, 3.9207e-1, 3.8685e-1)
_CONE_GYRO_BIAS = (1.9091e2, 2.0820e2, 1.9168e2, 1.8354e2, 1.9367e2, 1.8348e2)
_CONE_ACCEL_SF = (2.2498e-4, 2.1681e-4, 2.3295e-4, 1.8836e-4, 1.8858e-4, 1.8847e-4)
_CONE_ACCEL_BIAS = (3.6463, 4.0643, 4.1861, 3.9279, 3.2673, 3.5403)
CONE_GYRO_NOISE_DPS = 0.3
"""Per-sample white noise of the cone-paper gyros (°/s at 100 Hz)."""
CONE_ACCEL_NOISE_MG = 1.0
"""Per-sample white noise of the cone-paper accelerometers (mg at 100 Hz)."""


def _unit_rows_m(off: tuple) -> np.ndarray:
    """Misalignment matrix from off-diagonal terms, diagonals making unit rows."""
    M = np.zeros((3, 3))
    for i, row in enumerate(off):
        s2 = sum(v * v for v in row if v is not None)
        for j, v in enumerate(row):
            M[i, j] = math.sqrt(1.0 - s2) if v is None else v
    return M


def _group_matrices(H: np.ndarray, Ht: np.ndarray,
                    groups: tuple[tuple[int, ...], ...]) -> tuple[np.ndarray, ...]:
    """M per group as the papers print it: H̃_g = M·H_g (3 sensors) or H̃_g itself."""
    out = []
    for g in groups:
        idx = list(g)
        if len(idx) == 3 and abs(np.linalg.det(H[idx])) > 1e-9:
            out.append(Ht[idx] @ np.linalg.inv(H[idx]))
        else:
            out.append(Ht[idx].copy())
    return tuple(out)


def make_sensor_set(kind: str, config: Configuration, axes: np.ndarray,
                    scale_factors: Seq[float], scale_factor_unit: str,
                    biases: Seq[float], bias_unit: str, noise_sd: Seq[float] | float,
                    raw_unit: str) -> SensorSet:
    """A true :class:`SensorSet` (all sd fields 0) from values in file units.

    Parameters
    ----------
    kind : str
        ``"gyro"`` or ``"accel"``.
    config : Configuration
        Nominal axes, names and groups.
    axes : ndarray, shape (n, 3)
        True axes (normalised here).
    scale_factors : sequence of float
        In ``scale_factor_unit`` (e.g. ``"mV/(deg/s)"``).
    biases : sequence of float
        In ``bias_unit``.
    noise_sd : float or sequence of float
        Per-sample white-noise standard deviation, SI (rad/s or m/s²).
    raw_unit : str
    """
    Ht = np.asarray(axes, float)
    Ht = Ht / np.linalg.norm(Ht, axis=1, keepdims=True)
    n = config.n
    bf = input_unit_factor(bias_unit)
    sd = np.broadcast_to(np.asarray(noise_sd, float), (n,))
    sensors = tuple(
        SensorCal(name=config.sensor_names[i], axis=Ht[i], axis_nominal=config.H[i].copy(),
                  scale_factor=scale_factor_to_si(float(scale_factors[i]), scale_factor_unit),
                  scale_factor_sd=0.0, bias=float(biases[i]) * bf, bias_sd=0.0,
                  raw_unit=raw_unit, scale_factor_unit=scale_factor_unit, bias_unit=bias_unit)
        for i in range(n))
    return SensorSet(kind, sensors, np.diag(sd**2), tuple(config.groups),
                     _group_matrices(config.H, Ht, config.groups))


def _tetrad_paper() -> Preset:
    cfg = tetrad()
    Ht = calibrated_axes(cfg.H, cfg.groups, [_M1, _M2])      # seed 000 Eq. 14, 26
    gyro = make_sensor_set("gyro", cfg, Ht, _TETRAD_SF_MV_DPS, "mV/(deg/s)",
                           _TETRAD_BIAS_DPS, "deg/s", TETRAD_NOISE_DPS * DPS, "mV")
    cal = Calibration("tetrad", {"gyro": gyro}, 100.0, latitude_deg=-23.2,
                      extra={"preset": "tetrad-paper"})
    return Preset(load_sequence("tetrad-paper"), cal, SessionNoise())


def _cone_paper() -> Preset:
    cfg = cone6()
    sets = {}
    for kind, mats, sf, sfu, b, bu, sd in (
            ("gyro", _CONE_GYRO_M, _CONE_GYRO_SF, "(deg/s)/LSB", _CONE_GYRO_BIAS, "deg/s",
             CONE_GYRO_NOISE_DPS * DPS),
            ("accel", _CONE_ACCEL_M, _CONE_ACCEL_SF, "(g)/LSB", _CONE_ACCEL_BIAS, "g",
             CONE_ACCEL_NOISE_MG * MG)):
        Ms = [_unit_rows_m(m) for m in mats]
        Ht = calibrated_axes(cfg.H, cfg.groups, Ms)           # seed 001 Eq. 1
        sets[kind] = make_sensor_set(kind, cfg, Ht, sf, sfu, b, bu, sd, "LSB")
    cal = Calibration("cone6", sets, 100.0, latitude_deg=37.5,
                      extra={"preset": "cone-paper"})
    return Preset(load_sequence("cone-paper"), cal, SessionNoise())


def preset(name: str) -> Preset:
    """A preset: (sequence, truth, noise model), also ``.config`` and ``.accel_config``.

    Names: :data:`PRESETS`.

    Raises
    ------
    ConfigError
        Unknown name.
    """
    key = name.replace("_", "-")
    if key == "tetrad-paper":
        return _tetrad_paper()
    if key == "cone-paper":
        return _cone_paper()
    raise ConfigError(f"unknown preset {name!r}; expected one of {', '.join(sorted(PRESETS))}")


def default_sequence_name(config: Configuration) -> str:
    """``tetrad-paper`` for the tetrad, ``cone-paper`` (rates along x, y, z and positions
    along ±x, ±y, ±z: enough excitation for any axes) otherwise."""
    return "tetrad-paper" if config.name == "tetrad" else "cone-paper"


def random_truth(config: Configuration, *, seed: int | None = 0,
                 accelerometers: bool | None = None, latitude_deg: float | None = None,
                 sample_rate_hz: float = 100.0) -> Calibration:
    """Nominal-ish true parameters drawn with a seed.

    FOG-like for the ``tetrad`` (gyros only): SF 25 mV/(°/s) × (1 + 0.03·N), bias N(0, 10 °/h),
    noise 0.01 °/s per sample. MEMS-like otherwise (gyros and, by default, accelerometers on
    the same axes): gyro SF 0.39 (°/s)/LSB × (1 + 0.03·N), bias 190 + N(0, 10) °/s, noise
    0.3 °/s; accelerometer SF 2e-4 g/LSB × (1 + 0.05·N), bias 3.6 + N(0, 0.3) g, noise 1 mg.
    Misalignment: each true axis is the nominal one tilted by two N(0, σ²) angles along its
    tangent basis (:func:`fdi.calfile.tangent_basis`), σ = 2 mrad (FOG) or 5 mrad (MEMS).
    Latitude default −23.2° (tetrad) or 37.5°.
    """
    rng = np.random.default_rng(seed)
    fog = config.name == "tetrad"
    if accelerometers is None:
        accelerometers = not fog
    lat = latitude_deg if latitude_deg is not None else (-23.2 if fog else 37.5)
    n = config.n

    def tilt(sigma: float) -> np.ndarray:
        Ht = np.empty((n, 3))
        for i in range(n):
            d = rng.normal(0.0, sigma, 2)
            Ht[i] = config.H[i] + tangent_basis(config.H[i]).T @ d
        return Ht

    sets = {}
    if fog:
        sets["gyro"] = make_sensor_set(
            "gyro", config, tilt(2e-3), 25.0 * (1 + 0.03 * rng.standard_normal(n)),
            "mV/(deg/s)", rng.normal(0.0, 10.0, n), "deg/h", TETRAD_NOISE_DPS * DPS, "mV")
    else:
        sets["gyro"] = make_sensor_set(
            "gyro", config, tilt(5e-3), 0.39 * (1 + 0.03 * rng.standard_normal(n)),
            "(deg/s)/LSB", 190.0 + rng.normal(0.0, 10.0, n), "deg/s",
            CONE_GYRO_NOISE_DPS * DPS, "LSB")
    if accelerometers:
        sets["accel"] = make_sensor_set(
            "accel", config, tilt(2e-3 if fog else 5e-3),
            2e-4 * (1 + 0.05 * rng.standard_normal(n)), "(g)/LSB",
            3.6 + rng.normal(0.0, 0.3, n), "g", CONE_ACCEL_NOISE_MG * MG, "LSB")
    if not math.isfinite(lat):
        raise ConfigError(f"latitude must be finite, got {lat}")
    return Calibration(config.name, sets, float(sample_rate_hz), latitude_deg=float(lat),
                       extra={"preset": None, "random_seed": seed})


