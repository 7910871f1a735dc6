"""replay.imu_set: a flight of several IMUs and its truth record."""

from __future__ import annotations

import numpy as np
import pytest

from fdi.errors import ConfigError
from replay.flight_io import load_flight_dir, save_flight_dir
from replay.imu_set import ImuEffects, ImuSetSpec, simulate_imu_set
from replay.motion import body_rates


def test_outputs_follow_the_truth_record_exactly_without_noise() -> None:
    spec = ImuSetSpec(imus=3, duration_s=20, seed=4, time_offset_s=(0.0, 0.004, -0.002),
                      noise_sd=0.0)
    f = simulate_imu_set(spec)
    assert f.imu == ("imu1",) * 3 + ("imu2",) * 3 + ("imu3",) * 3
    assert f.sensor_names[4] == "imu2.y"
    tr = f.truth["imus"]
    for j in (1, 2, 3):
        m = tr[f"imu{j}"]
        w = body_rates(f.t + m["time_offset_s"], seed=4, max_rate_dps=spec.max_rate_dps)
        want = w @ np.array(m["gain_matrix"]).T + np.array(m["bias"])
        np.testing.assert_allclose(f.raw[:, 3 * j - 3:3 * j], want, atol=1e-12)
    rel = f.truth["relative_to_reference"]["imu3"]
    G1, G3 = (np.array(tr[k]["gain_matrix"]) for k in ("imu1", "imu3"))
    np.testing.assert_allclose(np.array(rel["A"]), G3 @ np.linalg.inv(G1), atol=1e-12)
    assert rel["time_offset_s"] == pytest.approx(-0.002)


def test_accelerometers_feel_gravity_and_temperature_is_logged(tmp_path) -> None:
    eff = ImuEffects(temperature_coeff=1e-4, temperature_rise_c=10.0, temperature_tau_s=5.0)
    f = simulate_imu_set(ImuSetSpec(imus=2, duration_s=30, seed=1, linear_accel=0.0,
                                    accel_noise_sd=0.0, effects=eff))
    acc = f.aux.select("accel")
    assert acc.m == 6
    np.testing.assert_allclose(np.linalg.norm(acc.values[:, :3], axis=1), 9.80665, rtol=1e-9)
    temp = f.aux.select("temperature").values
    assert temp[-1, 0] - temp[0, 0] == pytest.approx(10.0, abs=0.3)
    save_flight_dir(f, tmp_path / "f")
    g = load_flight_dir(tmp_path / "f")
    assert g.imu == f.imu and g.aux.columns == f.aux.columns
    np.testing.assert_array_equal(g.raw, f.raw)
    assert g.truth["relative_to_reference"]["reference"] == "imu1"


def test_effects_only_on_the_chosen_imus() -> None:
    eff = ImuEffects(g_sensitivity=1e-3, vibration_hz=10.0, vibration=0.01, imus=(2,))
    f = simulate_imu_set(ImuSetSpec(imus=2, duration_s=5, effects=eff))
    assert not np.any(f.truth["imus"]["imu1"]["g_sensitivity"])
    assert np.any(f.truth["imus"]["imu2"]["g_sensitivity"])


@pytest.mark.parametrize("spec, word", [
    (ImuSetSpec(imus=1), "--imus"),
    (ImuSetSpec(imus=2, time_offset_s=(0.0,)), "time offsets"),
    (ImuSetSpec(imus=2, duration_s=-1), "duration_s"),
    (ImuSetSpec(imus=2, effects=ImuEffects(imus=(3,))), "effect IMUs")])
def test_bad_specs_are_named(spec: ImuSetSpec, word: str) -> None:
    with pytest.raises(ConfigError, match=word):
        simulate_imu_set(spec)
