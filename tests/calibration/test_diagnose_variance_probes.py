"""The variance probes of the turntable diagnosis (calibration.diagnose.probes):
spikes at every step change (``transients``) and noise that grows over the session
(``noise_growth``), injected by hand into one sensor of a simulated session; neither
fires on the clean session."""

import numpy as np
from _diagnose_sessions import add_signal, calibrate_fast, clean_fast

from calibration.diagnose import diagnose
from fdi.units import DPH


def _spikes(s, truth, sensor, size_dph, seed=0):
    rng = np.random.default_rng(seed)
    step = np.asarray(s.step)
    edges = np.flatnonzero(np.diff(step)) + 1
    sig = np.zeros(step.shape[0])
    sig[edges] = size_dph * DPH * rng.choice([-1.0, 1.0], edges.size)   # one sample each
    return add_signal(s, truth, sensor, sig)


def _growth(s, truth, sensor, factor, seed=0):
    rng = np.random.default_rng(seed)
    sd = float(np.sqrt(truth.sets["gyro"].noise_covariance[sensor, sensor]))
    u = np.linspace(0.0, 1.0, s.raw_gyro.shape[0])
    return add_signal(s, truth, sensor, rng.normal(0, 1, u.size) * sd * factor * u)


def _probes(d):
    return {(u["test"], u["sensor"]) for u in d.unexplained_detail}


def test_spikes_at_every_step_change_are_unexplained_on_that_sensor():
    s, truth = clean_fast("tetrad-paper", 3)
    sd = float(np.sqrt(truth.sets["gyro"].noise_covariance[2, 2])) / DPH
    d = diagnose(*(lambda x: (x, calibrate_fast(x)))(_spikes(s, truth, 2, 8 * sd)))
    got = _probes(d)
    assert ("transients", 3) in got, d.unexplained_detail
    assert all(sensor == 3 for _, sensor in got)


def test_noise_that_grows_is_unexplained_on_that_sensor():
    s, truth = clean_fast("tetrad-paper", 4)
    x = _growth(s, truth, 1, 2.0)
    d = diagnose(x, calibrate_fast(x))
    got = _probes(d)
    assert ("noise_growth", 2) in got, d.unexplained_detail
    assert all(sensor == 2 for _, sensor in got)


def test_clean_session_passes_the_variance_probes():
    hits = 0
    for seed in range(3):
        s, _ = clean_fast("tetrad-paper", 20 + seed)
        d = diagnose(s, calibrate_fast(s))
        hits += any(u["test"] in ("transients", "noise_growth") for u in d.unexplained_detail)
    assert hits == 0
