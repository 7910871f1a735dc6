"""Earth rate from the outer-axis modulation (seed 000 Fig. 3 and Results)."""

import numpy as np
import pytest
from _sessions import session, shift_outer, with_changes

from calibration.calibrate import calibrate
from fdi.units import EARTH_RATE_DPH


@pytest.mark.parametrize("denoise", [True, False])
def test_noise_free_recovers_earth_rate(denoise):
    s, _ = session("tetrad-paper", white=False)
    cal = calibrate(s, denoise=denoise, allan=False)
    assert cal.earth_rate_dph == pytest.approx(EARTH_RATE_DPH, abs=1e-6), "Earth rate"
    fit = cal.extra["earth_rate_fit"]
    assert fit["steps"] == list(range(5, 17)), "outer-axis steps of seed 000 Table 1"
    assert abs(fit["heading_offset_deg"]) < 1e-5, "table zero points North"


def test_heading_offset_of_the_table_zero_is_fitted():
    s, _ = session("tetrad-paper", white=False)
    s2 = shift_outer(s, np.deg2rad(-7.0))        # recorded angles 7 deg behind the truth
    cal = calibrate(s2, allan=False)
    fit = cal.extra["earth_rate_fit"]
    assert cal.earth_rate_dph == pytest.approx(EARTH_RATE_DPH, abs=1e-6), "Earth rate"
    assert abs(abs(fit["heading_offset_deg"]) - 7.0) < 1e-4, "heading offset"


def test_noisy_tetrad_paper_within_three_sigma():
    s, _ = session("tetrad-paper", seed=11)
    cal = calibrate(s, allan=False)
    z = (cal.earth_rate_dph - EARTH_RATE_DPH) / cal.earth_rate_dph_sd
    assert abs(z) < 3, f"Earth rate {cal.earth_rate_dph} ± {cal.earth_rate_dph_sd}"
    fit = cal.extra["earth_rate_fit"]
    # the independent per-step scatter agrees with the propagated sd (loose: 12 steps)
    assert 0.5 < fit["scatter_sd_dph"] / cal.earth_rate_dph_sd < 2.0
    assert 0.05 < cal.earth_rate_dph_sd < 0.5, "sd of the order of the simulated noise"


def test_no_earth_rate_gives_zero_within_sigma():
    s, _ = session("tetrad-paper", seed=3, effects={"no_earth_rate": 1})
    cal = calibrate(s, allan=False)
    # |(A, B)| is a magnitude: with no signal it is Rayleigh-distributed around ~1.25 sigma
    assert cal.earth_rate_dph < 4 * cal.earth_rate_dph_sd


def test_inner_axis_steps_only_are_rank_deficient():
    s, _ = session("tetrad-paper", white=False)
    keep = s.step <= 4
    s2 = with_changes(s, t=s.t[keep], step=s.step[keep], inner=s.inner[keep],
                      outer=s.outer[keep], inner_rate=s.inner_rate[keep],
                      outer_rate=s.outer_rate[keep], raw_gyro=s.raw_gyro[keep],
                      steps=s.steps[:4])
    from fdi.errors import CalibrationError
    with pytest.raises(CalibrationError, match="rank of R"):
        calibrate(s2)
