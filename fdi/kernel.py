"""The monitor's per-sample recursion, compiled once (numba, ``cache=True``).

:func:`advance` runs rows r0 … r1−1 of a block (one row for :meth:`fdi.monitor.Monitor.step`,
many for :meth:`~fdi.monitor.Monitor.run`: the same machine code, hence bit-identical
answers). Per sample, with the constants of the current healthy set (:mod:`fdi.state`):

1. Health (:func:`health_checks`): a valid raw value outside lo < u < hi (``range``;
   NaN/inf: ``nonfinite``), ``stuck_count`` identical values (``stuck``), no valid sample
   for ``stale_timeout_s`` (``stale``). Any verdict stops the kernel: the monitor isolates
   and resumes the same sample at re-admission.
2. Re-admission (opt-in, :func:`readmission_check`): an isolated sensor that agrees with the
   reconstruction (|y_i − h_iᵀω̂|² < ``readmit_gate``·var, 9: 3σ) for ``readmit_dwell_s``
   stops the kernel.
3. A healthy sensor without a sample stops the kernel (the monitor reconstructs from the
   sensors present; no parity test, infinite protection level).
4. :func:`compensate`: y = SF·u − b − c (c: run-time correction of the effect terms),
   parity p = V·y, whitened parity z = A·p (Cov z = I),
   ω̂ = G·y and ρ = max_i [ω̂ᵀC_iω̂ + τ_i²(h_iᵀω̇̂)²]/Σ_ii (seed 001 Eq. 21 for the
   zeroed rows of H̃; the second term is the timing jitter τ_i of sensor i against the
   reference, with ω̇̂_t = (ω̂_t − ω̂_{t−1})·fs and ω̂_{t−1} the ω̂ of the last completed
   sample, kept in the detector state; a non-finite ω̇̂ counts as 0).
   These depend on the row and the set only, so :func:`compensate_ahead` computes them
   (and the protection level, step 7) for up to ``BLOCK_ROWS`` rows before their health
   checks; a row the kernel stops at or before is computed again by the next call. The
   first row of a block reads ω̂_{t−1} from the state, the others the row before in the
   block; the state's ω̂_{t−1} moves on only when a sample completes (its parity tests ran,
   or it was incomplete), so a sample the kernel stops during is compensated again with the
   same ω̂_{t−1}, and :meth:`~fdi.monitor.Monitor.step` and :meth:`~fdi.monitor.Monitor.run`
   see the same one. When the monitor reconstructs a completed sample (an incomplete one,
   or after an exclusion: :func:`reconstruct_row`) it reads the ω̂ before that sample, kept
   beside, and its new ω̂ becomes ω̂_{t−1}.
5. Windows (:func:`fdi.windows.window_update`) and the CUSUM bank
   (:func:`fdi.cusum.cusum_update`).
6. Detection state machine (:func:`detection_machine`): a detection or an isolation stops
   the kernel after the sample (the monitor attributes it, names the events, isolates).
7. Protection level PL(ρ) = a·sqrt(1 + bρ) + c·sqrt(d + eρ) (:mod:`fdi.integrity`).

The kernel never raises on numbers: a bad raw value only makes non-finite numbers in the
compensation ahead (``error_model="numpy"``, no floating-point traps), and the health
checks stop the kernel before any of them enters the windows, the CUSUM bank or a kept
output row.
"""

from __future__ import annotations

import hashlib
import math
from pathlib import Path

import numpy as np
from numba import njit

