"""Turntable closure with effects injected by hand (issue 18, Must hold).

Clean sessions of the presets (the product simulator, truth sidecar in memory) get one
effect added to the recorded raw samples of one sensor. Each effect is written here from
its physical definition (the true input along the sensor's true axis from the session's
own table angles and rates, :meth:`Session.inputs`), not through the simulator's knobs and
not with the library's regressors. Then the product's path as the command line runs it:
``rimu calibrate`` (:func:`calibrate_checked`, adequacy verdict) and ``rimu diagnose``
on that calibration (:func:`diagnose`, selection, refit, verdict of the refit). Claims,
over 10 seeds per effect:

- every library effect is found, under its own name, on the sensor it was put on;
- every effect outside the library is "unexplained" on that sensor, or the refit is
  refused as adequate (verdict "effects suspected");
- never a calibration or a refit called adequate (any verdict but "effects suspected")
  while a parameter of the truth is beyond 5 σ of it.

Run cost: the full tetrad-paper (576 s) and cone-paper (368 s) sequences at 100 Hz, white
noise from the truth (:func:`_diagnose_sessions.clean_fast`); the detectability limits are
switched off (``detectability=False``): they only turn an "adequate" verdict into a
weaker one, so the adequacy claim is checked against the strongest verdict the product
could give. The Allan table and the Earth-rate fit are skipped (they feed no parameter
the claims compare). 160 sessions, about 1-2 s each: 315-390 s wall (330-410 s with the
held-out check; 682 s with the closure probes under a load of 4-5) for the file with
``--campaign`` on the shared 2-core machine (the ~60 s
aimed for would need shorter sessions than the presets' sequences; the presets were
kept). Marked ``campaign``: it runs with ``pytest --campaign`` and not in CI, whose
budget it would take half of.

All 16 cases pass (2026-11-27). Fixed along the way, each once a strict expected failure:
by the held-out check (:mod:`calibration.diagnose.holdout`) the rate-sign hysteresis
(seeds 3, 9, 10: gyro 3's model fails its held-out check, worst fold p 1.5e-6 to 2e-5)
and the late quadratic drift (seed 8: gyro 4's bias_drift + warmup fail to predict the
first quarter, p 1.3e-4 against the limit 6.3e-4); by naming a failing change point
``bias_step`` (:func:`calibration.diagnose.selection._promote_steps`) the 3 °/h step of
seed 9 (under the coloured null the candidate's ln p -8.8 missed the Holm limit -9.1;
the change_point probe, p 1.5e-4 against its limit 1.8e-4, now names it: 2.94 ± 0.55
°/h on gyro 4); by the line stationarity probe (:mod:`calibration.diagnose.stationarity`)
the growing line of seeds 7 and 8 (claimed as a periodic_line of mean amplitude, refit
called adequate; now gyro 1 "unexplained (line_stationarity)", p 7e-7 and 2e-7).
"""

import dataclasses

import numpy as np
import pytest
from _diagnose_sessions import add_signal, clean_fast
from threadpoolctl import threadpool_limits

from calibration.calibrate_checked import calibrate_checked
from calibration.diagnose import diagnose
from calibration.effects import WARMUP_TAU_S
from fdi.units import DPH, DPS, G0

SEEDS = range(1, 11)
ADEQUATE_LIMIT = 5.0
"""A calibration called adequate must hold every parameter of the truth within this many σ."""


def _along(s, truth, kind, i):
    """True input along the true axis of sensor ``i`` (SI): rate (Earth included) or
    specific force, from the session's table angles and rates."""
    wt, we, fb = s.inputs()
    h = truth.sets[kind].H[i]
    return ((wt + we) @ h) if kind == "gyro" else fb @ h


def _t(s):
    return s.t - s.t[0]


def _tangent(h):
    """Two unit vectors orthogonal to the axis ``h``."""
    a = np.eye(3)[int(np.argmin(np.abs(h)))]
    e1 = np.cross(h, a)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(h, e1)


def _mount_masks(s):
    """Per mounting (distinct step ``mat_pb``, in order of first use), the sample mask."""
    mats, masks = [], []
    for st in s.steps:
        for k, m in enumerate(mats):
            if np.allclose(st.mat_pb, m):
                masks[k] |= s.step == st.index
                break
        else:
            mats.append(st.mat_pb)
            masks.append(s.step == st.index)
    return masks


# ---- library effects, from their physical definitions --------------------------------
# each: (preset, kind, 0-based sensor, library name, signal(s, truth) in SI)

def _g_sens(s, truth):                # bias 100 deg/h per g of specific force along the axis
    return 100.0 * DPH * (s.inputs()[2] @ truth.sets["gyro"].H[1]) / G0


