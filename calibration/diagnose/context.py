"""What the diagnosis works on: per sensor kind, the residual of a session under a calibration.

For each kind (gyros, and accelerometers when both the session and the calibration have
them) and every sample of the session::

    y_i = SF_i·u_i − b_i − h̃_i·x          (SI; seed 000 Eq. 13 rearranged)

with ``x`` the exact body input (table rate + Earth rate for gyros, specific force for
accelerometers) and ``SF``, ``b``, ``h̃`` the calibration's. Candidate effects build their
regressors from the same arrays (:class:`KindData`), so a user effect sees exactly what the
built-in ones see.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calibration.session import Session
from fdi.calfile import Calibration
from fdi.errors import ConfigError

__all__ = ["SAME_SESSION_RTOL", "KindData", "check_match", "check_same_session", "kind_data"]

SAME_SESSION_RTOL = 1e-6
"""Relative agreement of the recomputed gyro residual RMS with the calibration's for the
calibration to count as made from this session (another session of the same sensors
differs by sampling noise, about 1/sqrt(2N), 3e-3 for 58k samples)."""


@dataclass(frozen=True)
class KindData:
    """One sensor kind of a session, with the calibration's residual.

    Attributes
    ----------
    kind : str
        ``"gyro"`` or ``"accel"``.
    names : tuple of str
        Sensor names.
    raw : ndarray, shape (N, n)
        Raw outputs.
    scale_factor, bias : ndarray, shape (n,)
        The calibration's SF (SI input per raw unit) and bias (SI).
    H : ndarray, shape (n, 3)
        The calibration's axes.
    x : ndarray, shape (N, 3)
        Body input (rad/s for gyros: table + Earth rate; m/s² for accelerometers).
    x_dot : ndarray, shape (N, 3)
        Time derivative of ``x`` within each step (per s).
    earth : ndarray, shape (N, 3)
        Earth rate in the body frame (rad/s).
    force : ndarray, shape (N, 3)
        Specific force in the body frame (m/s²).
    s : ndarray, shape (N, n)
        Input along each calibrated axis, ``x @ H.T``.
    y : ndarray, shape (N, n)
        Residual ``SF·u − b − s`` (SI).
    t : ndarray, shape (N,)
        Time since the first sample (s).
    step : ndarray of int, shape (N,)
        1-based step numbers.
    steps : tuple of int
        The steps present, in session order.
    temperature : ndarray, shape (N, n), or None
        Temperature per sensor (°C), None when the session has none.
    table_rate : float
        The sequence's table rate (rad/s; the largest table rate of the session).
    sample_rate_hz : float
    mount : ndarray of int, shape (N,)
        Index of the mounting of the IMU on the plate (0 for the first one met).
    """

    kind: str
    names: tuple[str, ...]
    raw: np.ndarray
    scale_factor: np.ndarray
    bias: np.ndarray
    H: np.ndarray
    x: np.ndarray
    x_dot: np.ndarray
    earth: np.ndarray
    force: np.ndarray
    s: np.ndarray
    y: np.ndarray
    t: np.ndarray
    step: np.ndarray
    steps: tuple[int, ...]
    temperature: np.ndarray | None
    table_rate: float
    sample_rate_hz: float
    mount: np.ndarray

    @property
    def n(self) -> int:
        """Number of sensors."""
        return self.raw.shape[1]

    @property
    def N(self) -> int:
        """Number of samples."""
        return self.raw.shape[0]

    @property
    def duration_s(self) -> float:
        """Session length as the simulator counts it (N / fs)."""
        return self.N / self.sample_rate_hz


def check_match(session: Session, cal: Calibration, cal_path: str = "<calibration>") -> None:
    """Refuse a calibration made for another configuration or another session.

    Raises
    ------
    ConfigError
        One line naming the calibration file and the field that disagrees.
    """
    def fail(field: str, what: str) -> ConfigError:
        return ConfigError(f"{cal_path}, field {field}: {what}; expected a calibration of "
                           f"session {session.source}")

    if "gyro" not in cal.sets:
        raise fail("sensors.gyro", "the calibration has no gyros")
    kinds = [("gyro", session.gyro_config, session.gyro_raw_unit)]
    if session.raw_accel is not None and session.accel_config is not None \
            and "accel" in cal.sets:
        kinds.append(("accel", session.accel_config, session.accel_raw_unit))
    for kind, cfg, unit in kinds:
        s = cal.sets[kind]
        names = tuple(c.name for c in s.sensors)
        if s.n != cfg.n or names != tuple(cfg.sensor_names):
            raise fail(f"sensors.{kind}", f"sensors {', '.join(names)} do not match the "
                       f"session's {', '.join(cfg.sensor_names)} (another configuration)")
        if not np.allclose(s.H_nominal, cfg.H, atol=1e-6):
            raise fail(f"sensors.{kind}.axis_nominal", "nominal axes differ from the "
                       "session's (another configuration)")
        if any(c.raw_unit != unit for c in s.sensors):
            raise fail(f"sensors.{kind}.raw_unit", f"raw unit differs from the session's "
                       f"{unit!r}")
    if cal.configuration and cal.configuration != session.gyro_config.name:
        raise fail("configuration", f"{cal.configuration!r}, the session's configuration is "
                   f"{session.gyro_config.name!r}")
    if not np.isclose(cal.sample_rate_hz, session.sample_rate_hz, rtol=1e-9):
        raise fail("sample_rate_hz", f"{cal.sample_rate_hz:g} Hz, the session's is "
                   f"{session.sample_rate_hz:g} Hz")



def check_same_session(datas: dict[str, KindData], cal: Calibration, source: str,
                       cal_path: str = "<calibration>") -> None:
    """Refuse a calibration made from another session of the same configuration.

    The calibration stores each gyro's residual RMS; recomputed on the session it was made
    from it agrees to rounding, on any other session it differs by sampling noise. Sensors
    without a stored RMS (hand-made files) are not checked.

    Raises
    ------
    ConfigError
        One line naming the calibration file and the field.
    """
    d = datas["gyro"]
    for i, c in enumerate(cal.sets["gyro"].sensors):
        if not np.isfinite(c.residual_rms) or c.residual_rms <= 0:
            continue
        rms = float(np.sqrt(np.mean(d.y[:, i] ** 2)))
        if abs(rms / c.residual_rms - 1) > SAME_SESSION_RTOL:
            raise ConfigError(
                f"{cal_path}, field sensors.gyro[{i + 1}].residual_rms: {c.residual_rms:.6g} "
                f"but {rms:.6g} on session {source} (a calibration of another session); "
                "expected a calibration of this session (rimu calibrate it)")


def _derivative(x: np.ndarray, t: np.ndarray, step: np.ndarray) -> np.ndarray:
    """d x / d t within each contiguous run of one step (0 where a run is too short)."""
    out = np.zeros_like(x)
    edges = np.flatnonzero(np.diff(step)) + 1
    for a, b in zip(np.r_[0, edges], np.r_[edges, step.size], strict=True):
        if b - a >= 3:
            out[a:b] = np.gradient(x[a:b], t[a:b], axis=0)
    return out


def _temperature(session: Session, kind: str, n: int) -> np.ndarray | None:
    T = getattr(session, "temperature_degC", None)
    if T is None:
        return None
    T = np.asarray(T, float)
    if T.ndim == 1:
        return np.repeat(T[:, None], n, axis=1)
    if kind == "gyro" and T.shape[1] == n:
        return T
    return None                     # per-gyro columns say nothing about accelerometers


def kind_data(session: Session, cal: Calibration) -> dict[str, KindData]:
    """Residual data per kind (gyros first; accelerometers when both sides have them)."""
    wt, we, fb = session.inputs()
    t = np.asarray(session.t, float) - float(session.t[0])
    step = np.asarray(session.step)
    rates = np.abs(np.r_[session.inner_rate, session.outer_rate])
    w = float(np.max(rates)) if rates.size else 0.0
    _, first = np.unique(step, return_index=True)
    order = tuple(int(step[i]) for i in sorted(first))
    mats: list[np.ndarray] = []
    mount_of: dict[int, int] = {}
    for st in session.steps:
        j = next((k for k, m in enumerate(mats) if np.allclose(m, st.mat_pb, atol=1e-9)), None)
        if j is None:
            mats.append(np.asarray(st.mat_pb, float))
            j = len(mats) - 1
        mount_of[st.index] = j
    mount = np.array([mount_of.get(int(k), 0) for k in step], dtype=np.int64)
    out: dict[str, KindData] = {}
    todo = [("gyro", session.raw_gyro, session.gyro_config, wt + we)]
    if session.raw_accel is not None and "accel" in cal.sets \
            and session.accel_config is not None:
        todo.append(("accel", session.raw_accel, session.accel_config, fb))
    for kind, raw, cfg, x in todo:
        s = cal.sets[kind]
        raw = np.asarray(raw, float)
        H = s.H
        sx = x @ H.T
        y = raw * s.scale_factors - s.biases - sx
        out[kind] = KindData(
            kind=kind, names=tuple(cfg.sensor_names), raw=raw, scale_factor=s.scale_factors,
            bias=s.biases, H=H, x=x, x_dot=_derivative(x, t, step), earth=we, force=fb, s=sx,
            y=y, t=t, step=step, steps=order, temperature=_temperature(session, kind, s.n),
            table_rate=w, sample_rate_hz=float(session.sample_rate_hz), mount=mount)
    return out