from fdi.cusum import cusum_update
from fdi.state import (
    ALARM_RUN,
    ASK_ISOLATE,
    AXIS0,
    BIAS,
    BLOCK_ROWS,
    CAND_T,
    CAPABILITY,
    CAPABILITY_CODE,
    CLEAR_RUN,
    CLEAR_SAMPLES,
    CUSUM_CLEAR,
    CUSUM_H,
    CUSUM_ROWS,
    DETECTED,
    DETECTED_ROWS,
    DF,
    ENV_OUT,
    FIRED,
    GOOD_SINCE_T,
    H_P_H,
    HAS_CUSUM,
    HAS_OMEGA,
    HAS_PARITY,
    HAS_VALID,
    HEALTH0,
    HEALTH_NONFINITE,
    HEALTH_OK,
    HEALTH_RANGE,
    HEALTH_STALE,
    HEALTH_STUCK,
    HI,
    HOLD_OPEN,
    IN_SET,
    JITTER_COEF,
    LAST_GOOD_T,
    LAST_RAW,
    LAST_VALID_T,
    LO,
    MAX_TIME_STEP_S,
    MISSED_RUN,
    N_WINDOWS,
    NOISE_BAND,
    NOISE_CLIP,
    NOISE_GAIN,
    NOISE_MAX,
    OMEGA0,
    PERSISTENCE,
    PHASE,
    PHASE_HEALTH,
    PHASE_READMIT,
    PL_A,
    PL_B,
    PL_C,
    PL_D,
    PL_E,
    PROTECTION,
    READMISSION,
    READMIT_DWELL_S,
    READMIT_GATE,
    READMIT_SENSOR,
    REBASE_RUN,
    REBASE_SAMPLES,
    RETURN_DETECTED,
    RHO_COEF0,
    RING_LEN,
    SAME_RUN,
    SCALE_COLS,
    SCRATCH_BEFORE,
    SCRATCH_BLOCK,
    SCRATCH_P,
    SCRATCH_PREV,
    SCRATCH_W,
    SCRATCH_Y,
    SCRATCH_Z,
    SENSOR_COLS,
    SENSOR_STATE_COLS,
    SET_FCONST,
    SET_ICONST0,
    SET_MATS,
    SET_SCALES,
    SET_SENSORS,
    SF,
    SIGMA_II,
    STALE_SAMPLES,
    STALE_TIMEOUT_S,
    STARTED,
    STATE_CLOCK,
    STATE_CUSUM,
    STATE_NOISE,
    STATE_SENSOR,
    STATE_VIB,
    STATE_WINDOWS,
    STATE_ZPREV,
    STATS0,
    STOP_CLEARED,
    STOP_CODE,
    STOP_DETECTED,
    STOP_HEALTH,
    STOP_INCOMPLETE,
    STOP_ISOLATE,
    STOP_NONE,
    STOP_READMIT,
    STOP_ROW,
    STOP_VIBRATION,
    STUCK_COUNT,
    THRESHOLD,
    TIME_BACKWARD,
    TIME_CODE,
    TIME_JUMP,
    TIME_NONFINITE,
    TIME_OK,
    TIME_REBASED,
    TIME_STATUS,
    U_NORM2,
    VIB_DWELL,
    VIB_LEVEL,
    VIB_ON,
    VIB_RATIO,
    VIB_RUN,
    VIB_SENSOR,
    WINDOW_COUNT,
    ZPREV_OK,
    offset,
)
from fdi.state import span as _span_py
from fdi.windows import window_update

__all__ = ["advance", "compensate", "reconstruct_row"]

# Every kernel function is compiled without numba's reference counting (``_nrt=False``): the
# kernel allocates nothing (its scratch vectors live in the detector state), and with
# counting on, the array arguments of the inlined helpers cost an atomic increment and
# decrement each per sample, most of the kernel's time. Only the two entry points are cached
# (see _entry_points): a cached inner function would be reloaded after an edit of a module
# it inlines.
_KERNEL = dict(error_model="numpy", _nrt=False)
_INLINE = dict(_KERNEL, inline="always")

_NONE = CAPABILITY_CODE["none"]


_span = njit(**_INLINE)(_span_py)           # fdi.state.span, compiled inline


@njit(**_INLINE)
def _finite(x):
    """x when finite, else 0."""
    return x if math.isfinite(x) else 0.0


@njit(**_INLINE)
def set_views(kset, n):
    """The packed constants of a set (:class:`fdi.state.KernelSet`) as (fconst, sensors,
    scales, mats, df, nw)."""
    df = int(kset[SET_ICONST0 + DF])
    nw = int(kset[SET_ICONST0 + N_WINDOWS])
    return (_span(kset, SET_FCONST, n, nw),
            _span(kset, SET_SENSORS, n, nw).reshape(SENSOR_COLS, n),
            _span(kset, SET_SCALES, n, nw).reshape(nw, SCALE_COLS),
            kset[offset(SET_MATS, n, nw):].reshape(3 * df + 3, n), df, nw)


@njit(**_INLINE)
def scratch_views(values, n):
    """The kernel's scratch vectors y, p, z (n each) and ω̂ (3) in the detector state, the
    ω̂ of the last completed sample and of the one before it (3 each: ``prev``,
    ``before``), and the block of (z, ρ) rows, shape (BLOCK_ROWS, n + 1)
    (:data:`fdi.state.STATE_PARTS`)."""
    return (_span(values, SCRATCH_Y, n, 0), _span(values, SCRATCH_P, n, 0),
            _span(values, SCRATCH_Z, n, 0), _span(values, SCRATCH_W, n, 0),
            _span(values, SCRATCH_PREV, n, 0), _span(values, SCRATCH_BEFORE, n, 0),
            _span(values, SCRATCH_BLOCK, n, 0).reshape(BLOCK_ROWS, n + 1))


