"""``compare`` with a temperature term: the calibration states its bias at the term's
reference temperature (the session mean), the simulator's truth at T₀ = 20 °C, so the true
bias to compare is b₀ + k·(T_ref − T₀) (:func:`calibration.compare.true_bias`).

Over seeds, with the temperature term fitted (``calibrate_checked(effects=[...])``): the
bias of the sensor with the knob is within 3σ of that true bias, and the premise is checked
too: against b₀ as it stands it would be off by far more than 3σ.
"""

import numpy as np
import pytest

from calibration.calibrate_checked import calibrate_checked
from calibration.compare import compare
from calibration.presets import preset
from calibration.simulate import simulate_session, truth_of_session

SEEDS = (1, 2, 3)
K_DPH_PER_DEGC = 2.0


@pytest.mark.parametrize("seed", SEEDS)
def test_bias_compared_at_the_temperature_reference(seed):
    seq, truth, noise = preset("tetrad-paper")
    s = simulate_session(None, seq, truth, seed=seed, noise=noise,
                         effects={"temperature": K_DPH_PER_DEGC}, effect_sensors=[2])
    t_cal, effects, sensors, _ = truth_of_session(s, truth)
    cal = calibrate_checked(s, effects=["temperature"], noise_model="white", allan=False,
                            earth_rate=False)
    term = next(t for t in cal.effects if t.name == "temperature" and t.sensor == 1)
    assert abs(term.estimate - K_DPH_PER_DEGC) < 3 * term.estimate_sd, term
    row = next(r for r in compare(cal, t_cal, effects, sensors)
               if r.sensor == cal.gyro.sensors[1].name and r.parameter == "bias")
    assert abs(row.z) < 3, f"gyro 2 bias error/sd {row.z:+.2f} at the reference temperature"
    naive = next(r for r in compare(cal, t_cal, effects)                 # no sensors: b0
                 if r.sensor == row.sensor and r.parameter == "bias")
    assert abs(naive.z) > 5, f"premise: against b0 the bias is off by {naive.z:+.2f} sd"
    others = [r for r in compare(cal, t_cal, effects, sensors)
              if r.parameter == "bias" and r.sensor != row.sensor and r.kind == "gyro"]
    assert np.all([abs(r.z) < 4.5 for r in others]), [(r.sensor, r.z) for r in others]
