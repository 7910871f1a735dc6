"""Several flights of one IMU set calibrated together: what lasts across power-ups, what not.

``rimu calibrate in-flight F1 F2 ...``. Each flight is fitted on its own
(:func:`calibration.inflight.fit.fit_inflight`); then, per IMU:

- **shared** (mounting, misalignment, scale, non-orthogonality: the parts of E, which
  belong to the airframe and the sensor): the flights' data combined with the one prior.
  Each flight's posterior ``N(b_f, C_f)`` holds the prior ``N(0, Λ⁻¹)`` once, so its data
  information is ``I_f = C_f⁻¹ − Λ`` (eigenvalues clipped at 0) and the joint posterior is
  ``P = Λ + Σ_f I_f``, ``b = P⁻¹·Σ_f C_f⁻¹·b_f`` (exact for linear-Gaussian fits: the
  per-flight parameters are each flight's own, so the flights' data are independent given
  the shared ones). A mounting (the rotation by multiples of 90°) must agree between
  flights;
- **per power-up** (the turn-on bias; the time offset and jitter where they move): each
  flight's own values are kept (``extra.inflight.flights``), the file's value is their
  mean, and the run-to-run sd of the relative biases ``c_j`` is split into each sensor's
  own (``bias_turn_on_sd``) by the three-cornered hat over the IMUs, as the noise is
  (:func:`calibration.inflight.fit.axis_noise`; with two IMUs equally): the reference's
  turn-on bias moves every ``c_j`` together.

The noise model, Allan table and residual tails come from the longest flight's residual
(its own biases and offsets removed).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, replace

import numpy as np

from calibration.inflight.fit import (
    ESTIMATED,
    HELD,
    INFORMED,
    ImuAlignmentFit,
    InflightFit,
    ParameterStatus,
    _decomposition_matrix,
)
from calibration.inflight.prior import Prior, mounting_text
from fdi.errors import CalibrationError

__all__ = ["JointFit", "combine_fits", "turn_on_split"]


@dataclass(frozen=True, eq=False)
class JointFit:
    """Flights calibrated together.

    Attributes
    ----------
    fit : InflightFit
        The joint calibration (shared parts joint, per-flight parts their mean) on the
        longest flight's residual.
    base : int
        Index of that flight.
    fits : tuple of InflightFit
        Each flight's own fit.
    turn_on_sd : dict of str to ndarray (3,)
        Each IMU's own run-to-run sd of the turn-on bias per axis (rad/s, its own axes).
    relative_sd : dict of str to ndarray (3,)
        Run-to-run sd of each IMU's bias relative to the reference (rad/s).
    notes : tuple of str
    """

    fit: InflightFit
    base: int
    fits: tuple[InflightFit, ...]
    turn_on_sd: dict[str, np.ndarray]
    relative_sd: dict[str, np.ndarray]
    notes: tuple[str, ...] = ()


def _prior_precision_E(prior: Prior, model: str) -> np.ndarray:
    """Λ of vec(E) (9×9): the prior of :class:`Prior` in the E parametrisation."""
    T = _decomposition_matrix()                      # φ = T·vec(E)
    s = prior.sds()
    if model != "full":
        s = s.copy()
        s[3:] = 1e-9                                 # rotation model: E is [θ]× only
    return T.T @ np.diag(1.0 / s**2) @ T


def turn_on_split(c: dict[str, np.ndarray], mountings: dict[str, np.ndarray],
                  reference: str) -> dict[str, np.ndarray]:
    """Each IMU's own run-to-run bias sd from the flights' relative biases.

    Parameters
    ----------
    c : dict of str to ndarray (K, 3)
        Relative bias ``c_j`` of each IMU other than the reference on each of K flights
        (rad/s, the IMU's axes).
    mountings : dict of str to ndarray (3, 3)
    reference : str

    Returns
    -------
    dict of str to ndarray (3,)
        Including the reference (rad/s; ``c_j = b_j − A_j·b_ref``, the reference's in its
        axes, by the three-cornered hat over pairs, per body axis the median, at most the
        smallest relative variance; with one other IMU half the relative variance each).
    """
    names = list(c)
    rot = {g: c[g] @ np.asarray(mountings[g], float) for g in names}     # body axes
    var = {g: np.var(rot[g], axis=0, ddof=1) for g in names}
    if len(names) >= 2:
        est = [(var[i] + var[j] - np.var(rot[i] - rot[j], axis=0, ddof=1)) / 2
               for i, j in itertools.combinations(names, 2)]
        vr = np.clip(np.median(est, axis=0), 0, None)
        vr = np.minimum(vr, np.min([var[g] for g in names], axis=0))
    else:
        vr = var[names[0]] / 2
    out = {reference: np.sqrt(vr)}
    for g in names:
        R = np.asarray(mountings[g], float)
        own = np.clip(np.var(c[g], axis=0, ddof=1) - (R**2) @ vr, 0, None)
        out[g] = np.sqrt(own)
    return out


def combine_fits(fits: list[InflightFit]) -> JointFit:
    """The joint calibration of several flights' fits (module docstring).

    Raises
    ------
    CalibrationError
        The flights do not hold the same IMUs, reference or mountings (the message names
        the IMU, the flights and what to do).
    """
    _check_same_set(fits)
    first = fits[0]
    base = int(np.argmax([int(f.used.sum()) for f in fits]))
    prior = first.prior or Prior()
    notes = []
    alignments = {}
    rel_sd, cs, mounts = {}, {}, {}
    for g in first.alignments:
        als = [f.alignments[g] for f in fits]
        R = _common_mounting(g, fits, als)
        model = als[0].model
        E, Pc = _joint_small(als, _prior_precision_E(prior, model))
        K = np.kron(np.eye(3), R.T)
        A = (np.eye(3) + E) @ R
        A_cov = K @ Pc @ K.T
        c = np.array([a.c for a in als])
        cs[g], mounts[g] = c, R
        rel_sd[g] = np.std(c, axis=0, ddof=1)
        c_cov = np.sum([a.c_cov for a in als], axis=0) / len(als) ** 2
        tau, tau_sd, note = _joint_time_offset(g, als)
        if note:
            notes.append(note)
        jit = max(a.timing_jitter_s for a in als)
        jit_sd = max(a.timing_jitter_sd_s for a in als)
        params = _joint_parameters(als, model, E, Pc, tau, tau_sd)
        b = als[base]
        alignments[g] = replace(
            b, A=A, A_cov=A_cov, c=c.mean(axis=0), c_cov=c_cov, time_offset_s=tau,
            time_offset_sd_s=tau_sd, timing_jitter_s=jit, timing_jitter_sd_s=jit_sd,
            parameters=tuple(params), check=None,
            notes=(*b.notes, f"joint over {len(fits)} flights: mounting, misalignment, scale "
                   "and non-orthogonality from all of them; bias and time offset their mean "
                   f"(each flight's under extra.inflight.flights); residual of "
                   f"{fits[base].source}"))
    turn_on = turn_on_split(cs, mounts, first.reference)
    joint = replace(fits[base], alignments=alignments,
                    source=" + ".join(f.source for f in fits),
                    findings=tuple(dict.fromkeys(x for f in fits for x in f.findings)))
    return JointFit(fit=joint, base=base, fits=tuple(fits), turn_on_sd=turn_on,
                    relative_sd=rel_sd, notes=tuple(notes))


def _check_same_set(fits: list[InflightFit]) -> None:
    """Refuse fewer than two flights, or flights of different IMUs or references.

    Parameters
    ----------
    fits : list of InflightFit

    Raises
    ------
    CalibrationError
        The message names the flights and what to do.
    """
    if len(fits) < 2:
        raise CalibrationError("calibrating flights together needs two flights or more")
    first = fits[0]
    for f in fits[1:]:
        if f.imus != first.imus or f.reference != first.reference:
            raise CalibrationError(
                f"{f.source}: IMUs {', '.join(f.imus)} (reference {f.reference}) differ from "
                f"{first.source}'s {', '.join(first.imus)} (reference {first.reference}): "
                "calibrate flights of one IMU set together, with the same --reference")


def _common_mounting(g: str, fits: list[InflightFit], als: list[ImuAlignmentFit]) -> np.ndarray:
    """The mounting of IMU ``g``, which every flight must share.

    Parameters
    ----------
    g : str
    fits : list of InflightFit
    als : list of ImuAlignmentFit
        ``g``'s alignment in each flight.

    Returns
    -------
    ndarray, shape (3, 3)

    Raises
    ------
    CalibrationError
        A flight mounts it otherwise (the message names both flights).
    """
    R = np.asarray(als[0].mounting, float)
    for f, a in zip(fits, als, strict=True):
        if not np.allclose(a.mounting, R):
            raise CalibrationError(
                f"{g}: mounted {mounting_text(a.mounting)} on {f.source} but "
                f"{mounting_text(R)} on {fits[0].source}: calibrate the flights separately, "
                "or declare the mounting")
    return R


def _joint_small(als: list[ImuAlignmentFit], Lam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """E of the flights' data combined with the one prior (module docstring).

    Parameters
    ----------
    als : list of ImuAlignmentFit
        One IMU's alignment in each flight.
    Lam : ndarray, shape (9, 9)
        Prior precision of vec(E).

    Returns
    -------
    E : ndarray, shape (3, 3)
    Pc : ndarray, shape (9, 9)
        Its posterior covariance.
    """
    P = Lam.copy()
    rhs = np.zeros(9)
    for a in als:
        E, C = a.small
        Ci = np.linalg.pinv(C, hermitian=True)
        w, V = np.linalg.eigh(0.5 * (Ci - Lam + (Ci - Lam).T))
        P += (V * np.clip(w, 0, None)) @ V.T
        rhs += Ci @ E.ravel()
    Pc = np.linalg.pinv(P, hermitian=True)
    return (Pc @ rhs).reshape(3, 3), Pc


def _joint_time_offset(g: str, als: list[ImuAlignmentFit]) -> tuple[float, float, str]:
    """Inverse-variance mean of the flights' time offsets; their spread is the sd when
    they disagree (χ² above three per degree of freedom).

    Parameters
    ----------
    g : str
    als : list of ImuAlignmentFit

    Returns
    -------
    tau, tau_sd : float
        s.
    note : str
        Empty, or the flights' offsets when they move between flights.
    """
    taus = np.array([a.time_offset_s for a in als])
    tsd = np.array([max(a.time_offset_sd_s, 1e-12) for a in als])
    wt = 1.0 / tsd**2
    tau = float(np.sum(wt * taus) / np.sum(wt))
    chi2 = float(np.sum(wt * (taus - tau) ** 2))
    tau_sd = float(np.sqrt(1.0 / np.sum(wt)))
    if not (len(als) > 1 and chi2 > 3.0 * (len(als) - 1)):
        return tau, tau_sd, ""
    spread = float(np.std(taus, ddof=1))
    note = (f"{g}: the time offset moves between flights ("
            + ", ".join(f"{1e3 * x:+.2f}" for x in taus)
            + f" ms): it is a per-flight parameter here, its spread "
            f"{1e3 * spread:.2f} ms is its sd")
    return tau, max(tau_sd, spread), note


def _joint_parameters(als: list[ImuAlignmentFit], model: str, E: np.ndarray, Pc: np.ndarray,
                      tau: float, tau_sd: float) -> list[ParameterStatus]:
    """Parameter statuses of the joint: estimated when the flights together inform it.

    Parameters
    ----------
    als : list of ImuAlignmentFit
    model : str
        ``"full"`` or ``"rotation"``.
    E, Pc : ndarray
        The joint E and its covariance.
    tau, tau_sd : float
        The joint time offset and its sd (s).

    Returns
    -------
    list of ParameterStatus
    """
    T = _decomposition_matrix()
    phi = T @ E.ravel()
    phi_sd = np.sqrt(np.clip(np.diag(T @ Pc @ T.T), 0, None))
    if model != "full":
        phi, phi_sd = phi[:3], phi_sd[:3]
    params = []
    for j, p in enumerate(p for p in als[0].parameters if p.name != "time offset"):
        params.append(replace(p, value=float(phi[j]), sd=float(phi_sd[j]),
                              status=ESTIMATED if phi_sd[j] <= INFORMED * p.prior_sd
                              else HELD,
                              excitation=max(a.parameters[j].excitation for a in als)))
    tp = [p for p in als[0].parameters if p.name == "time offset"]
    if tp:
        params.append(replace(tp[0], value=tau, sd=tau_sd,
                              status=ESTIMATED if tau_sd <= INFORMED * tp[0].prior_sd
                              else HELD))
    return params
