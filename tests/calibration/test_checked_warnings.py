"""``calibrate --effects``: the whiteness warnings describe the model that was fitted.

The white-noise fit's warnings (step means scattering beyond white noise) are about the
model without the effects; once the effects are fitted jointly they are replaced, for the
sensors the refit changed, by the same check on the refit residual. A session with scale
nonlinearity and a temperature term on gyro 2: fitting both leaves no such warning on g2;
fitting the temperature term alone leaves the nonlinearity in the step means and the
recomputed warning names g2.
"""

import pytest

from calibration.calibrate_checked import calibrate_checked
from calibration.presets import preset
from calibration.simulate import simulate_session


def _session(seed):
    seq, truth, noise = preset("tetrad-paper")
    return simulate_session(None, seq, truth, seed=seed, noise=noise,
                            effects={"scale_nonlinearity": 3e-4, "temperature": 2.0},
                            effect_sensors=[2])


def _step_warnings(cal, name):
    return [w for w in cal.extra.get("warnings", [])
            if w.startswith(f"gyro {name}: ") and "white noise explains" in w]


@pytest.mark.parametrize("seed", (1, 2))
def test_whiteness_warnings_follow_the_refit(seed):
    s = _session(seed)
    kw = {"noise_model": "white", "allan": False, "earth_rate": False}
    both = calibrate_checked(s, effects=["scale_nonlinearity", "temperature"], **kw)
    g2 = both.gyro.sensors[1].name
    assert _step_warnings(both, g2) == [], both.extra.get("warnings")
    plain = calibrate_checked(s, **kw)
    assert _step_warnings(plain, g2), "premise: without the effects g2's step means scatter"
    part = calibrate_checked(s, effects=["temperature"], **kw)
    w = _step_warnings(part, g2)
    assert len(w) == 1 and "with the effect terms fitted" in w[0], part.extra.get("warnings")
