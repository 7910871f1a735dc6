"""A moved sample's envelope code covers the later samples it is made from
(replay.envelope_lead): an impact flagged at sample m is out of the envelope from the first
moved sample that draws on it, in a stream fed in pieces as in the whole flight."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from replay.envelope_lead import LeadHold, dilate_back
from replay.imu_set import ImuSetSpec, simulate_imu_set


def test_dilate_back_is_the_union_over_the_next_lead_samples():
    c = np.array([0, 0, 0, 1, 0, 0, 4, 0, 0, 0])
    np.testing.assert_array_equal(dilate_back(c, 0), c)
    np.testing.assert_array_equal(dilate_back(c, 1), [0, 0, 1, 1, 0, 4, 4, 0, 0, 0])
    np.testing.assert_array_equal(dilate_back(c, 2), [0, 1, 1, 1, 4, 4, 4, 0, 0, 0])
    np.testing.assert_array_equal(dilate_back(c, 50), [5, 5, 5, 5, 4, 4, 4, 0, 0, 0])
    assert dilate_back(np.zeros(0, int), 3).shape == (0,)


def _pieces(f, sizes):
    out, k, j = [], 0, 0
    while k < f.t.shape[0]:
        rows = slice(k, min(f.t.shape[0], k + sizes[j % len(sizes)]))
        out.append(replace(f, t=f.t[rows], raw=f.raw[rows], valid=f.valid[rows],
                           omega_true=None if f.omega_true is None else f.omega_true[rows],
                           aux=None if f.aux is None else f.aux.slice(rows)))
        k, j = rows.stop, j + 1
    return out


@pytest.mark.parametrize("lead", [0, 1, 3])
@pytest.mark.parametrize("sizes", [(1,), (2, 5, 1), (400,)])
def test_pieces_get_the_whole_flights_codes(lead, sizes):
    f = simulate_imu_set(ImuSetSpec(imus=2, duration_s=4, seed=2))
    rng = np.random.default_rng(7)
    codes = np.where(rng.random(f.t.shape[0]) < 0.05, rng.integers(1, 32, f.t.shape[0]), 0)
    hold, got_t, got_c, k = LeadHold(lead), [], [], 0
    for p in _pieces(f, sizes):
        out, c = hold.push(p, codes[k:k + p.t.shape[0]])
        k += p.t.shape[0]
        if out is not None:
            got_t.append(out.t)
            got_c.append(c)
        assert hold.holding == (lead > 0)
    out, c = hold.release()
    if out is not None:
        got_t.append(out.t)
        got_c.append(c)
    np.testing.assert_array_equal(np.concatenate(got_t), f.t)
    np.testing.assert_array_equal(np.concatenate(got_c), dilate_back(codes, lead),
                                  err_msg=f"lead {lead}, sizes {sizes}")


def _shocked(tau_s):
    """Two IMUs at 50 Hz, IMU2 ``tau_s`` late, an impact at sample 600 (6 g on every
    accelerometer, the gyros kicked by 150 deg/s for one sample); the calibration of the
    clean flight with its offset."""
    from calibration.inflight import calibration_from_fit, fit_inflight

    f = simulate_imu_set(ImuSetSpec(imus=2, duration_s=20, seed=1, time_offset_s=(0.0, tau_s)))
    cal = calibration_from_fit(fit_inflight(f), f)
    m = 600
    raw, aux = f.raw.copy(), f.aux.values.copy()
    acc = [i for i, k in enumerate(f.aux.kinds) if k == "accel"]
    assert len(acc) == 6
    aux[m, acc] = 6 * 9.80665
    raw[m, :] += np.radians(150.0) / np.asarray([s.scale_factor for s in cal.gyro.sensors])
    return replace(f, raw=raw, aux=replace(f.aux, values=aux)), cal, m


def test_an_impact_is_out_of_the_envelope_from_the_first_moved_sample_it_reaches():
    from replay.chain import ChainOptions, chain_for_flight

    f, cal, m = _shocked(-0.010)                   # IMU2 drawn from 10 ms ahead: one sample
    ch = chain_for_flight(f, cal, ChainOptions(report=False))
    assert ch._hold is not None and ch._hold.lead == 1
    whole = ch.feed_whole(f)
    env = np.asarray(whole.envelope)
    assert env[m] != 0 and env[m - 1] != 0, env[m - 3:m + 3]
    assert env[m - 3] == 0                         # not more than it reaches
    ch2 = chain_for_flight(f, cal, ChainOptions(report=False))
    parts = [ch2.feed(p) for p in _pieces(f, (7, 1, 64))] + [ch2.finish()]
    parts = [p for p in parts if p is not None]
    np.testing.assert_array_equal(np.concatenate([p.envelope for p in parts]), env)
    np.testing.assert_array_equal(np.concatenate([p.statistics for p in parts]),
                                  whole.statistics)


def test_nothing_moved_ahead_holds_nothing():
    from replay.chain import ChainOptions, chain_for_flight

    f, cal, _ = _shocked(+0.010)                   # IMU2 drawn from the past: no lead
    ch = chain_for_flight(f, cal, ChainOptions(report=False))
    assert ch._hold is None