def _asym(s, truth):                  # gain 1 + a/2 for positive, 1 - a/2 for negative input
    x = _along(s, truth, "gyro", 0)
    return np.where(x > 0, 0.001 * x, -0.001 * x)          # a = 0.002


def _nonlin(s, truth):                # output x + k2 x^2, k2 = 0.003 per (10 deg/s)
    x = _along(s, truth, "gyro", 2)
    return 0.003 / (10.0 * DPS) * x**2


def _warmup(s, truth):                # 30 deg/h decaying with the library's time constant
    return 30.0 * DPH * np.exp(-_t(s) / WARMUP_TAU_S)


def _drift(s, truth):                 # bias drifting linearly by 10 deg/h over the session
    t = _t(s)
    return 10.0 * DPH * t / t[-1]


def _no_earth(s, truth):              # the sensor's output lacks the Earth rate
    return -(s.inputs()[1] @ truth.sets["gyro"].H[3])


def _step(s, truth):                  # bias jumps by 3 deg/h at 55 % of the session
    t = _t(s)
    return 3.0 * DPH * (t >= 0.55 * t[-1])


def _line(s, truth):                  # 3 deg/h sinusoid at 0.0213 Hz
    return 3.0 * DPH * np.sin(2 * np.pi * 0.0213 * _t(s) + 0.4)


def _skew(s, truth):                  # the accelerometer samples its input 5 ms late
    x = _along(s, truth, "accel", 4)     # (within each step: the moves between steps are
    t = _t(s)                            # not recorded, so nothing is interpolated across)
    out = np.zeros_like(x)
    for st in s.steps:
        m = np.flatnonzero(s.step == st.index)
        if m.size < 2:
            continue
        tm, xm = t[m], x[m]
        late = np.interp(tm - 0.005, tm, xm)
        late[0] = xm[0] - 0.005 * (xm[1] - xm[0]) / (tm[1] - tm[0])   # first sample
        out[m] = late - xm
    return out


def _misalign(s, truth):              # axis of gyro 3 tilted by (3, -2) mrad in mounting 2
    h = truth.sets["gyro"].H[2]
    e1, e2 = _tangent(h)
    wt, we, _ = s.inputs()
    m = _mount_masks(s)[1]
    return ((wt + we) @ (3e-3 * e1 - 2e-3 * e2)) * m


def _with_temperature(s, truth, sensor, k_dph_per_degC, seed):
    """Temperature columns (warm-up plus a slow swing, °C) and a bias k·(T - mean T)."""
    rng = np.random.default_rng(seed)
    t = _t(s)
    T = 25 + 8 * (1 - np.exp(-t / 200)) + 2 * np.sin(2 * np.pi * 1.3 * t / t[-1]
                                                      + rng.uniform(0, 6))
    TT = T[:, None] + rng.normal(0, 0.5, s.raw_gyro.shape[1])[None, :]
    col = TT[:, sensor]
    s = add_signal(s, truth, sensor, k_dph_per_degC * DPH * (col - col.mean()))
    return dataclasses.replace(s, temperature_degC=TT)


LIBRARY = {
    "g_sensitivity": ("tetrad-paper", "gyro", 1, _g_sens),
    "scale_asymmetry": ("tetrad-paper", "gyro", 0, _asym),
    "scale_nonlinearity": ("tetrad-paper", "gyro", 2, _nonlin),
    "warmup": ("tetrad-paper", "gyro", 2, _warmup),
    "bias_drift": ("tetrad-paper", "gyro", 1, _drift),
    "no_earth_rate": ("tetrad-paper", "gyro", 3, _no_earth),
    "temperature": ("tetrad-paper", "gyro", 0, None),        # 1 deg/h per degC
    "bias_step": ("tetrad-paper", "gyro", 3, _step),
    "periodic_line": ("tetrad-paper", "gyro", 1, _line),
    "time_skew": ("cone-paper", "accel", 4, _skew),
    "misalignment": ("cone-paper", "gyro", 2, _misalign),
}


# ---- effects outside the library ------------------------------------------------------

def _am_line(s, truth):               # 0.0371 Hz line whose amplitude grows 1 -> 7 deg/h
    t = _t(s)
    return DPH * (1 + 6 * t / t[-1]) * np.sin(2 * np.pi * 0.0371 * t)


def _dead_zone(s, truth):             # accelerometer reads zero below 30 mg of input (the
    x = _along(s, truth, "accel", 0)    # positions that hold its axis near horizontal)
    return np.where(np.abs(x) < 0.03 * G0, -x, 0.0)


def _hysteresis(s, truth):            # +-4 deg/h offset that follows the sign of the last
    x = _along(s, truth, "gyro", 2)   # input beyond 1 deg/s (backlash on reversal)
    sign = np.where(np.abs(x) > 1.0 * DPS, np.sign(x), 0.0)
    idx = np.where(sign != 0, np.arange(sign.size), 0)
    last = sign[np.maximum.accumulate(idx)]
    return 4.0 * DPH * last


