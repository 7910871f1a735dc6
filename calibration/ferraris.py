"""Known-angle rotation calibration (Ferraris et al. 1995, as imucal does it), with honest σ.

A three-axis IMU (3 gyros, 3 accelerometers) is held still in six positions, each with one
sensor axis pointing up or down (``x_p``: +x up, the x accelerometer reads +g; ``x_a``: −x
up), and turned by hand by a known angle about each axis (``x_rot``: in the ``x_p``
position about x by ``rotation_deg``, imucal's convention −360°: clockwise seen from above).
No turntable rate is known: the gyro gains come from the *integrated* rate over each
rotation, not from a constant-rate model. Model per sensor (rimu's, seed 000 Eq. 13)::

    accelerometer i:  u_i = a_i·f + c_i                  a_i = h̃_i/SF_i, c_i = b_i/SF_i
    gyro i:           u_i = a_i·ω + c_i + k_i·f          k_i: g-sensitivity (raw per m/s²)

Estimates, all linear in section means and sums (so their covariance is exact):

- accelerometers: least squares over the six position means with ``f_k = ±g·e_k``
  (seed 001 Eqs. 5-10), generalised: weighted by the covariance of each mean below;
- gyro offsets and g-sensitivity: weighted least squares of the six static means on
  ``[1, f_k]`` (2 spare degrees of freedom per gyro: a check);
- gyro gains: for rotation r with rotation vector ``ρ_r = θ_r·e_r`` and duration ``T_r``,
  ``Σ u_i/fs = a_i·ρ_r + (c_i + k_i·f_r)·T_r`` so ``a_i = P⁻ᵀ·(J_i − T·(c_i + k_i·f_r))``
  with ``P = [ρ_1 ρ_2 ρ_3]`` (exactly determined: 0 spare degrees of freedom).

Uncertainty of the procedure, not only of the noise. A hand-held Ferraris session has errors
no least-squares scatter can show: each position is tilted from the nominal axis by a small
angle (sd ``position_sd_deg`` per tilt component), each rotation stops ``angle_sd_deg`` off
the nominal angle, and the Earth rate (unknown heading) adds to every static gyro mean. These
enter as covariances of the section means and sums:

- static mean k of sensor i: ``σ_i²/N_k + g²·(δ²·|(I − e_k e_kᵀ)·a_i|² + δ⁴·(a_i·e_k)²)``
  (accelerometers, tilt δ: first order across the axis, second order along it),
  ``σ_i²/N_k`` plus the Earth rate (gyros: its vertical part flips sign with the position
  like a g-sensitivity along the axis, so it is removed with the latitude, or without one
  counted as an unknown common to the positions; its horizontal part has an unknown
  heading per position);
- rotation sum r of gyro i: ``σ_i²·N_r/fs² + (a_i·e_r)²·ε² + θ_r²·(δ²·|(I − e_r e_rᵀ)·a_i|²
  + δ⁴·(a_i·e_r)²) + |a_i|²·Ω²·T_r²/3`` (angle error ε, rotation axis tilted by δ);

and the tilt shortens the input along the nominal axis on average, ``E[cos τ] = 1 − δ²``: the
nominal inputs ``f_k`` and ``ρ_r`` are scaled by it (3·10⁻⁴ for δ = 1°);

then ``cov θ_i = P·C_i·Pᵀ`` and the unit-norm split (seed 000 Eq. 19). The stated sds are
assumptions about how the session was made; the accelerometer and gyro static fits have two
spare degrees of freedom per sensor, and their χ² (``extra["ferraris"]["chi2_dof"]``) checks
the stated position sd against the data (a warning when it fails at 0.1 %). Their defaults,
1° for both, describe a unit held against the edges of a box on a level table.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.stats

from calibration.multiposition import multiposition
from calibration.residuals import noise_covariance
from calibration.sensor_set import build_sensor_set, check_gains
from calibration.uncertainty import split_with_cov
from fdi.calfile import Calibration
from fdi.errors import CalibrationError
from fdi.extras import FERRARIS_LAYOUT, CalibrationExtras, FerrarisRecord, Method
from fdi.geometry import Configuration
from fdi.units import DEG, EARTH_RATE, G0

__all__ = ["POSITIONS", "RAW_LIMIT", "ROTATIONS", "SECTIONS", "FerrarisOptions",
           "FerrarisSession", "ferraris_calibrate", "position_inputs"]

RAW_LIMIT = 1e12
"""No raw output (counts of a 32-bit converter, or SI values) is beyond this: a larger value
is damage, refused before the fit would overflow."""

POSITIONS = ("x_p", "x_a", "y_p", "y_a", "z_p", "z_a")
"""Static positions: axis up (``_p``) or down (``_a``)."""
ROTATIONS = ("x_rot", "y_rot", "z_rot")
"""Rotations about x, y, z (in the ``_p`` position of that axis)."""
SECTIONS = POSITIONS + ROTATIONS
MIN_SECTION_SAMPLES = 10
"""Fewest samples a section may have."""


@dataclass(frozen=True)
class FerrarisSession:
    """Samples of a Ferraris session.

    Attributes
    ----------
    sample_rate_hz : float
    gyro, accel : ndarray, shape (N, 3)
        Raw outputs (any unit: counts, deg/s, m/s²).
    sections : dict of name to ndarray of int
        Sample indices of each of :data:`SECTIONS` (rotations: contiguous, the whole motion).
    gyro_raw_unit, accel_raw_unit : str
    source : str
        For error messages.
    """

    sample_rate_hz: float
    gyro: np.ndarray
    accel: np.ndarray
    sections: dict[str, np.ndarray]
    gyro_raw_unit: str = "raw"
    accel_raw_unit: str = "raw"
    source: str = "<memory>"


@dataclass(frozen=True)
class FerrarisOptions:
    """How the session was made (the procedure's own uncertainties).

    Attributes
    ----------
    rotation_deg : float
        Nominal rotation angle about each axis (imucal's −360: clockwise seen from above).
    gravity : float
        Local gravity (m/s²).
    position_sd_deg : float
        sd of each tilt component of a position and of a rotation axis (°).
    angle_sd_deg : float
        sd of each rotation angle (°).
    earth_rate : bool
        Count the Earth rate as an uncertainty of the gyro means (False: ignore it).
    latitude_deg : float or None
        Latitude (°): the vertical Earth rate is removed from the static gyro means; None:
        it is an uncertainty of unknown latitude.
    """

    rotation_deg: float = -360.0
    gravity: float = G0
    position_sd_deg: float = 1.0
    angle_sd_deg: float = 1.0
    earth_rate: bool = True
    latitude_deg: float | None = None


def position_inputs(g: float) -> np.ndarray:
    """Specific force (m/s²) in each of :data:`POSITIONS`, shape (6, 3)."""
    e = np.eye(3)
    return g * np.array([e[0], -e[0], e[1], -e[1], e[2], -e[2]])


def _perp(e: np.ndarray, a: np.ndarray) -> float:
    """|(I − e eᵀ)·a|²."""
    return float(a @ a - (e @ a) ** 2)


@dataclass(frozen=True)
class _Means:
    count: np.ndarray          # (6,) static samples
    u_gyro: np.ndarray         # (6, 3)
    u_accel: np.ndarray        # (6, 3)
    rot_count: np.ndarray      # (3,)
    rot_sum: np.ndarray        # (3, 3) Σ u/fs per rotation (rows) and gyro
    resid_gyro: np.ndarray     # static residuals about the section means
    resid_accel: np.ndarray


def _check_session(s: FerrarisSession) -> None:
    """Every section present, long enough, with finite samples."""
    missing = [k for k in SECTIONS if k not in s.sections]
    if missing:
        raise CalibrationError(f"{s.source}: sections {', '.join(missing)} missing; expected "
                               f"all of {', '.join(SECTIONS)}")
    few = [k for k in SECTIONS if len(s.sections[k]) < MIN_SECTION_SAMPLES]
    if few:
        raise CalibrationError(f"{s.source}: section {few[0]} has "
                               f"{len(s.sections[few[0]])} samples; expected at least "
                               f"{MIN_SECTION_SAMPLES}")
    used = np.concatenate([s.sections[k] for k in SECTIONS])
    for kind, raw in (("gyro", s.gyro), ("accel", s.accel)):
        bad = ~np.all(np.isfinite(raw[used]), axis=1)
        if bad.any():
            raise CalibrationError(f"{s.source}: non-finite {kind} sample (row "
                                   f"{int(used[bad][0]) + 1}); expected finite numbers")
        big = np.any(np.abs(raw[used]) > RAW_LIMIT, axis=1)
        if big.any():       # 1e308 in a damaged file: the fit would overflow
            raise CalibrationError(f"{s.source}: {kind} sample beyond any sensor's output "
                                   f"(row {int(used[big][0]) + 1}, magnitude over "
                                   f"{RAW_LIMIT:g}); a damaged file?")


def _means(s: FerrarisSession) -> _Means:
    _check_session(s)
    idx = [s.sections[k] for k in POSITIONS]
    ug = np.array([s.gyro[i].mean(axis=0) for i in idx])
    ua = np.array([s.accel[i].mean(axis=0) for i in idx])
    rg = np.concatenate([s.gyro[i] - m for i, m in zip(idx, ug, strict=True)])
    ra = np.concatenate([s.accel[i] - m for i, m in zip(idx, ua, strict=True)])
    rot = [s.sections[k] for k in ROTATIONS]
    return _Means(count=np.array([len(i) for i in idx], float), u_gyro=ug, u_accel=ua,
                  rot_count=np.array([len(i) for i in rot], float),
                  rot_sum=np.array([s.gyro[i].sum(axis=0) for i in rot]) / s.sample_rate_hz,
                  resid_gyro=rg, resid_accel=ra)


def _chi2(resid: np.ndarray, C: np.ndarray, dof: int) -> float:
    """``rᵀ·C⁺·r / dof`` (C the covariance of the residuals, rank ``dof``)."""
    return float(resid @ np.linalg.pinv(C, rcond=1e-10, hermitian=True) @ resid) / dof


def _tilt_var(a: np.ndarray, C_a: np.ndarray, F: np.ndarray,
              opt: FerrarisOptions) -> np.ndarray:
    """Variance (raw²) of the six position means of one accelerometer from position tilt.

    ``g²·(δ²·|(I − e eᵀ)·a|² + δ⁴·(a·e)²)`` per position; ``|(I − e eᵀ)·a|²`` is estimated
    without the bias that the estimate's own scatter ``C_a`` puts into it.
    """
    d = np.deg2rad(opt.position_sd_deg)
    out = np.zeros(F.shape[0])
    for k, f in enumerate(F):
        e = f / np.linalg.norm(f)
        Pe = np.eye(3) - np.outer(e, e)
        perp = max(_perp(e, a) - float(np.trace(Pe @ C_a @ Pe)), 0.0)
        out[k] = opt.gravity**2 * (d**2 * perp + d**4 * (e @ a) ** 2)
    return out


def _accel_fit(m: _Means, opt: FerrarisOptions, F: np.ndarray, source: str
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(θ (4, 3), cov (3, 4, 4), σ² raw (3, 3), χ²/dof (3,)) of the accelerometers.

    Generalised least squares per sensor with the covariance of the position means (noise
    plus position tilt, the tilt term evaluated at the ordinary least-squares gains): the
    positions where a sensor's axis is vertical, insensitive to tilt to first order, carry
    its offset and scale factor.
    """
    mp = multiposition(m.u_accel, m.count, F, step_numbers=list(range(1, 7)), source=source)
    Sigma = noise_covariance(m.resid_accel, dof_used=6)
    X = np.hstack([F, np.ones((6, 1))])
    theta, cov, chi2 = np.zeros((4, 3)), [], []
    for i in range(3):
        a, C_a = mp.a[i], np.zeros((3, 3))
        for _ in range(2):                       # the tilt terms need a: two passes
            v = Sigma[i, i] / m.count + _tilt_var(a, C_a, F, opt)
            Xw = X / v[:, None]
            C = np.linalg.inv(X.T @ Xw)                               # (XᵀV⁻¹X)⁻¹
            th = C @ Xw.T @ m.u_accel[:, i]
            a, C_a = th[:3], C[:3, :3]
        theta[:, i] = th
        cov.append(C)
        r = m.u_accel[:, i] - X @ th
        chi2.append(float(r @ (r / v)) / 2)
    return theta, np.array(cov), Sigma, np.array(chi2)


def _gyro_operator(m: _Means, F: np.ndarray, rho: np.ndarray,
                   fs: float) -> tuple[np.ndarray, np.ndarray]:
    """Operator P (7, 9): ``[a; c; k] = P @ [static means (6); rotation sums (3)]``, and the
    static-fit operator (4, 6) for the χ²."""
    X = np.hstack([np.ones((6, 1)), F])                               # (c, k) design
    W = m.count / m.count.sum()
    op_s = np.linalg.solve((X * W[:, None]).T @ X, (X * W[:, None]).T)  # (4, 6)
    T = m.rot_count / fs
    f_rot = F[[0, 2, 4]]                                              # x_p, y_p, z_p
    off = np.hstack([np.ones((3, 1)), f_rot]) @ op_s                  # (3, 6): c + k·f_r
    Pinv_T = np.linalg.inv(rho.T)                                     # a = P⁻ᵀ (J − T·off)
    A = np.hstack([-Pinv_T @ (T[:, None] * off), Pinv_T])             # (3, 9)
    P = np.vstack([A, np.hstack([op_s, np.zeros((4, 3))])])
    return P, op_s


def _earth_static(a: np.ndarray, U: np.ndarray,
                  opt: FerrarisOptions) -> tuple[np.ndarray, np.ndarray]:
    """Earth rate in one gyro's six static means: (known part (6,), covariance (6, 6)), raw.

    The vertical component ``Ω sin φ`` flips with the position (``a·Up_k``), like a
    g-sensitivity along the axis: with the latitude it is removed, without it it is an
    unknown common to the positions (``E[sin²φ] = 1/3``, fully correlated). The horizontal
    component (unknown heading per position) is independent between positions.
    """
    b = U @ a
    perp = float(a @ a) - b**2
    if not opt.earth_rate:
        return np.zeros(6), np.zeros((6, 6))
    if opt.latitude_deg is None:
        return np.zeros(6), EARTH_RATE**2 / 3 * (np.outer(b, b) + np.diag(perp))
    lat = np.deg2rad(opt.latitude_deg)
    return (EARTH_RATE * np.sin(lat) * b,
            np.diag(EARTH_RATE**2 * np.cos(lat) ** 2 / 2 * perp))


def _gyro_fit(m: _Means, opt: FerrarisOptions, F: np.ndarray, fs: float
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(θ (7, 3): a, c, k; cov (3, 7, 7); σ² raw (3, 3); static χ²/dof (3,)) of the gyros."""
    th = np.deg2rad(opt.rotation_deg)
    d = np.deg2rad(opt.position_sd_deg)
    rho = th * (1 - d**2) * np.eye(3)                 # columns ρ_r, E[cos tilt] = 1 − δ²
    P, op_s = _gyro_operator(m, F, rho, fs)
    D = np.vstack([m.u_gyro, m.rot_sum])                              # (9, 3)
    theta = P @ D
    U = F / np.linalg.norm(F, axis=1, keepdims=True)                  # Up per position
    earth = [_earth_static(theta[:3, i], U, opt) for i in range(3)]
    D[:6] -= np.array([sh for sh, _ in earth]).T                      # vertical Earth rate
    theta = P @ D
    Sigma = noise_covariance(m.resid_gyro, dof_used=6)
    eps = np.deg2rad(opt.angle_sd_deg)
    om2 = EARTH_RATE**2 / 3 if opt.earth_rate else 0.0
    T = m.rot_count / fs
    X = np.hstack([np.ones((6, 1)), F])
    cov, chi2 = [], []
    for i in range(3):
        a = theta[:3, i]
        C_static = np.diag(Sigma[i, i] / m.count) + earth[i][1]
        e = np.eye(3)
        v_rot = np.array([Sigma[i, i] * m.rot_count[r] / fs**2 + a[r] ** 2 * eps**2
                          + th**2 * (d**2 * _perp(e[r], a) + d**4 * a[r] ** 2)
                          + (a @ a) * om2 * T[r] ** 2 for r in range(3)])
        Cd = np.zeros((9, 9))
        Cd[:6, :6] = C_static
        Cd[6:, 6:] = np.diag(v_rot)
        cov.append(P @ Cd @ P.T)
        M = np.eye(6) - X @ op_s                                      # residual operator
        r_s = M @ D[:6, i]
        chi2.append(_chi2(r_s, M @ C_static @ M.T, 2))
    return theta, np.array(cov), Sigma, np.array(chi2)


def _unbiased_norm(a: np.ndarray, cov_a: np.ndarray) -> np.ndarray:
    """Gains with the second-order bias of their norm removed.

    Noise across ``a`` lengthens it on average, ``E|â| ≈ |a| + tr((I − ĥĥᵀ)·C)/(2|a|)``:
    small for a turntable, but a 1° position sd puts ≈ 1.5·10⁻⁴ into 1/SF, comparable to
    the accelerometer scale-factor sd. Rows of ``a`` (n, 3) are shortened by that amount.
    """
    out = np.array(a, float)
    for i, (ai, C) in enumerate(zip(out, cov_a, strict=True)):
        n2 = float(ai @ ai)
        h = ai / np.sqrt(n2)
        perp = float(np.trace(C) - h @ C @ h)
        out[i] = ai * (1.0 - perp / (2.0 * n2))
    return out


def _config(name: str, a: np.ndarray) -> Configuration:
    """Nominal axes ±e_i, the sign the estimate is nearest (an inverted axis stays one)."""
    s = np.sign(np.diag(a))
    s[s == 0] = 1.0
    return Configuration(name, np.diag(s), ("x", "y", "z"), ((0, 1, 2),))


def ferraris_calibrate(session: FerrarisSession,
                       options: FerrarisOptions | None = None) -> Calibration:
    """Calibrate the gyros and accelerometers of a Ferraris session.

    Returns
    -------
    Calibration
        Gyros and accelerometers (3 each, names x, y, z; rad/s and m/s² per raw unit);
        ``extra["ferraris"]``: the gyro g-sensitivity (raw per m/s², with sd), the stated
        procedure sds, χ²/dof of the static fits, and imucal's matrices from this fit
        (``K``, ``R``, ``b`` per kind in imucal's units: raw per deg/s or per m/s²).

    Raises
    ------
    CalibrationError
        Missing or short sections, non-finite samples, gains that cannot be split.
    """
    opt = FerrarisOptions() if options is None else options
    fs = float(session.sample_rate_hz)
    m = _means(session)
    # a position tilted by τ (two components of sd δ) feels g·cos τ along its nominal axis:
    # E[cos τ] = 1 − δ² to second order; the scatter of cos τ enters the variances
    F = position_inputs(opt.gravity) * (1 - np.deg2rad(opt.position_sd_deg) ** 2)
    ta, cov_a, Sig_a, chi_a = _accel_fit(m, opt, F, session.source)
    tg, cov_g, Sig_g, chi_g = _gyro_fit(m, opt, F, fs)
    sets, warnings = {}, []
    for kind, th, cov, Sig, resid, unit in (
            ("gyro", tg, cov_g, Sig_g, m.resid_gyro, session.gyro_raw_unit),
            ("accel", ta, cov_a, Sig_a, m.resid_accel, session.accel_raw_unit)):
        a, c = _unbiased_norm(th[:3].T, cov[:, :3, :3]), th[3]
        check_gains(session.source, kind, a, ("x", "y", "z"))
        cfg = _config("ferraris-imu", a)
        parts = split_with_cov(a, c, cov[:, :4, :4], cfg.H)
        sf = np.array([p.split.scale_factor for p in parts])
        sets[kind] = build_sensor_set(kind, cfg, unit, parts, resid * sf,
                                      Sig * np.outer(sf, sf), fs, allan=False,
                                      source=session.source)
    lim = float(scipy.stats.chi2.isf(1e-3, 2)) / 2
    for kind, chi in (("accel", chi_a), ("gyro", chi_g)):
        for i in np.flatnonzero(chi > lim):
            warnings.append(
                f"{kind} {'xyz'[i]}: the six position means scatter more than the noise and "
                f"the stated position sd explain (chi2/dof {chi[i]:.2f}, 0.1 % limit "
                f"{lim:.2f}); positions less accurate than stated or an unmodelled effect")
    extra = _extra(session, opt, tg, cov_g, sets, chi_a, chi_g, warnings)
    return Calibration(configuration="ferraris-imu", sets=sets, sample_rate_hz=fs,
                       earth_rate_dph=None, earth_rate_dph_sd=None, latitude_deg=None,
                       extra=extra)


def _imucal_matrices(s: Any, per_unit: float) -> dict[str, Any]:
    """imucal's K (diag, raw per unit), R (rows h̃) and b (raw) of a calibrated set."""
    K = np.array([1.0 / (c.scale_factor / per_unit) for c in s.sensors])
    return {"K": np.diag(K).tolist(), "R": s.H.tolist(),
            "b": [c.bias / c.scale_factor for c in s.sensors]}


def _extra(session: FerrarisSession, opt: FerrarisOptions, tg: np.ndarray,
           cov_g: np.ndarray, sets: dict, chi_a: np.ndarray, chi_g: np.ndarray,
           warnings: list[str]) -> dict[str, Any]:
    k_sd = np.sqrt(np.clip(np.diagonal(cov_g[:, 4:, 4:], axis1=1, axis2=2), 0, None))
    lat = None if opt.latitude_deg is None else opt.latitude_deg * DEG
    record = FerrarisRecord(
        rotation=opt.rotation_deg * DEG, gravity=opt.gravity,
        position_sd=opt.position_sd_deg * DEG, angle_sd=opt.angle_sd_deg * DEG,
        earth_rate_in_sd=opt.earth_rate, latitude=lat,
        g_sensitivity_raw_per_m_s2=_rows(tg[4:].T), g_sensitivity_raw_per_m_s2_sd=_rows(k_sd),
        chi2_dof={"accel": tuple(chi_a.tolist()), "gyro": tuple(chi_g.tolist())},
        chi2_dof_dof=2, rotation_dof=0,
        imucal={"gyro": _imucal_matrices(sets["gyro"], DEG),
                "accel": _imucal_matrices(sets["accel"], 1.0)})
    return CalibrationExtras(
        source=session.source,
        method=Method(parts={
            "gyro": "Ferraris: offsets and g-sensitivity from six static positions, gains "
                    "from the integrated rate over known-angle rotations",
            "accel": "six-position least squares (seed 001 Eqs. 5-10)"}),
        ferraris=record, warnings=tuple(warnings)).to_dict(FERRARIS_LAYOUT)


def _rows(a: np.ndarray) -> tuple[tuple[float, ...], ...]:
    return tuple(tuple(r) for r in np.asarray(a, float).tolist())