@njit(**_INLINE)
def compensate(raw, r, corr, cr, sensors, mats, df, has_omega, y, p, z, w, v0, v1,
               v2) -> float:
    """y = SF·u − b − c, p = V·y, z = A·p, ω̂ = G·y of the sensors of the set, row r;
    returns ρ. ``sensors`` is laid out (SENSOR_COLS, n): one row per quantity.
    (v0, v1, v2) is the ω̂ of the sample before (rad/s): the timing-jitter term of ρ reads
    Δω̂ = ω̂ − ω̂_{t−1} (zero when not finite).

    ``c = corr[cr]`` is the run-time correction of the effect terms (rad/s; a non-finite entry
    counts as 0, so a bad input of an effect never reaches the parity). Sums run over the
    sensors of the set in ascending order (left to right). Without three independent
    sensors ω̂ is NaN and ρ is 0.
    """
    n = sensors.shape[1]
    # Dense loops over all n sensors: a sensor outside the set has y = −0.0 and zero columns
    # in V and G and zero ρ coefficients (:func:`fdi.state.pack_set`), and x + (+0·−0) = x
    # for every x (also −0, ±inf, NaN), so the sums equal those over the set's sensors alone,
    # bit for bit, in the same order.
    for i in range(n):
        yi = sensors[SF, i] * raw[r, i] - sensors[BIAS, i] - _finite(corr[cr, i])
        y[i] = yi if sensors[IN_SET, i] != 0.0 else -0.0
    for j in range(df):
        acc = 0.0
        for i in range(n):
            acc = acc + mats[j, i] * y[i]
        p[j] = acc
    a0 = df + 3
    for j in range(df):
        acc = 0.0
        for k in range(j + 1):
            acc = acc + mats[a0 + j, k] * p[k]
        z[j] = acc
    if not has_omega:
        w[0] = np.nan
        w[1] = np.nan
        w[2] = np.nan
        return 0.0
    w0 = 0.0
    w1 = 0.0
    w2 = 0.0
    for i in range(n):
        w0 = w0 + mats[df, i] * y[i]
        w1 = w1 + mats[df + 1, i] * y[i]
        w2 = w2 + mats[df + 2, i] * y[i]
    w[0] = w0
    w[1] = w1
    w[2] = w2
    q0, q1, q2 = w0 * w0, w1 * w1, w2 * w2
    q3, q4, q5 = w0 * w1, w0 * w2, w1 * w2
    d0, d1, d2 = w0 - v0, w1 - v1, w2 - v2
    if not (math.isfinite(d0) and math.isfinite(d1) and math.isfinite(d2)):
        d0, d1, d2 = 0.0, 0.0, 0.0
    rho = 0.0                       # a sensor outside the set gives s = 0 (or NaN): no change
    c = RHO_COEF0
    for i in range(n):
        s = (sensors[c, i] * q0 + sensors[c + 1, i] * q1 + sensors[c + 2, i] * q2
             + sensors[c + 3, i] * q3 + sensors[c + 4, i] * q4 + sensors[c + 5, i] * q5)
        jc = sensors[JITTER_COEF, i]
        if jc != 0.0:                   # τ = 0: exactly the calibration term (no 0·inf)
            a = (sensors[AXIS0, i] * d0 + sensors[AXIS0 + 1, i] * d1
                 + sensors[AXIS0 + 2, i] * d2)
            s = s + jc * (a * a)
        if s > rho:
            rho = s
    return rho


@njit(**_INLINE)
def time_check(t, clock, counters, max_step, rebase) -> int:
    """The time-stamp verdict of one sample (:data:`fdi.state.TIME`); keeps the monitor's
    time base in ``clock`` (:data:`fdi.state.CLOCK`).

    A time stamp is good when it is finite, not earlier than the last good one and at most
    ``max_step`` (s) after it (the first finite one is good). A bad one is not taken for the
    clocks; the sample is tested as any other. ``rebase`` bad time stamps in a row that are
    consistent among themselves (each finite, not earlier than the one before and at most
    ``max_step`` after it) become the new time base (a clock reset, a genuine jump): that
    sample is ``TIME_REBASED`` and good.
    """
    lg = clock[LAST_GOOD_T]
    if not math.isfinite(t):
        counters[REBASE_RUN] = 0
        return TIME_NONFINITE
    if lg != lg or (t >= lg and t - lg <= max_step):
        clock[LAST_GOOD_T] = t
        counters[REBASE_RUN] = 0
        return TIME_OK
    ct = clock[CAND_T]
    if counters[REBASE_RUN] > 0 and t >= ct and t - ct <= max_step:
        counters[REBASE_RUN] += 1
    else:
        counters[REBASE_RUN] = 1
    clock[CAND_T] = t
    if counters[REBASE_RUN] >= rebase:
        counters[REBASE_RUN] = 0
        clock[LAST_GOOD_T] = t
        return TIME_REBASED
    return TIME_BACKWARD if t < lg else TIME_JUMP


