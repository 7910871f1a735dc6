"""Calibration of several IMUs at rest against one of them (``rimu calibrate static``).

A static recording excites no rotation, so the in-flight fit (:mod:`.fit`) cannot run. What
a set at rest does show:

- **biases**: each gyro's mean (rad/s; it holds the Earth rate's projection, at most
  7.3e-5 rad/s, which a set of MEMS gyros cannot tell from bias), sd from the scatter of
  :data:`BLOCKS` contiguous blocks;
- **alignment from gravity and the shared disturbances**: the mean specific force of each
  IMU (gravity in its frame) and the direction of the motion all IMUs see together (the
  first principal direction of all gyro axes when the correlation matrix has an
  eigenvalue above the Marchenko–Pastur edge, :func:`replay.ingest.characterise.common_mode`)
  give two vectors in each frame; the rotation of IMU j onto the reference is the
  least-squares fit of the pairs (Wahba's problem, ``scipy.spatial.transform.Rotation.
  align_vectors``), its sd from the scatter over blocks. With gravity alone the rotation
  about gravity is not observable: the minimal rotation is used and the note says so;
- **relative drift**: the trend of each IMU's residual ``r_j = y_j − b_j − H_j·ω̂_ref``
  over the record (:func:`replay.ingest.characterise_flight.slow_drift`), and
  :func:`attribute_drift`: what every IMU shares relative to the reference is the
  reference's own drift (it cannot be told apart from all others drifting together).

Scale factors are not observable at rest (taken as 1, sd 0, noted). The noise covariance,
the Allan table, the residual's tail and drift models and the range the samples covered
(rate, specific force, jolt) come from each IMU's rates with its mean removed, on the
samples at rest: shocks (a knock on the bench, :func:`at_rest`) are left out, so the
monitor marks them beyond the range instead of its thresholds covering them.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from scipy import stats
from scipy.spatial.transform import Rotation

from calibration.inflight.calfile import _sf_unit
from calibration.residual_models import with_residual_models
from calibration.residuals import allan_table
from fdi.calfile import Calibration, SensorCal, SensorSet, tangent_basis
from fdi.envelope import covered_jolt, covered_rate, covered_specific_force
from fdi.errors import CalibrationError, ConfigError
from fdi.extras import (
    STATIC_LAYOUT,
    CalibrationExtras,
    DriftAttribution,
    Method,
    OwnDrift,
    StaticAlignment,
    StaticImu,
    extras_from_dict,
)
from fdi.units import DEG, DPS
from replay.envelope import flight_accel
from replay.flight_data import Flight

__all__ = ["BLOCKS", "SCALE_FACTOR_TOLERANCE", "SHOCK_PAD_S", "SHOCK_SD", "STATIC_METHOD",
           "at_rest", "attribute_drift", "calibrate_static", "static_text"]

STATIC_METHOD = "static alignment to a reference IMU (calibration.inflight.static/1)"
BLOCKS = 10
SCALE_FACTOR_TOLERANCE = 0.03
"""Scale-factor uncertainty stated for every gyro of a static calibration (relative): rest
cannot observe a scale factor, so the calibration takes 1 ± this (a consumer MEMS gyro's
sensitivity tolerance, MPU9250 datasheet ±3 %). It enters the input-error covariance, so
the monitor's thresholds widen when the bench moves instead of taking the scale-factor
differences for a fault."""
"""Contiguous blocks whose scatter gives the sds."""
_MOVING_RPS = 0.05
SHOCK_SD = 8.0
"""A sample in which at least two IMUs depart from their record median by more than this
many robust sds (1.4826·MAD) on any gyro or accelerometer axis is a shock (a knock on the
bench: 4×MPU9250 at 186.76 s, accelerometers 140 sd, gyros 18 sd), not rest."""
SHOCK_PAD_S = 0.5
"""Samples this close to a shock are not rest either (the ringing after a knock)."""
_MIN_ANGLE_DEG = 15.0
"""Smallest angle between gravity and the shared motion for both to fix the rotation."""


def _groups(flight: Flight) -> dict[str, list[int]]:
    return flight.imu_triads("static calibration")


def _accel(flight: Flight, imu: str) -> np.ndarray | None:
    if flight.aux is None:
        return None
    a = flight.aux.select("accel")
    cols = [k for k, h in enumerate(a.imu) if h == imu]
    return a.values[:, cols] if len(cols) == 3 else None


def at_rest(x: np.ndarray, acc: Mapping[str, np.ndarray | None],
            groups: Mapping[str, list[int]], sample_rate_hz: float) -> np.ndarray:
    """Samples at rest: not within :data:`SHOCK_PAD_S` of a shock (:data:`SHOCK_SD`).

    Parameters
    ----------
    x : ndarray, shape (N, n)
        Gyro outputs (rad/s).
    acc : mapping of IMU name to ndarray, shape (N, 3), or None
        Each IMU's accelerometer (m/s²) on the same samples.
    groups : mapping of IMU name to its gyro columns
    sample_rate_hz : float

    Returns
    -------
    ndarray of bool, shape (N,)
    """
    def robust_out(a: np.ndarray) -> np.ndarray:
        med = np.median(a, axis=0)
        mad = 1.4826 * np.median(np.abs(a - med), axis=0)
        return np.any(np.abs(a - med) > SHOCK_SD * np.where(mad > 0, mad, np.inf), axis=1)

    hits = np.zeros((x.shape[0], len(groups)), int)
    for k, (g, idx) in enumerate(groups.items()):
        out = robust_out(x[:, idx])
        if acc.get(g) is not None:
            out |= robust_out(np.asarray(acc[g], float))
        hits[:, k] = out
    shock = hits.sum(axis=1) >= 2
    pad = max(0, round(SHOCK_PAD_S * sample_rate_hz))
    if pad and shock.any():
        shock = np.convolve(shock.astype(float), np.ones(2 * pad + 1), "same") > 0.5
    return ~shock


def _shared_direction(x: np.ndarray, groups: dict[str, list[int]]) -> dict[str, np.ndarray] | None:
    """Per IMU, the unit direction (its own frame) of the motion all IMUs see, or None."""
    from replay.ingest.characterise import common_mode

    xs = x - x.mean(axis=0)
    if common_mode(xs)["n_common"] < 1:
        return None
    _, V = np.linalg.eigh(np.cov(xs.T))
    v = V[:, -1]
    out = {}
    for g, idx in groups.items():
        u = v[idx]
        n = float(np.linalg.norm(u))
        if n == 0:
            return None
        out[g] = u / n
    return out


def _rotations(x: np.ndarray, acc: dict[str, np.ndarray | None], groups: dict[str, list[int]],
               ref: str) -> tuple[dict[str, Rotation], list[str], bool]:
    """Rotation of every IMU's frame onto the reference's (``v_ref = R·v_j``)."""
    notes: list[str] = []
    grav = {g: (a.mean(axis=0) / np.linalg.norm(a.mean(axis=0))) if a is not None else None
            for g, a in acc.items()}
    shared = _shared_direction(x, groups)        # one eigenvector: one sign for all IMUs
    full = True
    out = {}
    for g in groups:
        if g == ref:
            out[g] = Rotation.identity()
            continue
        a_ref, b_j, wts = [], [], []
        if grav[g] is not None and grav[ref] is not None:
            a_ref.append(grav[ref])
            b_j.append(grav[g])
            wts.append(1.0)
        if shared is not None:
            s_ref, s_j = shared[ref], shared[g]
            if a_ref:
                ang = math.degrees(math.acos(min(1.0, abs(float(
                    np.dot(grav[ref], s_ref))))))
                if ang >= _MIN_ANGLE_DEG:
                    a_ref.append(s_ref)
                    b_j.append(s_j)
                    wts.append(0.5)
            else:
                a_ref.append(s_ref)
                b_j.append(s_j)
                wts.append(1.0)
        if not a_ref:
            raise CalibrationError(f"{g}: no accelerometer and no shared motion: the "
                                   f"alignment is not observable at rest")
        if len(a_ref) == 1:
            full = False
        r, _ = Rotation.align_vectors(np.array(a_ref), np.array(b_j), weights=np.array(wts))
        out[g] = r
    if not full:
        notes.append("the rotation about gravity is not observable (no shared motion at an "
                     "angle to gravity): the smallest rotation that aligns gravity is used")
    return out, notes, full


def attribute_drift(rel: dict[str, np.ndarray], cov: dict[str, np.ndarray], ref: str, *,
                    alpha: float = 0.01) -> dict[str, Any]:
    """What of the IMUs' drifts relative to the reference is the reference's own.

    Parameters
    ----------
    rel : dict of str to ndarray (3,)
        Drift of each non-reference IMU relative to the reference, in the reference
        (body) frame: ``D_j − D_ref``.
    cov : dict of str to ndarray (3, 3)
        Their covariances.
    ref : str
    alpha : float

    Returns
    -------
    dict
        ``common`` (the weighted mean ``c = −D_ref`` estimate, body frame), ``common_sd``,
        ``common_p`` (Wald test that c = 0), ``consistent_p`` (χ² test that every IMU's
        relative drift equals c),
        ``own`` (per IMU its drift relative to the reference, z per axis and the χ² p that
        it is 0), ``statement``: which drift is whose (the reference's when every IMU
        drifts alike; an IMU's own when it drifts from the reference and from the IMUs
        that agree with it), and that the reference's drift cannot be told from every
        other IMU drifting together.
    """
    names = list(rel)
    W = {g: np.linalg.pinv(cov[g]) for g in names}
    S = sum(W.values())
    c = np.linalg.solve(S, sum(W[g] @ rel[g] for g in names))
    C = np.linalg.inv(S)
    chi2 = float(sum((rel[g] - c) @ W[g] @ (rel[g] - c) for g in names))
    dof = 3 * (len(names) - 1)
    p_cons = float(stats.chi2.sf(chi2, dof)) if dof > 0 else 1.0
    p_c = float(stats.chi2.sf(float(c @ S @ c), 3))
    own, moved = {}, []
    for g in names:
        d = rel[g]
        sd = np.sqrt(np.clip(np.diag(cov[g]), 1e-30, None))
        p_g = float(stats.chi2.sf(float(d @ W[g] @ d), 3))
        own[g] = {"drift": d.tolist(), "z": (d / sd).tolist(), "p_value": p_g}
        if p_g < alpha / len(names):
            moved.append(g)
    if len(names) < 2:
        statement = (f"with one IMU besides {ref}, a relative drift cannot be attributed: "
                     f"it is {names[0]}'s or {ref}'s")
    elif p_c < alpha and p_cons >= alpha:
        statement = (f"every IMU drifts alike relative to {ref}: that is {ref}'s own drift "
                     f"(it cannot be separated from all the others drifting together)")
    elif moved and len(moved) < len(names):
        rest = [g for g in names if g not in moved]
        statement = (f"{', '.join(moved)} drift{'s' if len(moved) == 1 else ''} relative to "
                     f"{ref} and to {', '.join(rest)} (which agree with {ref}): "
                     f"{'its' if len(moved) == 1 else 'their'} own drift")
    elif moved:
        statement = (f"every IMU drifts relative to {ref}, and differently from each other "
                     f"(chi2 p={p_cons:.2g}): {ref}'s own share cannot be separated from "
                     f"theirs; what they share, {ref}'s drift at most, is 'common'")
    else:
        statement = (f"no IMU drifts relative to {ref}; {ref}'s own drift, which cannot be "
                     f"separated from all the others drifting together, is not seen")
    return {"common": c.tolist(), "common_sd": np.sqrt(np.diag(C)).tolist(),
            "common_p": p_c, "consistent_chi2": chi2, "consistent_dof": dof,
            "consistent_p": p_cons, "own": own, "statement": statement,
            "unit": "rad/s over the record (body frame of the reference)"}


def calibrate_static(flight: Flight, *, reference: str | None = None, alpha: float = 0.01
                     ) -> Calibration:
    """Calibrate the IMUs of a recording at rest against the reference (module docstring).

    Raises
    ------
    ConfigError
        Not gyros, fewer than two IMUs, unknown reference.
    CalibrationError
        The set is moving, or no alignment is observable.
    """
    groups = _groups(flight)
    ref = reference or next(iter(groups))
    if ref not in groups:
        raise ConfigError(f"reference {ref!r} is not an IMU of {flight.source} "
                          f"(IMUs: {', '.join(groups)})")
    ok, t, x, xs = _still_samples(flight, groups[ref])
    acc = {g: (_accel(flight, g)[ok] if _accel(flight, g) is not None else None)
           for g in groups}
    rots, notes, full = _rotations(x, acc, groups, ref)
    blocks = np.array_split(np.arange(x.shape[0]), BLOCKS)
    bias_sd = np.std([x[b].mean(axis=0) for b in blocks], axis=0, ddof=1) / math.sqrt(BLOCKS)
    rot_sd = {g: (np.zeros(3) if g == ref else _rotation_sd(g, x, acc, groups, ref, rots[g],
                                                           blocks))
              for g in groups}
    b = x.mean(axis=0)
    # the noise statistics, the residual models and the range describe the set at rest: a
    # knock is beyond the range (its jolt) and out of the monitor's envelope, not noise its
    # thresholds must cover (the alignment above uses every sample: knocks are shared motion)
    rest = at_rest(x, acc, groups, flight.sample_rate_hz)
    if rest.mean() < 0.5:
        raise CalibrationError(f"{flight.source}: only {rest.mean():.0%} of the samples are "
                               f"at rest (shocks of more than {SHOCK_SD:g} sd in two IMUs)")
    xr = xs[rest]
    sensors: list[SensorCal] = []
    n = flight.n
    cov = np.zeros((n, n))
    rel_drift, rel_cov, per_imu = {}, {}, {}
    w_ref = xs[:, groups[ref]]
    for g, idx in groups.items():
        R = rots[g].as_matrix()                  # v_ref = R v_j; rows of H_j: R[:, k]
        cov[np.ix_(idx, idx)] = np.cov(xr[:, idx].T)
        for k, i in enumerate(idx):
            sensors.append(_static_sensor(flight, i, R[:, k], rot_sd[g], float(b[i]),
                                          float(bias_sd[i]), float(np.std(xr[:, i]))))
        if g == ref:
            continue
        rel_drift[g], rel_cov[g], per_imu[g] = _static_imu(
            t, xs[:, idx] - w_ref @ R, R, rots[g], rot_sd[g],
            b[idx] - R.T @ b[groups[ref]])
    attr = attribute_drift(rel_drift, rel_cov, ref, alpha=alpha)
    notes.append(f"scale factors are not observable at rest: taken as 1 ± "
                 f"{100 * SCALE_FACTOR_TOLERANCE:g} % (a stated tolerance, in the input-error "
                 "covariance: the monitor's thresholds widen when the set moves)")
    notes.append("biases hold the Earth rate's projection (<= 0.0042 deg/s)")
    notes.append(f"{int(np.sum(~rest))} of {rest.size} samples near shocks (more than "
                 f"{SHOCK_SD:g} robust sd in two IMUs, +-{SHOCK_PAD_S:g} s) are left out of "
                 f"the noise, the residual models and the range")
    summary = StaticAlignment(
        reference=ref, imus=per_imu, drift_attribution=_attribution(attr), notes=tuple(notes),
        alpha=alpha, bias=tuple(b.tolist()), bias_sd=tuple(bias_sd.tolist()),
        samples=int(x.shape[0]), duration_s=float(t[-1] - t[0]), alignment_full=full)
    gs = _static_set(flight, ok, sensors, cov, groups, x, xs, xr, b, rest)
    return Calibration(configuration=f"{len(groups)} IMUs at rest", sets={"gyro": gs},
        sample_rate_hz=flight.sample_rate_hz,
        extra=CalibrationExtras(method=Method(STATIC_METHOD), source=flight.source,
                                static=summary).to_dict(STATIC_LAYOUT))


def _still_samples(flight: Flight, ref_idx: list[int]
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The valid, finite samples of a recording that is at rest.

    Parameters
    ----------
    flight : Flight
    ref_idx : list of int
        Channels of the reference IMU.

    Returns
    -------
    ok : ndarray of bool, shape (N,)
        Samples kept.
    t, x : ndarray
        Their times and raw values.
    xs : ndarray
        ``x`` less its mean.

    Raises
    ------
    CalibrationError
        Too few samples, or the reference's median rate deviation says the set moves.
    """
    ok = flight.valid.all(axis=1) & np.all(np.isfinite(flight.raw), axis=1)
    t, x = flight.t[ok], np.asarray(flight.raw, float)[ok]
    if x.shape[0] < 10 * BLOCKS:
        raise CalibrationError(f"{flight.source}: only {x.shape[0]} valid samples")
    xs = x - x.mean(axis=0)
    spread = float(np.median(np.linalg.norm(xs[:, ref_idx], axis=1)))
    if spread > _MOVING_RPS:
        raise CalibrationError(f"{flight.source}: the set is moving (median rate deviation "
                               f"{spread:.3g} rad/s > {_MOVING_RPS:g}); use rimu calibrate "
                               "in-flight")
    return ok, t, x, xs


