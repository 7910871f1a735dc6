"""Two-axis turntable kinematics: what the sensors on the table feel.

Frames
------
- ``n``: local level, ENU (x East, y North, z Up). Earth rate in ``n`` is
  ``Ω·(0, cos φ, sin φ)``; specific force at rest is ``(0, 0, +g)``.
- Outer axis: vertical (``n`` z, Up). The outer angle ``a_o`` turns the outer gimbal about Up.
- Inner axis: horizontal, carried by the outer gimbal, along North when ``a_o = 0``. The inner
  angle ``a_i`` turns the inner plate about it (right-handed).
- ``b``: master body (MB) frame of the IMU, fixed on the inner plate through the mounting
  ``mat_pb`` (columns: body axes in plate coordinates; the plate frame equals ``n`` when both
  angles are zero).

So ``mat_nb = Rz(a_o) · Ry(a_i) · mat_pb`` and, in the body frame,

- table rate  ``ω_tb_b = mat_pbᵀ·(0, ȧ_i, 0) + mat_nbᵀ·(0, 0, ȧ_o)``,
- Earth rate  ``ω_ie_b = mat_nbᵀ·ω_ie_n``,
- specific force ``f_b = mat_nbᵀ·(0, 0, g)``.

Angles in rad, rates in rad/s, arrays of N samples have shape (N,) or (N, 3).
"""

from __future__ import annotations

import math

import numpy as np

from fdi.units import EARTH_RATE, G0

__all__ = [
    "MOUNTS",
    "body_inputs",
    "earth_rate_n",
    "gravity_local",
    "mat_nb",
]

MOUNTS: dict[str, np.ndarray] = {
    # Body X along the inner axis (North at a_o = 0), body Y Up, body Z = X × Y (East).
    # The tetrad of seed 000 sits this way: inner rate → X, outer rate → Y at a_i = 0.
    "x_inner_y_up": np.array([[0.0, 0.0, 1.0],
                              [1.0, 0.0, 0.0],
                              [0.0, 1.0, 0.0]]),
    # Body Z along the inner axis, body X Up, body Y = Z × X.
    "z_inner_x_up": np.array([[0.0, 1.0, 0.0],
                              [0.0, 0.0, 1.0],
                              [1.0, 0.0, 0.0]]),
    # Body axes aligned with the plate: X East, Y North (inner axis), Z Up (outer axis).
    "level": np.eye(3),
    # Body X along the inner axis (North at a_o = 0), body Z Up, body Y = Z × X (West).
    # Seed 001's table: "z-axis of the MB frame aligned with the table axis, x-axis with
    # the tilt axis".
    "x_inner_z_up": np.array([[0.0, -1.0, 0.0],
                              [1.0, 0.0, 0.0],
                              [0.0, 0.0, 1.0]]),
}
"""Named mountings ``mat_pb`` (body axes as columns, in plate coordinates)."""


def gravity_local(latitude_rad: float, height_m: float = 0.0) -> float:
    """Normal gravity (m/s²) at a latitude and height (WGS-84 Somigliana, free-air term)."""
    s2 = math.sin(latitude_rad) ** 2
    g = 9.7803253359 * (1 + 0.00193185265241 * s2) / math.sqrt(1 - 0.00669437999013 * s2)
    return g - 3.086e-6 * height_m if g > 0 else G0


def earth_rate_n(latitude_rad: float) -> np.ndarray:
    """Earth rate in the ENU frame (rad/s), shape (3,)."""
    return EARTH_RATE * np.array([0.0, math.cos(latitude_rad), math.sin(latitude_rad)])


def _rz(a: np.ndarray) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    z, o = np.zeros_like(a), np.ones_like(a)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1),
                     np.stack([z, z, o], -1)], -2)


def _ry(a: np.ndarray) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    z, o = np.zeros_like(a), np.ones_like(a)
    return np.stack([np.stack([c, z, s], -1), np.stack([z, o, z], -1),
                     np.stack([-s, z, c], -1)], -2)


def mat_nb(inner_rad: np.ndarray, outer_rad: np.ndarray, mat_pb: np.ndarray) -> np.ndarray:
    """Body-to-ENU direction cosines, shape (N, 3, 3)."""
    a_i = np.atleast_1d(np.asarray(inner_rad, float))
    a_o = np.atleast_1d(np.asarray(outer_rad, float))
    return _rz(a_o) @ _ry(a_i) @ np.asarray(mat_pb, float)


def body_inputs(inner_rad: np.ndarray, outer_rad: np.ndarray, inner_rate: np.ndarray,
                outer_rate: np.ndarray, mat_pb: np.ndarray, latitude_rad: float,
                g: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact inputs in the MB frame at each sample.

    Parameters
    ----------
    inner_rad, outer_rad : ndarray, shape (N,)
        Table angles (rad).
    inner_rate, outer_rate : ndarray, shape (N,)
        Table rates (rad/s).
    mat_pb : ndarray, shape (3, 3)
        Mounting of the body on the inner plate.
    latitude_rad : float
    g : float, optional
        Local gravity (m/s²); normal gravity at the latitude when omitted.

    Returns
    -------
    omega_table_b : ndarray, shape (N, 3)
        Angular rate of the body relative to the Earth (the commanded table motion).
    omega_earth_b : ndarray, shape (N, 3)
        Earth rate seen in the body frame.
    f_b : ndarray, shape (N, 3)
        Specific force (m/s²). Centripetal terms are neglected (IMU at the table centre).
    """
    C = mat_nb(inner_rad, outer_rad, mat_pb)                  # (N, 3, 3)
    Ct = np.swapaxes(C, -1, -2)
    pb = np.asarray(mat_pb, float)
    wi = np.atleast_1d(np.asarray(inner_rate, float))
    wo = np.atleast_1d(np.asarray(outer_rate, float))
    inner_axis_b = pb.T @ np.array([0.0, 1.0, 0.0])            # fixed in the body
    up_b = Ct[..., :, 2]                                       # Up in body, (N, 3)
    omega_table = wi[:, None] * inner_axis_b[None, :] + wo[:, None] * up_b
    omega_earth = Ct @ earth_rate_n(latitude_rad)
    gl = gravity_local(latitude_rad) if g is None else g
    f_b = gl * up_b
    return omega_table, omega_earth, f_b