@njit(**_INLINE)
def health_checks(t, time_good, raw, r, valid, vr, sensors, sensor, counters, stuck,
                  stale_s, stale_n) -> int:
    """Health verdict per sensor of the set (``counters[HEALTH0 + i]``); returns how many
    failed. Each sensor's check reads only its own history, so the order of isolation does
    not change the verdicts.

    The stale clock runs on two counts: the time since the sensor's latest valid sample at
    a good time stamp (``time_good``: this sample's time stamp is good), and the samples in
    a row without a valid sample of it (more than ``stale_n``). A bad time stamp neither
    starts nor stops it (a valid sample at a bad time leaves the time unknown, NaN: the
    sample count alone decides until the next valid sample at a good time)."""
    failed = 0
    for i in range(sensors.shape[1]):
        counters[HEALTH0 + i] = HEALTH_OK
        if sensors[IN_SET, i] == 0.0:
            continue
        if valid[vr, i]:
            v = raw[r, i]
            if not (sensors[LO, i] < v and v < sensors[HI, i]):
                counters[HEALTH0 + i] = HEALTH_RANGE if math.isfinite(v) else HEALTH_NONFINITE
                failed += 1
                continue
            if v == sensor[i, LAST_RAW]:
                sensor[i, SAME_RUN] += 1.0
                if sensor[i, SAME_RUN] >= stuck:
                    counters[HEALTH0 + i] = HEALTH_STUCK
                    failed += 1
                    continue
            else:
                sensor[i, SAME_RUN] = 1.0
                sensor[i, LAST_RAW] = v
            sensor[i, MISSED_RUN] = 0.0
            if time_good:
                # equal time stamps keep the clock (a good time is never earlier)
                lvt = sensor[i, LAST_VALID_T]
                if t > lvt or lvt != lvt:
                    sensor[i, LAST_VALID_T] = t
            else:
                sensor[i, LAST_VALID_T] = np.nan
        else:
            sensor[i, MISSED_RUN] += 1.0
            if (sensor[i, MISSED_RUN] > stale_n
                    or (time_good and t - sensor[i, LAST_VALID_T] > stale_s)):
                counters[HEALTH0 + i] = HEALTH_STALE
                failed += 1
    return failed


@njit(**_INLINE)
def readmission_check(t, raw, r, corr, cr, valid, vr, sensors, mats, df, capability, sensor,
                      counters, dwell_s, gate, y, p, z, w, prev) -> int:
    """First isolated sensor that behaved for ``dwell_s`` (−1: none).

    Good behaviour: valid, within the raw bounds, not repeating, and |y_i − h_iᵀω̂|² below
    gate·(Σ_ii + h_iᵀPh_i) with ω̂ from the healthy set (``gate``: the squared standardised
    residual, :attr:`fdi.settings.MonitorSettings.readmit_gate`; 9 is 3σ), at a good time
    stamp (a bad one restarts the dwell: its length is not known).
    """
    if capability == _NONE or counters[DETECTED] != 0:
        return -1
    n = sensors.shape[1]
    time_good = counters[TIME_STATUS] == TIME_OK or counters[TIME_STATUS] == TIME_REBASED
    for i in range(n):
        if sensors[IN_SET, i] != 0.0 and not valid[vr, i]:
            return -1
    compensate(raw, r, corr, cr, sensors, mats, df, True, y, p, z, w, prev[0], prev[1],
               prev[2])
    for i in range(n):
        if sensors[IN_SET, i] != 0.0:
            continue
        v = raw[r, i]
        good = (valid[vr, i] and sensors[LO, i] < v and v < sensors[HI, i]
                and v != sensor[i, LAST_RAW])
        if good:
            yi = sensors[SF, i] * v - sensors[BIAS, i] - _finite(corr[cr, i])
            hw = (sensors[AXIS0, i] * w[0] + sensors[AXIS0 + 1, i] * w[1]
                  + sensors[AXIS0 + 2, i] * w[2])
            var = sensors[SIGMA_II, i] + sensors[H_P_H, i]
            good = (yi - hw) ** 2 < gate * var and time_good
        sensor[i, LAST_RAW] = v
        since = sensor[i, GOOD_SINCE_T]
        if not good:
            sensor[i, GOOD_SINCE_T] = np.nan
        elif since != since:
            sensor[i, GOOD_SINCE_T] = t
        elif t - since >= dwell_s:
            return i
    return -1


@njit(**_INLINE)
def detection_machine(alarm, clear, fired, ask_isolate, persistence, clear_samples,
                      counters) -> int:
    """Detection state machine for one complete sample; returns the stop code.

    The first alarm detects; ``persistence`` consecutive alarms ask the monitor to isolate
    (when the set can tell hypotheses apart, ``ask_isolate``; the monitor decides,
    :func:`fdi.isolation.decide`, and is asked again at every further alarm until it
    excludes); a detection clears after ``clear_samples`` samples in a row below the
    clearing levels (hysteresis: one event per onset; the levels follow the threshold's
    inflation, :func:`fdi.windows.window_update`) once the windows hold at least
    ``counters[HOLD_OPEN]`` samples (set at envelope re-entry: a detection open then stays
    open until every window has refilled; before that the run of clear samples starts
    again), and stops the kernel after that sample (the monitor forgets its suspects).
    """
    code = STOP_NONE
    if counters[DETECTED] == 0:
        if not alarm:
            return STOP_NONE
        counters[DETECTED] = 1
        counters[DETECTED_ROWS] = 1
        counters[ALARM_RUN] = 1
        counters[CLEAR_RUN] = 0
        counters[FIRED] = fired
        code = STOP_DETECTED
    else:
        counters[DETECTED_ROWS] += 1
        if alarm and counters[CLEAR_RUN] > 0:
            # the evidence had fallen back below the clearing levels and rises again: a new
            # onset within the open detection; its isolation windows start here (what came
            # before, a false alarm, must not hide it)
            counters[DETECTED_ROWS] = 1
        counters[ALARM_RUN] = counters[ALARM_RUN] + 1 if alarm else 0
        counters[CLEAR_RUN] = counters[CLEAR_RUN] + 1 if clear else 0
    if ask_isolate and counters[ALARM_RUN] >= persistence:
        counters[FIRED] = fired
        code |= STOP_ISOLATE
    elif counters[DETECTED] != 0 and counters[CLEAR_RUN] >= clear_samples:
        if counters[WINDOW_COUNT] < counters[HOLD_OPEN]:     # not every window refilled yet
            counters[CLEAR_RUN] = 0
        else:
            counters[DETECTED] = 0
            code = STOP_CLEARED
    return code