def _rotation_sd(g: str, x: np.ndarray, acc: dict[str, np.ndarray | None],
                 groups: dict[str, list[int]], ref: str, rot: Rotation,
                 blocks: list[np.ndarray]) -> np.ndarray:
    """Sd of IMU ``g``'s rotation from its spread over blocks of the record.

    Parameters
    ----------
    g : str
    x : ndarray, shape (N, n)
    acc : dict of str to ndarray or None
        Each IMU's accelerometer (on the same samples), or None.
    groups : dict of str to list of int
    ref : str
    rot : Rotation
        ``g``'s rotation from the whole record.
    blocks : list of ndarray of int
        Sample indices of each block.

    Returns
    -------
    ndarray, shape (3,)
        Rotation-vector sd (rad); infinite when fewer than three blocks resolve it.
    """
    vs = []
    for b in blocks:
        try:
            rb, _, _ = _rotations(x[b], {h: (a[b] if a is not None else None)
                                         for h, a in acc.items()}, groups, ref)
            vs.append((rb[g] * rot.inv()).as_rotvec())
        except CalibrationError:
            continue
    return (np.std(vs, axis=0, ddof=1) / math.sqrt(len(vs)) if len(vs) > 2
            else np.full(3, np.inf))


def _static_sensor(flight: Flight, i: int, h: np.ndarray, sd_rot: np.ndarray, bias: float,
                   bias_sd: float, residual_rms: float) -> SensorCal:
    """One gyro axis of a static calibration: its axis from the rotation, scale factor 1
    within :data:`SCALE_FACTOR_TOLERANCE`, its misalignment sd from the rotation's.

    Parameters
    ----------
    flight : Flight
    i : int
        Channel.
    h : ndarray, shape (3,)
        Its axis in the reference frame.
    sd_rot : ndarray, shape (3,)
        Sd of its IMU's rotation vector (rad).
    bias, bias_sd, residual_rms : float
        Raw units.

    Returns
    -------
    SensorCal
    """
    nom = np.zeros(3)
    m = int(np.argmax(np.abs(h)))
    nom[m] = np.sign(h[m])
    E = tangent_basis(nom)
    ms = np.abs(E @ np.cross(sd_rot, h)) if np.all(np.isfinite(sd_rot)) else \
        np.full(2, np.inf)
    tol = SCALE_FACTOR_TOLERANCE
    across = E.T @ np.diag(np.where(np.isfinite(ms), ms, 0.0) ** 2) @ E
    return SensorCal(
        name=flight.sensor_names[i], axis=h, axis_nominal=nom, scale_factor=1.0,
        scale_factor_sd=tol, bias=bias, bias_sd=bias_sd,
        input_error_cov=tol**2 * np.outer(h, h) + across,
        misalignment_sd=ms, raw_unit=flight.raw_unit,
        scale_factor_unit=_sf_unit(flight.raw_unit), bias_unit="deg/s",
        residual_rms=residual_rms)


