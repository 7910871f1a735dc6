"""Simulated Ferraris sessions with their truth (for users planning a session, and tests).

A three-axis IMU with true axes, scale factors, biases and gyro g-sensitivity
(:class:`FerrarisTruth`) goes through the procedure of :mod:`calibration.ferraris` the way a
hand-held session does: each position is tilted by a random angle (sd ``position_sd_deg``
per component) about a random heading, each rotation turns the unit about the *vertical*
(the tilted axis) by the nominal angle plus a random error (sd ``angle_sd_deg``), the Earth
rate acts with the heading of each position, and every sample gets white noise. A rotation
follows a raised-cosine rate profile (zero rate and acceleration at both ends) framed by rest.
The calibration's stated sds are then honest by construction when the simulated sds equal
the stated ones, which is what the Monte Carlo test checks.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calibration.ferraris import POSITIONS, ROTATIONS, FerrarisOptions, FerrarisSession
from fdi.units import DEG, EARTH_RATE

__all__ = ["FerrarisTruth", "imucal_like_truth", "simulate_ferraris"]


@dataclass(frozen=True)
class FerrarisTruth:
    """True parameters of a three-axis IMU (SI; raw outputs in counts).

    Attributes
    ----------
    gyro_axes, accel_axes : ndarray, shape (3, 3)
        Unit input axes (rows).
    gyro_sf, accel_sf : ndarray, shape (3,)
        Input per count (rad/s, m/s²).
    gyro_bias, accel_bias : ndarray, shape (3,)
        Input units.
    g_sensitivity : ndarray, shape (3, 3)
        Gyro counts per m/s² of specific force (rows: gyros).
    gyro_noise, accel_noise : float
        Per-sample white-noise sd (input units).
    """

    gyro_axes: np.ndarray
    accel_axes: np.ndarray
    gyro_sf: np.ndarray
    accel_sf: np.ndarray
    gyro_bias: np.ndarray
    accel_bias: np.ndarray
    g_sensitivity: np.ndarray
    gyro_noise: float
    accel_noise: float


def _unit_rows(M: np.ndarray) -> np.ndarray:
    return M / np.linalg.norm(M, axis=1, keepdims=True)


def imucal_like_truth(seed: int = 0) -> FerrarisTruth:
    """A MEMS unit like imucal's example (≈16.4 counts per °/s, ≈208 counts per m/s²,
    axes within about 1.5° of nominal), drawn from ``seed``."""
    rng = np.random.default_rng(seed)
    return FerrarisTruth(
        gyro_axes=_unit_rows(np.eye(3) + rng.normal(0, 0.015, (3, 3)) * (1 - np.eye(3))),
        accel_axes=_unit_rows(np.eye(3) + rng.normal(0, 0.015, (3, 3)) * (1 - np.eye(3))),
        gyro_sf=DEG / 16.4 * (1 + rng.normal(0, 0.01, 3)),
        accel_sf=1 / 208.5 * (1 + rng.normal(0, 0.01, 3)),
        gyro_bias=rng.normal(0, 0.3, 3) * DEG, accel_bias=rng.normal(0, 0.2, 3),
        g_sensitivity=rng.normal(0, 0.01, (3, 3)),
        gyro_noise=3.0 * DEG / 16.4, accel_noise=6.5 / 208.5)


def _tilted_up(e: np.ndarray, sd: float, rng: np.random.Generator) -> np.ndarray:
    """Body-frame Up: nominal ``e`` tilted by two normal components of sd ``sd`` (rad)."""
    h1 = np.cross(e, [1.0, 0.0, 0.0] if abs(e[0]) < 0.9 else [0.0, 1.0, 0.0])
    h1 /= np.linalg.norm(h1)
    h2 = np.cross(e, h1)
    u = e + sd * (rng.standard_normal() * h1 + rng.standard_normal() * h2)
    return u / np.linalg.norm(u)


def _earth_in_body(up: np.ndarray, heading: np.ndarray, lat: float) -> np.ndarray:
    """Earth rate in the body frame for a body Up and headings (rad), shape (len, 3)."""
    h1 = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    h1 /= np.linalg.norm(h1)
    h2 = np.cross(up, h1)
    north = np.cos(heading)[:, None] * h1 + np.sin(heading)[:, None] * h2
    return EARTH_RATE * (np.cos(lat) * north + np.sin(lat) * up)


def simulate_ferraris(truth: FerrarisTruth, *, seed: int = 0, sample_rate_hz: float = 100.0,
                      options: FerrarisOptions | None = None, static_s: float = 7.0,
                      rotation_s: float = 3.0, rest_s: float = 0.5,
                      latitude_deg: float = 49.6) -> FerrarisSession:
    """Simulate a Ferraris session (positions, then rotations) in raw counts.

    Parameters
    ----------
    truth : FerrarisTruth
    seed : int
    sample_rate_hz : float
    options : FerrarisOptions
        Nominal angle, gravity and the procedure's sds the simulation draws from.
    static_s, rotation_s, rest_s : float
        Duration of each position, of each rotation's motion and of the rest before and
        after it (s).
    latitude_deg : float
    """
    opt = FerrarisOptions() if options is None else options
    rng = np.random.default_rng(seed)
    fs, g = float(sample_rate_hz), opt.gravity
    d, eps = np.deg2rad(opt.position_sd_deg), np.deg2rad(opt.angle_sd_deg)
    lat = np.deg2rad(latitude_deg)
    e = np.eye(3)
    omegas, forces, sections, n0 = [], [], {}, 0
    for name, k in zip(POSITIONS, (0, 0, 1, 1, 2, 2), strict=True):
        up = _tilted_up(e[k] * (1 if name.endswith("_p") else -1), d, rng)
        n = round(static_s * fs)
        omegas.append(_earth_in_body(up, np.full(n, rng.uniform(0, 2 * np.pi)), lat))
        forces.append(np.tile(g * up, (n, 1)))
        sections[name] = np.arange(n0, n0 + n)
        n0 += n
    theta0 = np.deg2rad(opt.rotation_deg)
    for name, k in zip(ROTATIONS, range(3), strict=True):
        up = _tilted_up(e[k], d, rng)
        angle = theta0 + eps * rng.standard_normal()
        n_rest, n_mov = round(rest_s * fs), round(rotation_s * fs)
        tau = np.arange(n_mov) / n_mov
        rate = np.concatenate([np.zeros(n_rest), angle * fs / n_mov
                               * (1 - np.cos(2 * np.pi * tau)), np.zeros(n_rest)])
        turned = np.concatenate([[0.0], np.cumsum(rate)[:-1] / fs])
        n = rate.size
        psi = rng.uniform(0, 2 * np.pi) - turned
        omegas.append(rate[:, None] * up + _earth_in_body(up, psi, lat))
        forces.append(np.tile(g * up, (n, 1)))
        sections[name] = np.arange(n0, n0 + n)
        n0 += n
    w, f = np.vstack(omegas), np.vstack(forces)
    N = w.shape[0]
    gyro = ((w @ truth.gyro_axes.T + truth.gyro_bias
             + truth.gyro_noise * rng.standard_normal((N, 3))) / truth.gyro_sf
            + f @ truth.g_sensitivity.T)
    accel = (f @ truth.accel_axes.T + truth.accel_bias
             + truth.accel_noise * rng.standard_normal((N, 3))) / truth.accel_sf
    return FerrarisSession(sample_rate_hz=fs, gyro=gyro, accel=accel, sections=sections,
                           gyro_raw_unit="count", accel_raw_unit="count",
                           source=f"<simulated Ferraris session, seed {seed}>")
