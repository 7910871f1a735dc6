"""The in-flight calibration as a ``rimu.calibration/3`` file the monitor reads.

Frame and sensor model: the reference IMU defines the frame, so its axes are the unit
vectors, its scale factors 1 and its biases 0 (its absolute bias is not observable against
the other IMUs: every bias in the file is relative to the reference's, which leaves the
parity residual exact and shifts the reconstructed rate by the reference's bias). IMU j's
axis k follows from ``y_jk = A_k·ω' + c_k`` (``A_k`` row k of A, ω' the reference's
reading): ``h = A_k/|A_k|``, ``SF = 1/|A_k|``, ``b = c_k/|A_k|`` (seed 000 Eq. 13).
``input_error_cov`` is the covariance of ``A_k`` (already gain-normalised).

Noise: the fit residual of IMU j holds its own noise and the reference's
(``Cov r_j = Σ_j + A Σ_r Aᵀ``). With two IMUs the two are taken equal; with three or more
the reference's follows from pairs (three-cornered hat:
``Σ_r = (Cov r_i + Cov r_j − Cov(r_i − r_j))/2``, averaged over pairs). The Allan table of
each sensor is that of its share of the residual, so the thresholds carry the flight's own
coloured noise. Time offsets are kept under ``extra.inflight`` with their checks
(:mod:`.offset_check`), their sign convention and the identity of the flight they were
fitted on; ``rimu monitor-file`` and ``rimu diagnose`` move each IMU by its offset
(:mod:`.timing`).
The tail of the residual's parity statistic per window scale is kept too
(:func:`sensor_residuals`, :mod:`calibration.tails`), and the body rate per axis and the
specific force the samples the fit used reached (``SensorSet.validated_rate``,
``validated_specific_force``): the monitor's envelope marks what lies beyond as beyond what
this calibration has seen (:data:`fdi.envelope.RANGE`).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from calibration.inflight.fit import ImuAlignmentFit, InflightFit, axis_noise
from calibration.inflight.offset_check import SIGN_CONVENTION
from calibration.inflight.timing import flight_identity
from calibration.residual_models import with_residual_models
from calibration.residuals import allan_table
from fdi.calfile import AllanTable, Calibration, SensorCal, SensorSet, tangent_basis
from fdi.envelope import covered_jolt, covered_rate, covered_specific_force
from fdi.extras import (
    INFLIGHT_LAYOUT,
    CalibrationExtras,
    FlightIdentity,
    FlightValues,
    ImuAlignment,
    ImuTiming,
    InflightAlignment,
    InflightTiming,
    LeftOut,
    Method,
    ParameterRecord,
)
from fdi.units import RAW_UNITS
from replay.envelope import flight_accel
from replay.flight_data import Flight

__all__ = ["INFLIGHT_METHOD", "calibration_from_fit", "flight_values", "noise_split",
           "sensor_residuals"]

INFLIGHT_METHOD = "in-flight alignment to a reference IMU (calibration.inflight/1)"
_AXES = "xyz"


def noise_split(fit: InflightFit) -> dict[str, np.ndarray]:
    """Per-sample noise covariance (3×3, rad²/s², each IMU's own frame) of every IMU
    (module docstring; :func:`calibration.inflight.fit.axis_noise`)."""
    return axis_noise(fit.alignments, fit.reference)[1]


def _allan(fit: InflightFit, noise: dict[str, np.ndarray]) -> AllanTable | None:
    tables = {}
    for g, a in fit.alignments.items():
        r = a.residual[np.all(np.isfinite(a.residual), axis=1)]
        if r.shape[0] < 64:
            return None
        tables[g] = (allan_table(r, fit.sample_rate_hz), np.var(r, axis=0))
    if any(t is None for t, _ in tables.values()):
        return None
    first = next(iter(tables))
    taus = tables[first][0].tau_s
    cols = []
    for g in fit.imus:
        src = first if g == fit.reference else g
        tab, var = tables[src]
        share = np.sqrt(np.diag(noise[g]) / np.where(var > 0, var, 1.0))
        cols.append(tab.adev[:len(taus)] * share)
    return AllanTable(taus, np.hstack(cols))


def _sf_unit(raw_unit: str) -> str:
    return f"(rad/s)/{raw_unit}" if raw_unit in RAW_UNITS else "(rad/s)/raw"


def sensor_residuals(fit: InflightFit, flight: Flight) -> np.ndarray:
    """Residual per sensor (N, n) rad/s whose parity is the monitor's parity of the flight.

    The reference's compensated outputs are its readings (SF 1, bias 0); IMU j's axis k
    reads ``y = (u − c_k)/|A_k|``, so ``y_jk − h_k·y_ref = r_jk/|A_k|`` with ``r`` the fit
    residual. The reference's column is 0, IMU j's is ``r_jk/|A_k|``: ``V·e`` equals the
    parity of the compensated outputs (``V·H̃ = 0``). NaN on the samples the fit left out.
    """
    e = np.zeros((flight.t.shape[0], flight.n))
    e[~fit.used] = np.nan
    for g, idx in flight.imu_groups().items():
        a = fit.alignments.get(g)
        if a is None:
            continue
        for k, i in enumerate(idx):
            e[:, i] = a.residual[:, k] / float(np.linalg.norm(a.A[k]))
    return e


def calibration_from_fit(fit: InflightFit, flight: Flight, *, tails: bool = True,
                         jitter: bool = True, drift_model: bool = False,
                         turn_on_sd: dict[str, np.ndarray] | None = None,
                         flights: tuple[FlightValues, ...] = ()) -> Calibration:
    """The ``rimu.calibration/3`` calibration of a flight's gyro set (module docstring).

    With ``tails`` the residual's tail model per window scale is fitted and kept
    (:mod:`calibration.tails`). With ``jitter`` (default) each IMU's timing jitter goes into
    its sensors (``SensorCal.timing_jitter``) and the tail model is measured relative to the
    monitor's threshold inflation (calibration uncertainty and jitter,
    :func:`fdi.reconstruction.inflation_terms`); without it the jitter is 0 and the tails
    are those of the bare statistic (the behaviour before the jitter term). With
    ``drift_model`` the slow drift of the residual's whitened parity is kept too
    (:mod:`calibration.drift`; ``rimu calibrate in-flight --drift-model``): ``tune`` then
    covers the drift expected over its horizon, at a price in detectable size
    (``docs/drift.md``). ``turn_on_sd`` (per IMU group, per axis, rad/s) gives each
    sensor's ``bias_turn_on_sd`` and ``flights`` each flight's own values
    (:mod:`calibration.inflight.multi`).
    """
    noise = noise_split(fit)
    groups = flight.imu_groups()
    sensors: list[SensorCal] = []
    n = flight.n
    cov = np.zeros((n, n))
    sfu = _sf_unit(flight.raw_unit)
    for g, idx in groups.items():
        cov[np.ix_(idx, idx)] = noise[g]
        a = fit.alignments.get(g)
        for k, i in enumerate(idx):
            if a is None:
                A_k, C, c, c_sd = np.eye(3)[k], np.zeros((3, 3)), 0.0, 0.0
                jit, jit_sd = 0.0, 0.0                      # the reference
            else:
                A_k = a.A[k]
                C = a.A_cov[3 * k:3 * k + 3, 3 * k:3 * k + 3]
                c, c_sd = float(a.c[k]), float(np.sqrt(a.c_cov[k, k]))
                jit, jit_sd = _finite0(a.timing_jitter_s), _finite0(a.timing_jitter_sd_s)
                if not jitter:
                    jit, jit_sd = 0.0, 0.0
            g_k = float(np.linalg.norm(A_k))
            ton = (None if turn_on_sd is None or g not in turn_on_sd
                   else float(turn_on_sd[g][k]) / g_k)
            h = A_k / g_k
            nom = np.zeros(3)
            nom[int(np.argmax(np.abs(h)))] = np.sign(h[int(np.argmax(np.abs(h)))])
            E = tangent_basis(nom)
            ms = np.sqrt(np.clip(np.diag(E @ C @ E.T), 0, None)) / g_k
            r = a.residual[:, k] if a is not None else None
            rms = float(np.sqrt(np.nanmean(r**2))) if r is not None else float(
                np.sqrt(noise[g][k, k]))
            sensors.append(SensorCal(
                name=flight.sensor_names[i], axis=h, axis_nominal=nom,
                scale_factor=1.0 / g_k, scale_factor_sd=float(np.sqrt(h @ C @ h)) / g_k**2,
                bias=c / g_k, bias_sd=c_sd / g_k, input_error_cov=C, misalignment_sd=ms,
                raw_unit=flight.raw_unit, scale_factor_unit=sfu, bias_unit="deg/h",
                residual_rms=rms, timing_jitter=jit, timing_jitter_sd=jit_sd,
                bias_turn_on_sd=ton))
    H = np.array([c.axis for c in sensors])
    sf = np.array([c.scale_factor for c in sensors])
    b = np.array([c.bias for c in sensors])
    covered = covered_rate(H, list(groups.values()), np.asarray(flight.raw, float) * sf - b,
                           fit.used)
    acc = flight_accel(flight)
    force = covered_specific_force(acc, fit.used) if acc is not None else None
    jolt = covered_jolt(acc, fit.used) if acc is not None else None
    gs = SensorSet("gyro", tuple(sensors), cov, allan=_allan(fit, noise),
                   validated_rate=covered, validated_specific_force=force,
                   validated_jolt=jolt)
    if tails or drift_model:
        gs = with_residual_models(gs, sensor_residuals(fit, flight), flight.raw,
                                  fit.sample_rate_hz, tails=tails, drift=drift_model,
                                  inflation=jitter,
                                  source="in-flight alignment residual (samples the fit used)")
    timing, alignment = fit_records(fit, flight)
    if flights:
        alignment = replace(alignment, flights=tuple(flights))
    return Calibration(configuration=f"{len(groups)} IMUs in flight", sets={"gyro": gs},
        sample_rate_hz=fit.sample_rate_hz,
        extra=CalibrationExtras(method=Method(INFLIGHT_METHOD), source=fit.source,
                                inflight=timing, inflight_alignment=alignment
                                ).to_dict(INFLIGHT_LAYOUT))


def _finite0(x: float) -> float:
    """x when finite and ≥ 0, else 0 (no estimate: no jitter term)."""
    x = float(x)
    return x if math.isfinite(x) and x >= 0 else 0.0


def _rows(m: np.ndarray) -> tuple[tuple[float, ...], ...]:
    return tuple(tuple(r) for r in np.asarray(m, float).tolist())


def _alignment(a: ImuAlignmentFit, axis_sd: np.ndarray) -> ImuAlignment:
    """The typed record of one IMU's fitted alignment."""
    parts = a.parts()
    r = a.residual[np.all(np.isfinite(a.residual), axis=1)]
    lag1 = [float(np.corrcoef(r[1:, k], r[:-1, k])[0, 1]) for k in range(3)]
    return ImuAlignment(
        model=a.model, A=_rows(a.A), A_sd=_rows(np.sqrt(np.diag(a.A_cov)).reshape(3, 3)),
        **{name: tuple(v.tolist()) for name, (v, _) in parts.items()},
        **{f"{name}_sd": tuple(sd.tolist()) for name, (_, sd) in parts.items()},
        bias=tuple(a.c.tolist()), bias_sd=tuple(np.sqrt(np.diag(a.c_cov)).tolist()),
        residual_rms=tuple(np.sqrt(np.mean(r**2, axis=0)).tolist()),
        residual_lag1_autocorrelation=tuple(lag1), hac_lags=a.lags, samples=int(r.shape[0]),
        excitation=_finite_dict(a.excitation.to_dict()), notes=tuple(a.notes),
        mounting=_rows(a.mounting),
        parameters=tuple(ParameterRecord(
            p.name, p.value, p.sd, p.prior_sd, p.status,
            p.excitation if math.isfinite(p.excitation) else None) for p in a.parameters),
        axis_noise=tuple(np.asarray(axis_sd, float).tolist()))


