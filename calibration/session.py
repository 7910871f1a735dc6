"""A turntable calibration session in memory.

A session is a sequence of steps (seed 000 Table 1, seed 001 Tables 1-2, or the user's
own): in a *rate* step one table axis turns at constant rate; in a *position* step the
table stands still. Samples carry the table angles and rates and the raw outputs of every
sensor. Reading and writing sessions on disk lives in :mod:`calibration.session_io`.

Shapes: N samples, n_g gyros, n_a accelerometers, S steps. Angles rad, rates rad/s, time s.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calibration.turntable import body_inputs
from fdi.geometry import Configuration

__all__ = ["Session", "Step"]


@dataclass(frozen=True)
class Step:
    """One step of a test sequence.

    Attributes
    ----------
    index : int
        1-based step number (as the papers number them).
    kind : str
        ``"rate"`` or ``"position"``.
    mat_pb : ndarray, shape (3, 3)
        Mounting of the IMU on the inner plate during this step.
    label : str
        Free text (``"+w inner"``, ``"Table 1 row 7"``).
    pair : int or None
        For rate steps: the 1-based index of the opposite-rate step it is differenced with
        (seed 000 Eq. 16, seed 001 Eq. 12), or None.
    """

    index: int
    kind: str
    mat_pb: np.ndarray
    label: str = ""
    pair: int | None = None


@dataclass(frozen=True)
class Session:
    """Samples of a calibration session.

    Attributes
    ----------
    gyro_config : Configuration
        Nominal gyro axes and subsystems.
    accel_config : Configuration or None
        Nominal accelerometer axes, when the IMU has accelerometers.
    sample_rate_hz : float
    latitude_deg : float
    steps : tuple of Step
    t : ndarray, shape (N,)
        Time (s).
    step : ndarray of int, shape (N,)
        1-based step number of each sample.
    inner, outer : ndarray, shape (N,)
        Table angles (rad).
    inner_rate, outer_rate : ndarray, shape (N,)
        Table rates (rad/s).
    raw_gyro : ndarray, shape (N, n_g)
        Raw gyro outputs (sensor units).
    raw_accel : ndarray, shape (N, n_a) or None
    gyro_raw_unit, accel_raw_unit : str
        Raw output units (``"mV"``, ``"LSB"``).
    gravity : float or None
        Local gravity (m/s²); normal gravity at the latitude when None.
    source : str
        Where the session came from (path or ``"<memory>"``), for error messages.
    temperature_degC : ndarray, shape (N,) or (N, n_g), or None
        Sensor temperature (°C): one column for the whole set, or one per gyro.
    """

    gyro_config: Configuration
    accel_config: Configuration | None
    sample_rate_hz: float
    latitude_deg: float
    steps: tuple[Step, ...]
    t: np.ndarray
    step: np.ndarray
    inner: np.ndarray
    outer: np.ndarray
    inner_rate: np.ndarray
    outer_rate: np.ndarray
    raw_gyro: np.ndarray
    raw_accel: np.ndarray | None = None
    gyro_raw_unit: str = "raw"
    accel_raw_unit: str = "raw"
    gravity: float | None = None
    source: str = "<memory>"
    meta: dict = field(default_factory=dict)
    temperature_degC: np.ndarray | None = None

    def step_slice(self, index: int) -> np.ndarray:
        """Boolean mask of the samples of step ``index`` (1-based)."""
        return self.step == index

    def inputs(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Exact MB-frame inputs at every sample: (ω_table_b, ω_earth_b, f_b), each (N, 3).

        Uses each step's mounting; see :func:`calibration.turntable.body_inputs`.
        """
        N = self.t.shape[0]
        wt, we, fb = np.zeros((N, 3)), np.zeros((N, 3)), np.zeros((N, 3))
        lat = np.deg2rad(self.latitude_deg)
        for s in self.steps:
            m = self.step == s.index
            if not m.any():
                continue
            a, b, c = body_inputs(self.inner[m], self.outer[m], self.inner_rate[m],
                                  self.outer_rate[m], s.mat_pb, lat, self.gravity)
            wt[m], we[m], fb[m] = a, b, c
        return wt, we, fb
