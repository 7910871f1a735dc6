"""Calibrate a redundant IMU from a turntable session (seed 000, seed 001).

``calibrate(session)`` runs seven stages, each a function of its own module with a frozen
result (:func:`run_stages` returns them all, :class:`CalibrationStages`):

1. :func:`calibration.problem.gyro_problem` → :class:`~calibration.problem.GyroProblem`:
   per-segment means of the raw outputs and of the exact body-frame inputs (table rate,
   Earth rate, specific force from :meth:`calibration.session.Session.inputs`);
2. :func:`calibration.linear_fit.gyro_rate_test` → :class:`~calibration.rate_test.RateTestFit`:
   the gyro rate test over the paired ±ω steps (:mod:`calibration.rate_test`,
   seed 000 Eqs. 16-19), with the Earth rate as modelled included in the inputs;
3. :func:`calibration.linear_fit.fit_offsets` → :class:`~calibration.linear_fit.LinearFit`:
   the gyro offsets, both ways (:mod:`calibration.bias`): the explicit model over every step
   and seed 000's average over whole outer-axis turns (Eq. 20); ``bias_method`` says which
   one goes into the file;
4. :func:`calibration.fit_residuals.fit_residuals` →
   :class:`~calibration.fit_residuals.FitResiduals`: residuals ``u − a·x − c`` per sample →
   per-sample noise covariance, whiteness statistics;
5. :func:`calibration.uncertainty.set_uncertainty` →
   :class:`~calibration.uncertainty.Uncertainty`: every estimate is linear in segment
   means, so ``cov(θ_i, θ_j) = Σ_ij·P·diag(1/N)·Pᵀ`` with ``Σ`` the per-sample raw noise
   covariance (plus the coloured part below), then first-order propagation through the
   unit-norm split (seed 000 Eq. 19); :func:`calibration.sensor_set.build_sensor_set` makes
   the calibrated set (the same builder for gyros and accelerometers);
6. :func:`earth_rate_stage` → :class:`~calibration.earth_rate.EarthRateFit`: the Earth rate
   from the (wavelet-denoised) outer-axis modulation (:mod:`calibration.earth_rate`);
7. :func:`accel_stages` → :class:`AccelStages`: the accelerometer multi-position test over
   the position steps (:mod:`calibration.multiposition`, seed 001 Eqs. 5-10), when the
   session has accelerometers and at least 4 positions (stages 1, 4 and 5 for them).

Calling the stages one by one, and refitting with extra regressors::

    st = run_stages(session)                       # every stage's result
    st.gyro.fit.a, st.gyro.residuals.step_means    # any intermediate result
    p = st.gyro.problem.with_regressors(z, ["temperature"])     # z: (N,) or (N, m)
    st2 = run_stages(session, problem=p)           # joint fit of u = a·x + c + β·z
    st2.gyro.fit.beta, st2.gyro.uncertainty.theta_sd[4:]      # β (raw per unit) and sd
    st2.calibration                                # the Calibration with that model

Without regressors the estimates are the papers' (rate test, then offsets); with
regressors (even an empty set, ``np.zeros((N, 0))``) the gyro gains, offsets and β come
from one weighted least squares over the segment means (:mod:`calibration.linear_fit`).

Coloured noise (``noise_model="auto"``, the default): the covariances above are exact for
white noise only. With a bias instability the step means are correlated over several steps
and the bias σ is several times too small (tetrad-paper, 1 °/h, τc 100 s: sd(error/σ) ≈ 3.5
for the biases, 1.2 for the scale factors). Per sensor set a white + first-order
Gauss-Markov model, the bias process common to the set, is fitted to the residual spectrum
(:func:`calibration.residuals.fit_gauss_markov`, Whittle likelihood); when the
likelihood-ratio test keeps it, its exact covariance over the segment means
``(σ_b/SF_i)²·P·K(τc)·Pᵀ`` is added to the white one for a, SF, h̃, angles, both biases, v_c
and ``input_error_cov`` (it only adds: never below the white covariance). The pair
(σ_b², τc) of that covariance is the one with the largest bias variance among the
correlation times the profile likelihood does not exclude (90 % interval), cut at a quarter
of the record (:func:`calibration.residuals.gauss_markov_sigma_candidates`): a record of a
few correlation times hardly tells τc, and the σ at the maximum-likelihood τc were a scale
mixture, 2× too small where τ̂c came out short and 5-6× too wide where it ran long. The
estimates do not change. ``extra["noise_model"]`` records the fit, the pair the σ used and
the sd factor over white noise per sensor. How well these σ hold, measured by Monte Carlo
on simulated sessions (white and coloured, tetrad and cone): ``docs/model.md``
("Uncertainty"), ``tests/calibration/test_calibrate_coloured_holdout.py``.
The Earth-rate fit still uses the white per-sample covariance.

Two further checks test whiteness against the data and add a line to ``extra["warnings"]``
(printed by ``rimu calibrate``) when it fails at the 0.1 % level: the scatter of the
rate-step differences about the fit (``extra["rate_test"]["chi2_dof"]``) and the scatter of
the per-step residual means (``extra["step_residual_chi2_dof"]``, exact expectation 1 under
white noise).

Keys of ``Calibration.extra`` written here::

    source                     session path
    method                     {"gyro", "bias", "denoise"}
    rate_test                  {"pairs": [[k, p], ...] (1-based), "R_rad_s": (P, 3),
                                "chi2_dof": (n,)}
    step_residual_chi2_dof     (n,)
    warnings                   [str, ...]
    noise_model                {"method": str, "gyro"/"accel": {"applied", "bias_instability"
                                (SI), "correlation_s", "likelihood_ratio",
                                "sigma_bias_instability" (SI), "sigma_correlation_s",
                                "sigma_cut", "record_s", "sd_factor":
                                {"bias", "scale_factor", "misalignment": (n,)}}}
                               (sd_factor: sd with the model / white sd; misalignment: the
                               larger of the two angles' factors)
    gyro_bias                  {"unit", "model", "model_sd", and when there are whole outer
                                turns "turns", "turns_sd", "turns_steps", "turns_per_step",
                                "vertical_correction"}   (values in "unit")
    parity_calibrated_sd       (n-3, n) first-order sd of V_c (gyros)
    parity_accel_calibrated_sd (n-3, n) (accelerometers)
    residual_steps             {"unit": {...}, "gyro": [{"step", "label", "kind", "n",
                                "mean": [n], "rms": [n]}, ...], "accel": [...]}  (SI)
    earth_rate_fit             see :meth:`calibration.earth_rate.EarthRateFit.to_dict`
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from calibration.bias import is_outer_step
from calibration.earth_rate import EarthRateFit, fit_earth_rate
from calibration.fit_residuals import FitResiduals, fit_residuals, whiteness_warnings
from calibration.linear_fit import (
    MIN_STEP_SAMPLES,
    LinearFit,
    fail_steps,
    fit_offsets,
    gyro_rate_test,
)
from calibration.multiposition import MultiPosition, multiposition
from calibration.problem import AccelProblem, GyroProblem, accel_problem, gyro_problem
from calibration.rate_test import RateTestFit
from calibration.residuals import noise_covariance, residual_step_stats
from calibration.sensor_set import build_sensor_set, check_gains, display_units
from calibration.session import Session
from calibration.turntable import mat_nb
from calibration.uncertainty import (
    NOISE_METHOD,
    Uncertainty,
    parity_sd,
    segment_times,
    set_uncertainty,
)
from fdi.calfile import Calibration, SensorSet
from fdi.errors import CalibrationError
from fdi.extras import (
    TURNTABLE_LAYOUT,
    CalibrationExtras,
    GyroBias,
    Method,
    NoiseFit,
    NoiseModel,
    RateTest,
    ResidualStep,
)
from fdi.units import EARTH_RATE

__all__ = ["BIAS_METHODS", "MIN_STEP_SAMPLES", "NOISE_MODELS", "AccelStages",
           "CalibrationStages", "GyroStages", "accel_stages", "calibrate", "display_units",
           "earth_rate_stage", "gyro_stages", "outer_axis_fit", "run_stages"]

BIAS_METHODS = ("model", "turns")
NOISE_MODELS = ("auto", "white")


@dataclass(frozen=True)
class GyroStages:
    """The gyro stages 1-5 of one calibration.

    Attributes
    ----------
    problem : GyroProblem
    rate_test : RateTestFit
    fit : LinearFit
    residuals : FitResiduals
    uncertainty : Uncertainty
    sensor_set : SensorSet
        The calibrated gyros (biases per ``bias_method``).
    """

    problem: GyroProblem
    rate_test: RateTestFit
    fit: LinearFit
    residuals: FitResiduals
    uncertainty: Uncertainty
    sensor_set: SensorSet

    @property
    def scale_factors(self) -> np.ndarray:
        """SF per gyro (rad/s per raw), shape (n,)."""
        return self.sensor_set.scale_factors

    @property
    def residuals_si(self) -> np.ndarray:
        """Residuals of the bias steps in rad/s, shape (N_used, n)."""
        return self.residuals.raw * self.scale_factors


@dataclass(frozen=True)
class AccelStages:
    """The accelerometer stages (stage 7: problem, multi-position fit, residuals, σ).

    Attributes
    ----------
    problem : AccelProblem
    fit : MultiPosition
    residuals_raw : ndarray, shape (N_used, n)
    noise_cov_raw : ndarray, shape (n, n)
    uncertainty : Uncertainty
    sensor_set : SensorSet
    """

    problem: AccelProblem
    fit: MultiPosition
    residuals_raw: np.ndarray
    noise_cov_raw: np.ndarray
    uncertainty: Uncertainty
    sensor_set: SensorSet


@dataclass(frozen=True)
class CalibrationStages:
    """Every stage's result of one calibration, and the calibration they make.

    Attributes
    ----------
    gyro : GyroStages
    earth_rate : EarthRateFit or None
    accel : AccelStages or None
    warnings : tuple of str
    calibration : Calibration
        What :func:`calibrate` returns.
    """

    gyro: GyroStages
    earth_rate: EarthRateFit | None
    accel: AccelStages | None
    warnings: tuple[str, ...]
    calibration: Calibration


def _check_options(bias_method: str, noise_model: str) -> None:
    if bias_method not in BIAS_METHODS:
        raise CalibrationError(f"unknown bias method {bias_method!r}; expected one of "
                               f"{', '.join(BIAS_METHODS)}")
    if noise_model not in NOISE_MODELS:
        raise CalibrationError(f"unknown noise model {noise_model!r}; expected one of "
                               f"{', '.join(NOISE_MODELS)}")


def gyro_stages(session: Session, problem: GyroProblem | None = None, *,
                bias_method: str = "model", noise_model: str = "auto",
                allan: bool = True) -> GyroStages:
    """Stages 1-5 for the gyros: problem, rate test, offsets, residuals, uncertainty, set.

    ``problem``: a stage-1 result to use (e.g. with regressors); default
    :func:`calibration.problem.gyro_problem` of the session.
    """
    p = gyro_problem(session) if problem is None else problem
    rt = gyro_rate_test(p)
    fit = fit_offsets(p, rt, bias_method)
    cfg = session.gyro_config
    check_gains(p.source, "gyro", fit.a, cfg.sensor_names)
    res = fit_residuals(p, rt, fit)
    seg_start, seg_len = segment_times(p.t, p.segment, p.seg_count, p.sample_rate_hz)
    unc = set_uncertainty(fit.theta, fit.op, fit.inv_count, res.noise_cov_raw, cfg.H,
                          res.raw, seg_start, seg_len, p.sample_rate_hz, noise_model,
                          fit.theta_turns, fit.op_turns)
    sf = np.array([e.split.scale_factor for e in unc.estimates])
    gset = build_sensor_set(
        "gyro", cfg, session.gyro_raw_unit, unc.estimates, res.raw * sf,
        res.noise_cov_raw * np.outer(sf, sf), p.sample_rate_hz, allan=allan,
        source=p.source, bias_parts=unc.estimates_turns if bias_method == "turns" else None)
    return GyroStages(problem=p, rate_test=rt, fit=fit, residuals=res, uncertainty=unc,
                      sensor_set=gset)


def earth_rate_stage(session: Session, gyros: SensorSet, *,
                     denoise: bool = True) -> EarthRateFit | None:
    """Stage 6: the Earth rate from the outer-axis steps (None when there are none)."""
    wt, _, _ = session.inputs()
    return _earth_rate(session, gyros.H, gyros.scale_factors, wt, gyros.noise_covariance,
                       np.deg2rad(session.latitude_deg), denoise)


def accel_stages(session: Session, *, noise_model: str = "auto",
                 allan: bool = True) -> AccelStages | None:
    """Stage 7: multi-position calibration of the accelerometers (None without ≥ 4 positions).

    Raises
    ------
    CalibrationError
        Non-finite samples, a position with too few samples, rank-deficient positions.
    """
    fb = session.inputs()[2] if session.raw_accel is not None else None
    p = accel_problem(session, fb) if fb is not None else None
    if p is None:
        return None
    src = p.source
    few = [(k, int(p.count[j])) for j, k in enumerate(p.step_numbers)
           if p.count[j] < MIN_STEP_SAMPLES]
    if few:
        raise fail_steps(src, "accelerometer", few)
    mp = multiposition(p.mean_u, p.count, p.mean_f, step_numbers=list(p.step_numbers),
                       source=src)
    m = p.segment >= 0
    r_raw = p.raw[m] - p.specific_force[m] @ mp.a.T - mp.c
    Sigma_raw = noise_covariance(r_raw, dof_used=4)
    cfg = session.accel_config
    check_gains(src, "accel", mp.a, cfg.sensor_names)
    fs = float(session.sample_rate_hz)
    seg_start, seg_len = segment_times(p.t, p.segment, p.count, fs)
    theta = np.vstack([mp.a.T, mp.c[None, :]])
    unc = set_uncertainty(theta, mp.op, 1.0 / p.count, Sigma_raw, cfg.H, r_raw, seg_start,
                          seg_len, fs, noise_model)
    sf = np.array([e.split.scale_factor for e in unc.estimates])
    aset = build_sensor_set("accel", cfg, session.accel_raw_unit, unc.estimates, r_raw * sf,
                            Sigma_raw * np.outer(sf, sf), fs, allan=allan, source=src)
    return AccelStages(problem=p, fit=mp, residuals_raw=r_raw, noise_cov_raw=Sigma_raw,
                       uncertainty=unc, sensor_set=aset)


def run_stages(session: Session, *, bias_method: str = "model", denoise: bool = True,
               allan: bool = True, earth_rate: bool = True, noise_model: str = "auto",
               problem: GyroProblem | None = None) -> CalibrationStages:
    """Run every stage of :func:`calibrate` and keep each result.

    Parameters are those of :func:`calibrate`, plus ``problem``: a stage-1 gyro problem to
    use instead of the session's (see the module docstring for regressors).

    Returns
    -------
    CalibrationStages
        ``.calibration`` is what :func:`calibrate` returns.
    """
    _check_options(bias_method, noise_model)
    g = gyro_stages(session, problem, bias_method=bias_method, noise_model=noise_model,
                    allan=allan)
    res = g.residuals
    warnings = whiteness_warnings(res, session.gyro_config.sensor_names,
                                  g.uncertainty.record.applied)
    er = earth_rate_stage(session, g.sensor_set, denoise=denoise) if earth_rate else None
    acc = None
    if session.raw_accel is not None and session.accel_config is not None:
        acc = accel_stages(session, noise_model=noise_model, allan=allan)
    sets = {"gyro": _with_tails(g.sensor_set, g.residuals_si, session.sample_rate_hz)}
    if acc is not None:
        sets["accel"] = _with_tails(acc.sensor_set, acc.residuals_raw
                                    * acc.sensor_set.scale_factors, session.sample_rate_hz)
    cal = Calibration(
        configuration=session.gyro_config.name, sets=sets,
        sample_rate_hz=float(session.sample_rate_hz),
        earth_rate_dph=None if er is None else er.rate_dph,
        earth_rate_dph_sd=None if er is None else er.rate_dph_sd,
        latitude_deg=float(session.latitude_deg),
        extra=_extra(session, g, er, acc, warnings, bias_method=bias_method,
                     denoise=denoise, noise_model=noise_model))
    return CalibrationStages(gyro=g, earth_rate=er, accel=acc, warnings=tuple(warnings),
                             calibration=cal)


def _with_tails(s: SensorSet, residual: np.ndarray, fs: float) -> SensorSet:
    """The set with the tail model of its rate-test residual (:mod:`calibration.tails`).

    The residual rows are the used samples of the steps, concatenated: a window may span
    two steps (each step's residual is zero-mean by the fit).
    """
    from dataclasses import replace

    from calibration.tails import fit_tail_model

    model = fit_tail_model(residual, s.H, s.noise_covariance, float(fs),
                           source="turntable rate-test residual (used samples of the steps)")
    return replace(s, tails=model)


def calibrate(session: Session, *, bias_method: str = "model", denoise: bool = True,
              allan: bool = True, earth_rate: bool = True,
              noise_model: str = "auto") -> Calibration:
    """Calibrate the gyros (rate test) and accelerometers (multi-position) of a session.

    Parameters
    ----------
    session : Session
    bias_method : {"model", "turns"}
        Gyro bias written to the file: explicit Earth-rate model or seed 000's average over
        whole outer-axis turns (both are computed and kept in ``extra["gyro_bias"]``).
    denoise : bool
        Wavelet-denoise (db4, level 8) the outer-axis outputs before the Earth-rate fit.
    allan : bool
        Compute the Allan deviation of the residuals.
    earth_rate : bool
        Estimate the Earth rate from the outer-axis modulation.
    noise_model : {"auto", "white"}
        Uncertainties: ``"auto"`` adds a fitted Gauss-Markov bias process per sensor set when
        the residuals show one (see the module docstring); ``"white"`` assumes white noise.

    Returns
    -------
    Calibration

    Raises
    ------
    CalibrationError
        Rank-deficient rate pairs or positions, a used step with too few samples,
        non-finite samples, no whole outer turn for ``bias_method="turns"``.
    """
    return run_stages(session, bias_method=bias_method, denoise=denoise, allan=allan,
                      earth_rate=earth_rate, noise_model=noise_model).calibration


def _gyro_bias_record(session: Session, g: GyroStages) -> GyroBias:
    """``extra["gyro_bias"]``: both offsets (written in the file's bias unit)."""
    unc = g.uncertainty
    bu = g.sensor_set.sensors[0].bias_unit
    model = (tuple(e.bias for e in unc.estimates), tuple(e.bias_sd for e in unc.estimates))
    if unc.estimates_turns is None:
        return GyroBias(unit=bu, model=model[0], model_sd=model[1])
    tw, p = g.problem.turns, g.problem
    vert = g.sensor_set.H @ (EARTH_RATE * np.sin(p.latitude_rad)
                             * p.up[tw.in_window].mean(axis=0))
    return GyroBias(unit=bu, model=model[0], model_sd=model[1],
                    turns=tuple(e.bias for e in unc.estimates_turns),
                    turns_sd=tuple(e.bias_sd for e in unc.estimates_turns),
                    turns_steps=tuple(tw.steps), turns_per_step=tuple(tw.turns),
                    vertical_correction=tuple(vert.tolist()))


def _rows(a: np.ndarray) -> tuple[tuple[float, ...], ...]:
    return tuple(tuple(r) for r in np.asarray(a, float).tolist())


def _extra(session: Session, g: GyroStages, er: EarthRateFit | None,
           acc: AccelStages | None, warnings: list[str], *, bias_method: str,
           denoise: bool, noise_model: str) -> dict[str, Any]:
    """``Calibration.extra``: the record of every stage the file keeps."""
    p, res, unc = g.problem, g.residuals, g.uncertainty
    nums, steps = p.step_numbers, list(session.steps)
    bs = g.fit.bias_steps
    Q = g.fit.Q
    noise = {"gyro": unc.record}
    par = {"gyro": _rows(parity_sd(g.sensor_set.H, [e.split.jac[1:4] for e in unc.estimates],
                                   res.noise_cov_raw, Q[:3, :3], unc.extra_cov))}
    resid = {"gyro": residual_step_stats(g.residuals_si, session.step[res.mask],
                                         [nums[j] for j in bs], [steps[j].label for j in bs],
                                         [steps[j].kind for j in bs])}
    if acc is not None:
        noise["accel"], resid["accel"], par["accel"] = _accel_extra(session, acc)
    extras = CalibrationExtras(
        source=p.source,
        method=Method(parts={"gyro": "rate test, seed 000 Eqs. 16-19 / seed 001 Eqs. 11-15, "
                                     "inputs from the turntable model with the Earth rate",
                             "bias": bias_method, "denoise": "db4 level 8 (approximation)"
                             if denoise else "none"}),
        rate_test=RateTest(pairs=tuple((int(nums[k]), int(nums[q]))
                                             for k, q in g.rate_test.pairs),
                                 rates=_rows(g.rate_test.R),
                                 chi2_dof=tuple(np.asarray(res.rate_chi2_dof).tolist())),
        step_residual_chi2_dof=tuple(np.asarray(res.step_chi2_dof).tolist()),
        warnings=tuple(warnings), noise_model=NoiseModel(NOISE_METHOD[noise_model], noise),
        gyro_bias=_gyro_bias_record(session, g), parity_sd=par, residual_steps=resid)
    other: dict[str, Any] = {}
    if p.regressors is not None:
        other["regressors"] = {"names": list(p.regressor_names),
                               "coefficients_raw": g.fit.beta,
                               "coefficients_raw_sd": unc.theta_sd[4:].T}
    if er is not None:
        other["earth_rate_fit"] = er.to_dict()
    return extras.to_dict(TURNTABLE_LAYOUT, other)


def _accel_extra(session: Session, acc: AccelStages
                 ) -> tuple[NoiseFit, tuple[ResidualStep, ...], tuple[tuple[float, ...], ...]]:
    """Accelerometer entries of ``Calibration.extra``: noise fit, per-step residuals and
    the calibrated parity sd."""
    unc, aset = acc.uncertainty, acc.sensor_set
    pos_steps = list(acc.problem.step_numbers)
    label = {s.index: s.label for s in session.steps}
    m = acc.problem.segment >= 0
    steps = residual_step_stats(
        acc.residuals_raw * aset.scale_factors, session.step[m], pos_steps,
        [label[k] for k in pos_steps], ["position"] * len(pos_steps))
    Q = (acc.fit.op / acc.problem.count) @ acc.fit.op.T
    par = _rows(parity_sd(aset.H, [e.split.jac[1:4] for e in unc.estimates], acc.noise_cov_raw,
                          Q[:3, :3], unc.extra_cov)) if aset.n > 3 else ()
    return unc.record, steps, par


def outer_axis_fit(session: Session, cal: Calibration, *,
                   denoise: bool = True) -> EarthRateFit | None:
    """The Earth-rate fit of a session with a calibration's gyro parameters (for plots).

    Same computation as inside :func:`calibrate`; the result keeps the (denoised)
    compensated outputs and the fitted curves. None without outer-axis steps.
    """
    return earth_rate_stage(session, cal.gyro, denoise=denoise)


def _earth_rate(session: Session, Ht: np.ndarray, sf: np.ndarray, wt: np.ndarray,
                Sigma: np.ndarray, lat: float, denoise: bool) -> EarthRateFit | None:
    """Earth rate from the outer-axis steps (None when there are none)."""
    idx_all, ups = [], []
    for s in session.steps:
        idx = np.flatnonzero(session.step == s.index)
        if idx.size < MIN_STEP_SAMPLES or not is_outer_step(session.inner_rate[idx],
                                                            session.outer_rate[idx]):
            continue
        # inner angle fixed: C_nb = Rz(a_o)·[Ry(a_i)·P], rotate the fixed part about Up
        q = mat_nb(np.median(session.inner[idx]), 0.0, s.mat_pb)[0] @ Ht.T    # (3, n)
        co, so = np.cos(session.outer[idx])[:, None], np.sin(session.outer[idx])[:, None]
        ups.append(np.stack([co * q[0] - so * q[1], so * q[0] + co * q[1],
                             np.broadcast_to(q[2], co.shape[:1] + q[2].shape)], axis=1))
        idx_all.append(idx)
    if not idx_all:
        return None
    idx = np.concatenate(idx_all)
    y = np.asarray(session.raw_gyro, float)[idx] * sf - wt[idx] @ Ht.T
    return fit_earth_rate(y, np.concatenate(ups), session.step[idx], Sigma, lat,
                          denoise_outputs=denoise)