@njit(**_INLINE)
def protection_level(fconst, rho) -> float:
    """PL(ρ) = a·sqrt(1 + bρ) + c·sqrt(d + eρ) (rad/s), :mod:`fdi.integrity`."""
    return (fconst[PL_A] * math.sqrt(1.0 + fconst[PL_B] * rho)
            + fconst[PL_C] * math.sqrt(fconst[PL_D] + fconst[PL_E] * rho))


@njit(**_INLINE)
def _untested_row(out, r, scales, fconst, nw, K, parity0):
    """Statistics NaN, base thresholds, parity NaN: a sample without a parity test."""
    for k in range(nw):
        out[r, STATS0 + k] = np.nan
        out[r, STATS0 + K + k] = scales[k, THRESHOLD]
    if K > nw:
        out[r, STATS0 + nw] = np.nan
        out[r, STATS0 + K + nw] = fconst[CUSUM_H]
    for j in range(parity0, out.shape[1]):
        out[r, j] = np.nan


@njit(**_INLINE)
def noise_scale(noise, fconst) -> float:
    """s = min(K, max(1, v/(1 + band))): the factor the windows' thresholds and clearing
    levels take for the in-flight noise level v (:func:`noise_update`, before this
    sample's own contribution)."""
    s = noise[0] / fconst[NOISE_BAND]
    if not s > 1.0:                     # (also NaN)
        return 1.0
    m = fconst[NOISE_MAX]
    return s if s < m else m


@njit(**_INLINE)
def noise_update(z, df, sensors, mats, fconst, iconst_vib_on, vib_dwell, noise, zprev, vib,
                 counters) -> int:
    """Add one complete sample to the noise levels; returns the sensor that passed the
    vibration test for its dwell (−1: none).

    From the difference of two consecutive whitened parities d = z_t − z_{t−1} (the last
    complete sample of the same set; nothing out of the envelope): the level of the whole
    parity and of each sensor (:func:`_noise_levels`). A difference removes what changes
    slowly (a bias, a drift) and keeps what is noise. Then the vibration test
    (:func:`_vibration_test`).
    """
    if counters[ENV_OUT] != 0:
        return -1
    if counters[ZPREV_OK] != 0:
        _noise_levels(z, df, sensors, mats, fconst, noise, zprev, vib)
    for j in range(df):
        zprev[j] = z[j]
    counters[ZPREV_OK] = 1
    if not iconst_vib_on:
        return -1
    return _vibration_test(sensors, fconst, vib_dwell, vib, counters)


@njit(**_INLINE)
def _noise_levels(z, df, sensors, mats, fconst, noise, zprev, vib) -> None:
    """One step of the noise levels from d = z − zprev: of the whole parity,
    v += λ(min(|d|²/(2·df), clip·v) − v), and along each sensor's unit whitened column e_i,
    v_i += λ(min((e_iᵀd)²/2, clip·v_i) − v_i); 1 is the calibrated level. A non-finite
    step leaves a level as it was."""
    n = sensors.shape[1]
    lam = fconst[NOISE_GAIN]
    clip = fconst[NOISE_CLIP]
    acc = 0.0
    for j in range(df):
        d = z[j] - zprev[j]
        acc = acc + d * d
    q = acc / (2.0 * df)
    v = noise[0]
    if math.isfinite(q):
        if q > clip * v:
            q = clip * v
        noise[0] = v + lam * (q - v)
    u0 = 2 * df + 3
    for i in range(n):
        if sensors[IN_SET, i] == 0.0:
            continue
        a = 0.0
        for j in range(df):
            a = a + mats[u0 + j, i] * (z[j] - zprev[j])
        q = 0.5 * (a * a)
        vi = vib[i]
        if math.isfinite(q):
            if q > clip * vi:
                q = clip * vi
            vib[i] = vi + lam * (q - vi)


@njit(**_INLINE)
def _in_flight_variance(sensors, vib, i) -> float:
    """P_i = Σ_ii + max(v_i − 1, 0)/|u_i|² (SI²): sensor i's in-flight noise variance, its
    calibrated Σ_ii plus the excess its level v_i shows along its unit whitened column (a
    sensor alone at a times Σ_ii gives v_i = 1 + (a − 1)·|u_i|²·Σ_ii). It compares sensors
    in physical units: a sensor whose calibration under-stated its noise has a large v_i
    without being noisier than its peers."""
    u2 = sensors[U_NORM2, i]
    x = vib[i] - 1.0
    if not x > 0.0 or not u2 > 0.0:           # (also NaN)
        return sensors[SIGMA_II, i]
    return sensors[SIGMA_II, i] + x / u2


