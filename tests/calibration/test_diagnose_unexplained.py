"""Effects outside the library: "unexplained": true, where it sits, and no library effect
claimed (the best of a bad lot is not picked).

Four kinds the library has no regressor for, each added to one gyro of tetrad-paper at a
size well above the per-step noise (per-step mean sd ≈ 0.6 deg/h): a fixed pseudo-random
bias per step, a Gaussian bump in time (20 s wide), a square wave (period 37 s: a line plus
its harmonics), and a bias proportional to the table's outer angle (a wobble that follows
the table, not time).
"""

import numpy as np
import pytest
from _diagnose_sessions import add_signal, calibrate_fast, session

from calibration.diagnose import diagnose
from fdi.units import DPH


def _per_step(s):
    rng = np.random.default_rng(7)
    level = {k: rng.choice([-1.0, 1.0]) * rng.uniform(4, 8) for k in np.unique(s.step)}
    return np.array([level[k] for k in s.step])


def _bump(s):
    t = s.t - s.t[0]
    return 15.0 * np.exp(-0.5 * ((t - 0.37 * t[-1]) / 20.0) ** 2)


def _square(s):
    t = s.t - s.t[0]
    return 6.0 * np.sign(np.sin(2 * np.pi * t / 37.0))


def _outer_angle(s):
    return 10.0 * np.cos(2 * s.outer) * (np.abs(s.outer_rate) > 0)


OUTSIDE = {"per_step": _per_step, "bump": _bump, "square_wave": _square,
           "outer_angle": _outer_angle}


@pytest.mark.parametrize("kind", [k if k in ("per_step", "square_wave") else
                                  pytest.param(k, marks=pytest.mark.slow)
                                  for k in sorted(OUTSIDE)])
def test_effect_outside_library_is_unexplained(kind):
    s, truth = session("tetrad-paper", 4)
    s = add_signal(s, truth, 1, OUTSIDE[kind](s) * DPH)
    d = diagnose(s, calibrate_fast(s))
    assert d.unexplained, d.effects
    assert d.effects == [], d.effects
    where = {(u["kind"], u["sensor"]) for u in d.unexplained_detail}
    assert where == {("gyro", 2)}, d.unexplained_detail
    doc = d.to_json()
    assert doc["unexplained"] is True and doc["unexplained_detail"]
    assert any(u.get("steps") or u.get("band_hz") or u.get("time_s") is not None
               for u in doc["unexplained_detail"])