def _static_imu(t: np.ndarray, r: np.ndarray, R: np.ndarray, rot: Rotation,
                rot_sd: np.ndarray, relative_bias: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, StaticImu]:
    """The drift of one IMU relative to the reference over the record.

    Parameters
    ----------
    t : ndarray, shape (N,)
    r : ndarray, shape (N, 3)
        ``y_j − H_j·ω̂`` (its axes).
    R : ndarray, shape (3, 3)
        Its rotation onto the reference.
    rot : Rotation
    rot_sd : ndarray, shape (3,)
    relative_bias : ndarray, shape (3,)

    Returns
    -------
    drift : ndarray, shape (3,)
        In the reference (body) frame.
    drift_cov : ndarray, shape (3, 3)
    record : StaticImu
    """
    from replay.ingest.characterise_flight import slow_drift

    dr = slow_drift(t, r)
    d = np.asarray(dr["change"])
    dsd = np.asarray(dr["change_sd"])
    rec = StaticImu(
        rotation=tuple(rot.as_rotvec().tolist()), rotation_sd=tuple(rot_sd.tolist()),
        relative_bias=tuple(relative_bias.tolist()),
        relative_drift=tuple(d.tolist()), relative_drift_sd=tuple(dsd.tolist()),
        relative_drift_z=tuple(dr["z"]), relative_drift_p=tuple(dr["p_value"]),
        drift_block_s=dr["block_s"], drift_hac_lags=dr["hac_lags"])
    return R @ d, R @ np.diag(dsd**2) @ R.T, rec


