"""Corrupt samples that are still finite numbers: a one-line CalibrationError, not a crash.

Found by fuzzing: a single -1e300 sample gave a zero scale factor (ZeroDivisionError when
saving) and a rank-deficient H̃ (broadcast error in the parity sd).
"""

import dataclasses

import numpy as np
import pytest

from calibration.calibrate import calibrate
from fdi.errors import CalibrationError


def _with_raw(session, raw):
    return dataclasses.replace(session, raw_gyro=raw, source="corrupt-session")


@pytest.mark.parametrize("value", [1e300, -1e300])
def test_one_huge_sample_names_the_sensor(tetrad_session, value):
    raw = tetrad_session.raw_gyro.copy()
    raw[1234, 2] = value
    with pytest.raises(CalibrationError, match=r"corrupt-session: gyro sensor 3 \(g3\)"):
        calibrate(_with_raw(tetrad_session, raw))


def test_stuck_sensor_names_the_sensor(tetrad_session):
    raw = tetrad_session.raw_gyro.copy()
    raw[:, 3] = 5.0
    with pytest.raises(CalibrationError, match=r"gyro sensor 4 \(g4\).*stuck or corrupt"):
        calibrate(_with_raw(tetrad_session, raw))


def test_healthy_session_still_calibrates(tetrad_session):
    cal = calibrate(tetrad_session)
    assert np.all(cal.gyro.scale_factors > 0)