@njit(**_INLINE)
def _vibration_test(sensors, fconst, vib_dwell, vib, counters) -> int:
    """The sensor with the largest v_i, above ``VIB_LEVEL`` and more than ``VIB_RATIO`` times
    the next largest, whose in-flight variance (:func:`_in_flight_variance`) is also more than
    ``VIB_RATIO`` times every other sensor's, for ``vib_dwell`` samples in a row (−1: none
    yet)."""
    n = sensors.shape[1]
    top = -1
    v1 = -np.inf
    v2 = -np.inf
    for i in range(n):
        if sensors[IN_SET, i] == 0.0:
            continue
        x = vib[i]
        if x > v1:
            v2 = v1
            v1 = x
            top = i
        elif x > v2:
            v2 = x
    passes = top >= 0 and v1 > fconst[VIB_LEVEL] and v1 > fconst[VIB_RATIO] * v2
    if passes:
        p_top = _in_flight_variance(sensors, vib, top)
        for i in range(n):
            if i != top and sensors[IN_SET, i] != 0.0 and not (
                    p_top > fconst[VIB_RATIO] * _in_flight_variance(sensors, vib, i)):
                passes = False
                break
    if passes:
        if counters[VIB_RUN] > 0 and counters[VIB_SENSOR] == top:
            counters[VIB_RUN] += 1
        else:
            counters[VIB_RUN] = 1
            counters[VIB_SENSOR] = top
    else:
        counters[VIB_RUN] = 0
    if counters[VIB_RUN] >= vib_dwell:
        counters[VIB_RUN] = 0
        return top
    return -1


@njit(**_INLINE)
def parity_tests(z, rho, df, sensors, scales, mats, fconst, has_cusum, windows, cusum,
                 counters, K, out, r, ns) -> tuple[bool, bool, int]:
    """Windows (thresholds and clearing levels times the noise scale ``ns``) and CUSUM
    bank of one complete sample; returns (alarm, clear, fired) for the state machine."""
    nw = scales.shape[0]
    alarm, clear, fired, best = window_update(z, rho, df, windows, counters, scales, K, out, r,
                                              ns)
    if has_cusum:
        g = cusum_update(z, rho, df, sensors, mats, fconst, cusum)
        h = fconst[CUSUM_H]
        out[r, STATS0 + nw] = g
        out[r, STATS0 + K + nw] = h
        if g > h:
            alarm = True
            if g / h > best:
                fired = nw
        if g >= fconst[CUSUM_CLEAR]:
            clear = False
    return alarm, clear, fired