def _late_quadratic(s, truth):        # drift (t - t0)^2 from 40 % on, 12 deg/h at the end
    t = _t(s)
    t0 = 0.4 * t[-1]
    return 12.0 * DPH * (np.clip(t - t0, 0, None) / (t[-1] - t0)) ** 2


def _crosstalk(s, truth):             # gyro 4 picks up 2 % of gyro 2's input, rectified
    return 0.02 * np.abs(_along(s, truth, "gyro", 1))       # (a coupling via a detector)


OUTSIDE = {
    "am_line": ("tetrad-paper", "gyro", 0, _am_line),
    "dead_zone": ("cone-paper", "accel", 0, _dead_zone),
    "hysteresis": ("tetrad-paper", "gyro", 2, _hysteresis),
    "late_quadratic": ("tetrad-paper", "gyro", 3, _late_quadratic),
    "crosstalk": ("tetrad-paper", "gyro", 3, _crosstalk),
}


def _inject(spec, seed):
    preset, kind, sensor, fn = spec
    s, truth = clean_fast(preset, seed)
    if fn is None:                                           # temperature: column + bias
        return _with_temperature(s, truth, sensor, 1.0, seed), truth
    return add_signal(s, truth, sensor, fn(s, truth), kind=kind), truth


def _max_z(d, which):
    return max(abs(p["z"]) for p in d[which]["truth"]["parameters"] if p["kind"] != "site")


def _run(s, truth):
    """``rimu calibrate`` then ``rimu diagnose`` on its calibration."""
    with threadpool_limits(limits=1, user_api="blas"):
        cal = calibrate_checked(s, allan=False, earth_rate=False, detectability=False)
    d = diagnose(s, cal, truth=(truth, {}), detectability=False)
    return cal, d


def _adequacy_breaches(cal, d):
    """(what, max |z|) of every verdict of 'adequate' with the truth beyond 5 σ."""
    out = []
    if cal.adequacy["verdict"] != "effects suspected":
        z = _max_z({"e": d.error_before}, "e")               # the calibration itself
        if z > ADEQUATE_LIMIT:
            out.append(("calibrate", cal.adequacy["verdict"], round(z, 2)))
    if d.verdict != "effects suspected":
        z = _max_z({"e": d.error_after}, "e")                # the refit
        if z > ADEQUATE_LIMIT:
            out.append(("diagnose refit", d.verdict, round(z, 2)))
    return out


@pytest.mark.slow
@pytest.mark.campaign
@pytest.mark.parametrize("name", sorted(LIBRARY))
def test_library_effect_found_on_its_sensor(name):
    _preset, kind, sensor, _ = LIBRARY[name]
    missed, elsewhere, breaches = [], [], []
    for seed in SEEDS:
        s, truth = _inject(LIBRARY[name], seed)
        cal, d = _run(s, truth)
        claims = {(e["name"], e["kind"], e["sensors"][0]) for e in d.effects}
        if (name, kind, sensor + 1) not in claims:
            missed.append((seed, sorted(claims), [(u["kind"], u["sensor"], u["test"])
                                                 for u in d.unexplained_detail]))
        other = {c for c in claims if c[1:] != (kind, sensor + 1)}
        if other:
            elsewhere.append((seed, sorted(other)))
        breaches += [(seed, *b) for b in _adequacy_breaches(cal, d)]
    assert not missed, f"{name} not found on {kind} {sensor + 1}: {missed}"
    # claims on other sensors: family-wise level 0.01 per session; 3 of 10 has
    # probability 1e-4 under that level
    assert len(elsewhere) <= 2, elsewhere
    assert not breaches, breaches


@pytest.mark.slow
@pytest.mark.campaign
@pytest.mark.parametrize("name", sorted(OUTSIDE))
def test_outside_effect_unexplained_or_refused(name):
    _preset, kind, sensor, _ = OUTSIDE[name]
    wrong, breaches = [], []
    for seed in SEEDS:
        s, truth = _inject(OUTSIDE[name], seed)
        cal, d = _run(s, truth)
        on_sensor = any((u["kind"], u["sensor"]) == (kind, sensor + 1)
                        for u in d.unexplained_detail)
        refused = d.verdict == "effects suspected"          # the refit is not adequate
        if not (on_sensor or refused):
            wrong.append((seed, d.verdict, [(e["name"], e["kind"], e["sensors"][0])
                                            for e in d.effects],
                          [(u["kind"], u["sensor"], u["test"])
                           for u in d.unexplained_detail],
                          round(_max_z({"e": d.error_after}, "e"), 2)))
        breaches += [(seed, *b) for b in _adequacy_breaches(cal, d)]
    assert not breaches, breaches
    assert not wrong, wrong