def _static_set(flight: Flight, ok: np.ndarray, sensors: list[SensorCal], cov: np.ndarray,
                groups: dict[str, list[int]], x: np.ndarray, xs: np.ndarray, xr: np.ndarray,
                b: np.ndarray, rest: np.ndarray) -> SensorSet:
    """The gyro set of a static calibration: noise, Allan table, the envelope covered at
    rest and the residual models.

    Parameters
    ----------
    flight : Flight
    ok : ndarray of bool
        Samples kept (of the flight).
    sensors : list of SensorCal
    cov : ndarray, shape (n, n)
        Noise covariance.
    groups : dict of str to list of int
    x, xs, xr : ndarray
        Raw values kept, less their mean, and that at rest.
    b : ndarray, shape (n,)
        Biases.
    rest : ndarray of bool
        Kept samples at rest.

    Returns
    -------
    SensorSet
    """
    H = np.array([c.axis for c in sensors])
    acc_all = flight_accel(flight)
    acc_ok = acc_all[ok] if acc_all is not None else None
    return with_residual_models(
        SensorSet("gyro", tuple(sensors), cov, allan=allan_table(xr, flight.sample_rate_hz),
                  validated_rate=covered_rate(H, list(groups.values()), x - b, rest),
                  validated_specific_force=(covered_specific_force(acc_ok, rest)
                                            if acc_ok is not None else None),
                  validated_jolt=covered_jolt(acc_ok, rest) if acc_ok is not None else None),
        np.where(rest[:, None], xs, np.nan), x, flight.sample_rate_hz,
        source="static residual (raw - mean), shocks left out")