def _finite_dict(d: dict) -> dict:
    """Non-finite numbers in lists as None (JSON has no inf)."""
    def f(v):
        if isinstance(v, list):
            return [f(x) for x in v]
        if isinstance(v, float) and not math.isfinite(v):
            return None
        return v
    return {k: f(v) for k, v in d.items()}


def fit_records(fit: InflightFit, flight: Flight) -> tuple[InflightTiming, InflightAlignment]:
    """The typed ``extra.inflight`` of a fit: the offsets with their checks, the sign
    convention and the identity of the flight they belong to; every alignment estimate
    with its sd, excitation and residuals."""
    timing = InflightTiming(
        reference=fit.reference, time_offset_sign=SIGN_CONVENTION,
        flight=FlightIdentity(**flight_identity(flight)),
        imus={g: ImuTiming(time_offset_s=a.time_offset_s, time_offset_sd_s=a.time_offset_sd_s,
                           timing_jitter_s=a.timing_jitter_s,
                           timing_jitter_sd_s=a.timing_jitter_sd_s, check=a.check)
              for g, a in fit.alignments.items()})
    alignment = InflightAlignment(
        imus={g: _alignment(a, fit.axis_noise.get(g, ())) for g, a in fit.alignments.items()},
        left_out=tuple(LeftOut(s.t0_s, s.t1_s, s.reason, s.detail) for s in fit.left_out),
        samples_used=int(fit.used.sum()), samples=int(fit.used.shape[0]),
        samples_nonfinite=int(getattr(fit, "nonfinite", 0)),
        findings=tuple(x.text() for x in fit.findings),
        reference_noise=tuple(np.asarray(fit.axis_noise.get(fit.reference, ()),
                                         float).tolist()),
        prior={} if fit.prior is None else fit.prior.to_dict(fit.sample_rate_hz),
        window_s=() if fit.window is None else tuple(float(x) for x in fit.window))
    return timing, alignment


def flight_values(fit: InflightFit, flight: Flight) -> FlightValues:
    """One flight's own values (its biases, offsets, jitter and the parts of E), for
    ``extra.inflight.flights`` of a joint calibration."""
    imus = {}
    for g, a in fit.alignments.items():
        parts = a.parts()
        imus[g] = {"bias_dph": tuple(a.c.tolist()),
                   "bias_dph_sd": tuple(np.sqrt(np.diag(a.c_cov)).tolist()),
                   "time_offset_ms": (a.time_offset_s,),
                   "time_offset_ms_sd": (a.time_offset_sd_s,),
                   "timing_jitter_ms": (_finite0(a.timing_jitter_s),),
                   **{k: tuple(v.tolist()) for k, (v, _) in parts.items()},
                   **{f"{k}_sd": tuple(sd.tolist()) for k, (_, sd) in parts.items()}}
    return FlightValues(source=fit.source, flight=FlightIdentity(**flight_identity(flight)),
                        imus=imus)