@njit(**_KERNEL)
def _advance(t, raw, corr, valid, r0, r1, kset, values, counters, out) -> int:
    """Run samples r0 … r1−1 until one needs the monitor; see the module docstring.

    Parameters
    ----------
    t : ndarray, shape (N,)
    raw : ndarray, shape (N, n)
    corr : ndarray, shape (N, n), or (1, n) for one correction of every sample
        Run-time correction of the effect terms (rad/s), subtracted from y.
    valid : ndarray of bool, shape (N, n), or (1, n) when every sample is valid
    r0, r1 : int
    kset : ndarray
        Constants of the healthy set (:attr:`fdi.state.KernelSet.packed`).
    values : ndarray
        Float detector state (:attr:`fdi.state.DetectorState.values`), updated in place.
    counters : ndarray of int64
        Integer detector state (:attr:`fdi.state.DetectorState.counters`), updated in place.
    out : ndarray, shape (N, width)
        Output rows (:class:`fdi.state.OutLayout`).

    Returns
    -------
    int
        The stop code (``counters[STOP_CODE]``), plus :data:`fdi.state.RETURN_DETECTED`
        while a detection is active.

    Notes
    -----
    On return ``counters[STOP_ROW]`` is the row the kernel stopped at (r1 when it ran
    through) and ``counters[STOP_CODE]`` why. Detections and isolations stop *after* their
    sample; health, re-admission and incomplete samples *during* it (``PHASE`` tells where
    the next call resumes).
    """
    n = raw.shape[1]
    fconst, sensors, scales, mats, df, nw = set_views(kset, n)
    ic = SET_ICONST0
    has_omega = kset[ic + HAS_OMEGA] != 0.0
    has_cusum = kset[ic + HAS_CUSUM] != 0.0
    ask_isolate = kset[ic + ASK_ISOLATE] != 0.0
    capability = int(kset[ic + CAPABILITY])
    readmission = kset[ic + READMISSION] != 0.0
    stuck = kset[ic + STUCK_COUNT]
    persistence = int(kset[ic + PERSISTENCE])
    clear_samples = int(kset[ic + CLEAR_SAMPLES])
    stale_s = fconst[STALE_TIMEOUT_S]
    stale_n = fconst[STALE_SAMPLES]
    max_step = fconst[MAX_TIME_STEP_S]
    rebase = int(kset[ic + REBASE_SAMPLES])
    vib_on = kset[ic + VIB_ON] != 0.0
    vib_dwell = int(kset[ic + VIB_DWELL])
    dwell_s = fconst[READMIT_DWELL_S]
    gate = fconst[READMIT_GATE]
    R = counters[RING_LEN]
    sensor = _span(values, STATE_SENSOR, n, 0).reshape(n, SENSOR_STATE_COLS)
    clock = _span(values, STATE_CLOCK, n, 0)
    noise = _span(values, STATE_NOISE, n, 0)
    zprev = _span(values, STATE_ZPREV, n, 0)
    vib = _span(values, STATE_VIB, n, 0)
    cusum = _span(values, STATE_CUSUM, n, 0).reshape(CUSUM_ROWS, n)
    o_windows = offset(STATE_WINDOWS, n, 0)
    windows = values[o_windows:o_windows + (R + 1) * (df + 1)].reshape(R + 1, df + 1)
    y, p, z, w, prev, before, block = scratch_views(values, n)
    K = nw + (1 if has_cusum else 0)
    parity0 = STATS0 + 2 * K
    has_valid = counters[HAS_VALID] != 0
    per_row_corr = corr.shape[0] > 1
    phase = counters[PHASE]
    counters[PHASE] = PHASE_HEALTH
    has_parity = counters[HAS_PARITY] != 0
    b0 = r0                                 # rows b0 … b1−1 compensated ahead, in ``block``
    b1 = r0
    for r in range(r0, r1):
        if r >= b1:
            b0 = r
            b1 = min(r1, r + BLOCK_ROWS)
            compensate_ahead(raw, corr, b0, b1, sensors, mats, fconst, df, has_omega,
                             has_parity, parity0, y, p, z, w, prev, block, out)
        tr = t[r]
        vr = r if has_valid else 0
        cr = r if per_row_corr else 0
        if phase == PHASE_HEALTH:
            tc = time_check(tr, clock, counters, max_step, rebase)
            counters[TIME_STATUS] = tc
            out[r, TIME_CODE] = tc
            time_good = tc == TIME_OK or tc == TIME_REBASED
            if counters[STARTED] == 0 or tc == TIME_REBASED:
                _start(tr if time_good else np.nan, sensor, counters)
            if health_checks(tr, time_good, raw, r, valid, vr, sensors, sensor, counters,
                             stuck, stale_s, stale_n) > 0:
                return _stop(counters, r, STOP_HEALTH)
        if phase <= PHASE_READMIT and readmission:
            k = readmission_check(tr, raw, r, corr, cr, valid, vr, sensors, mats, df,
                                  capability, sensor, counters, dwell_s, gate, y, p, z, w,
                                  prev)
            if k >= 0:
                counters[READMIT_SENSOR] = k
                return _stop(counters, r, STOP_READMIT)
        phase = PHASE_HEALTH
        if has_valid and not _complete(sensors, valid, vr):
            _shift(prev, before)            # the monitor reconstructs the sample
            _untested_row(out, r, scales, fconst, nw, K, parity0)
            out[r, PROTECTION] = np.inf
            return _stop(counters, r, STOP_INCOMPLETE)
        code = STOP_NONE
        if df > 0:
            zr = block[r - b0]              # z (first df entries) and ρ (entry n) of row r
            ns = noise_scale(noise, fconst)
            alarm, clear, fired = parity_tests(zr, zr[n], df, sensors, scales, mats, fconst,
                                               has_cusum, windows, cusum, counters, K, out, r,
                                               ns)
            code = detection_machine(alarm, clear, fired, ask_isolate, persistence,
                                     clear_samples, counters)
            if noise_update(zr, df, sensors, mats, fconst, vib_on, vib_dwell, noise, zprev,
                            vib, counters) >= 0:
                code |= STOP_VIBRATION
        else:
            _untested_row(out, r, scales, fconst, nw, K, parity0)
        _shift(prev, before)                # the sample is complete: ω̂_{t−1} moves on
        prev[0] = out[r, OMEGA0]
        prev[1] = out[r, OMEGA0 + 1]
        prev[2] = out[r, OMEGA0 + 2]
        if code != STOP_NONE:
            return _stop(counters, r, code)
    return _stop(counters, r1, STOP_NONE)