def _attribution(attr: Mapping[str, Any]) -> DriftAttribution:
    """The record of :func:`attribute_drift`'s result."""
    return DriftAttribution(
        common=tuple(attr["common"]), common_sd=tuple(attr["common_sd"]),
        common_p=attr["common_p"], consistent_chi2=attr["consistent_chi2"],
        consistent_dof=attr["consistent_dof"], consistent_p=attr["consistent_p"],
        own={g: OwnDrift(drift=tuple(v["drift"]), z=tuple(v["z"]), p_value=v["p_value"])
             for g, v in attr["own"].items()}, statement=attr["statement"])


def static_text(doc: StaticAlignment | Mapping[str, Any]) -> str:
    """Readable summary of a static calibration's record (:attr:`fdi.extras.
    CalibrationExtras.static`, or the ``extra.static`` block as written)."""
    if isinstance(doc, Mapping):
        doc = extras_from_dict({"static": doc}).static
    lines = [f"static calibration against {doc.reference} ({doc.samples} samples, "
             f"{doc.duration_s:.0f} s at rest)"]
    for g, r in doc.imus.items():
        lines.append(f"  {g}: rotation onto {doc.reference} [" + ", ".join(
            f"{a / DEG:+.2f} ± {s / DEG:.2f}" for a, s in zip(r.rotation, r.rotation_sd,
                                                              strict=True))
            + "] deg (rotation vector)")
        lines.append(f"      bias relative to the reference, in {g}'s axes [" + ", ".join(
            f"{a / DPS:+.4f}" for a in r.relative_bias) + "] deg/s")
        sig = [f"{a} {d / DPS:+.4f} ± {s / DPS:.4f} deg/s (z {z:+.1f}, p {p:.2g})"
               for a, d, s, z, p in zip("xyz", r.relative_drift, r.relative_drift_sd,
                                        r.relative_drift_z, r.relative_drift_p, strict=True)]
        lines.append(f"      drift relative to the reference over the record, in {g}'s axes: "
                     + "; ".join(sig))
    a = doc.drift_attribution
    if a is not None:
        lines.append(f"  drift shared by every IMU relative to the reference (= minus the "
                     f"reference's own), in {doc.reference}'s axes: [" + ", ".join(
                         f"{c / DPS:+.4f} ± {s / DPS:.4f}"
                         for c, s in zip(a.common, a.common_sd, strict=True))
                     + f"] deg/s, p {a.common_p:.2g}; the IMUs differ from it with chi2 "
                       f"p {a.consistent_p:.2g}")
        for g, v in a.own.items():
            lines.append(f"    {g} relative to the reference, in {doc.reference}'s axes "
                         "(the same drift as above, rotated): [" + ", ".join(
                f"{d / DPS:+.4f} (z {z:+.1f})" for d, z in zip(v.drift, v.z, strict=True))
                + "] deg/s")
        lines.append(f"  {a.statement}")
    lines.extend(f"  note: {n}" for n in doc.notes)
    return "\n".join(lines)