@njit(**_INLINE)
def compensate_ahead(raw, corr, b0, b1, sensors, mats, fconst, df, has_omega, has_parity,
                     parity0, y, p, z, w, prev, block, out) -> None:
    """Compensate rows b0 … b1−1 (at most BLOCK_ROWS) with the current set, before their
    health checks: ω̂, the protection level and the parity go straight into their output
    rows, z and ρ into ``block`` for the windows and the CUSUM bank.

    These quantities depend on the row and the set only, not on the detector state, so the
    rows are independent and the processor overlaps them (the sequential part of the
    recursion starts at the windows). A row the kernel stops at or before is compensated
    again by the next call, with the set the monitor chose; rows it never tests (health
    verdicts, incomplete samples) are overwritten, so the extra work changes no answer.
    A bad raw value only gives non-finite numbers here (no exception: error_model numpy).
    The jitter term of row b0 reads ω̂_{t−1} from ``prev`` (the state's: the last completed
    sample), that of each later row the ω̂ of the row before it.
    """
    n = sensors.shape[1]
    per_row_corr = corr.shape[0] > 1
    v0, v1, v2 = prev[0], prev[1], prev[2]
    for q in range(b0, b1):
        rho = compensate(raw, q, corr, q if per_row_corr else 0, sensors, mats, df,
                         has_omega, y, p, z, w, v0, v1, v2)
        v0, v1, v2 = w[0], w[1], w[2]
        out[q, OMEGA0] = w[0]
        out[q, OMEGA0 + 1] = w[1]
        out[q, OMEGA0 + 2] = w[2]
        out[q, PROTECTION] = protection_level(fconst, rho)
        k = q - b0
        for j in range(df):
            block[k, j] = z[j]
        block[k, n] = rho
        if has_parity and df > 0:
            for j in range(df):
                out[q, parity0 + j] = p[j]
            for j in range(parity0 + df, out.shape[1]):
                out[q, j] = np.nan


@njit(**_INLINE)
def _shift(prev, before) -> None:
    """before = prev: the ω̂ before the sample the kernel completes (what a reconstruction
    of that sample by the monitor reads as ω̂_{t−1})."""
    before[0] = prev[0]
    before[1] = prev[1]
    before[2] = prev[2]


@njit(**_INLINE)
def _complete(sensors, valid, vr) -> bool:
    """Every sensor of the set delivered row ``vr`` of ``valid``."""
    for i in range(sensors.shape[1]):
        if sensors[IN_SET, i] != 0.0 and not valid[vr, i]:
            return False
    return True


@njit(**_INLINE)
def _start(t, sensor, counters) -> None:
    """The first sample, or the first of a new time base: every sensor's stale clock starts
    at its time (NaN: a bad time stamp, the sample count decides; the sample itself is not
    counted as missed, as the time clock counts intervals from it) and the re-admission
    dwells start again."""
    counters[STARTED] = 1
    for i in range(sensor.shape[0]):
        sensor[i, LAST_VALID_T] = t
        sensor[i, GOOD_SINCE_T] = np.nan
        sensor[i, MISSED_RUN] = -1.0        # this sample is the origin of both clocks


@njit(**_INLINE)
def _stop(counters, r, code) -> int:
    """Record where and why the kernel stopped; the return value of :func:`advance`."""
    counters[STOP_ROW] = r
    counters[STOP_CODE] = code
    return code + (RETURN_DETECTED if counters[DETECTED] != 0 else 0)


@njit(**_KERNEL)
def _reconstruct_row(raw, corr, r, kset, values, row) -> None:
    """ω̂ of one sample from the sensors of a set (row[OMEGA0 …]) and its protection level
    (row[PROTECTION]); used for incomplete samples and right after an isolation. The
    scratch vectors of the detector state ``values`` are overwritten. The sample is the one
    the kernel completed last: its jitter term reads the ω̂ before it (``before``), and its
    new ω̂ becomes the state's ω̂_{t−1}."""
    n = raw.shape[1]
    fconst, sensors, _, mats, df, _ = set_views(kset, n)
    y, p, z, w, prev, before, _ = scratch_views(values, n)
    cr = r if corr.shape[0] > 1 else 0
    rho = compensate(raw, r, corr, cr, sensors, mats, df,
                     kset[SET_ICONST0 + HAS_OMEGA] != 0.0, y, p, z, w, before[0], before[1],
                     before[2])
    row[OMEGA0] = w[0]
    row[OMEGA0 + 1] = w[1]
    row[OMEGA0 + 2] = w[2]
    prev[0] = w[0]
    prev[1] = w[1]
    prev[2] = w[2]
    row[PROTECTION] = protection_level(fconst, rho)


def _sources_digest() -> str:
    """Digest of the sources compiled into the entry points (this module, the windows, the
    CUSUM bank and the slot constants of :mod:`fdi.state`)."""
    h = hashlib.sha256()
    here = Path(__file__)
    for name in ("kernel.py", "windows.py", "cusum.py", "state.py"):
        h.update(here.with_name(name).read_bytes())
    return h.hexdigest()


def _entry_points(sources: str):
    """The cached entry points. numba's cache checks the source of the file that holds a
    cached function, not of what it calls; the digest of every source compiled in sits in
    their closure, which numba's cache key includes, so an edit anywhere recompiles."""

    @njit(cache=True, **_KERNEL)
    def advance(t, raw, corr, valid, r0, r1, kset, values, counters, out):
        sources  # noqa: B018
        return _advance(t, raw, corr, valid, r0, r1, kset, values, counters, out)

    @njit(cache=True, **_KERNEL)
    def reconstruct_row(raw, corr, r, kset, values, row):
        sources  # noqa: B018
        _reconstruct_row(raw, corr, r, kset, values, row)

    advance.__doc__ = _advance.__doc__
    reconstruct_row.__doc__ = _reconstruct_row.__doc__
    return advance, reconstruct_row


advance, reconstruct_row = _entry_points(_sources_digest())
