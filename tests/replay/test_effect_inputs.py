"""The effect terms' run-time inputs from a flight's aux channels (replay.effect_inputs)."""

import numpy as np

from replay.effect_inputs import flight_effect_inputs
from replay.flight_data import AuxChannels, Flight


def _flight(aux, imu=()):
    N = 5
    names = tuple(f"imu{1 + i // 3}.{'xyz'[i % 3]}" for i in range(6)) if imu else \
        tuple(f"g{i}" for i in range(6))
    return Flight(t=np.arange(N) / 100.0, raw=np.zeros((N, 6)), valid=np.ones((N, 6), bool),
                  sample_rate_hz=100.0, sensor_names=names, imu=imu, aux=aux)


def test_each_imu_reads_its_own_triad_and_temperature():
    N = 5
    rng = np.random.default_rng(1)
    vals = rng.normal(size=(N, 7))
    valid = np.ones((N, 7), bool)
    valid[2, 1] = False                                  # imu1.y missing at sample 2
    aux = AuxChannels(("accel",) * 6 + ("temperature",),
                      ("imu1.x", "imu1.y", "imu1.z", "imu2.x", "imu2.y", "imu2.z", "imu2"),
                      ("imu1",) * 3 + ("imu2",) * 4, vals, valid)
    f, T, avail = flight_effect_inputs(_flight(aux, imu=("imu1",) * 3 + ("imu2",) * 3))
    assert avail == {"specific_force": [0, 1, 2, 3, 4, 5], "temperature": [3, 4, 5]}
    np.testing.assert_array_equal(f[:, 3], vals[:, 3:6])
    np.testing.assert_array_equal(f[[0, 1, 3, 4], 0], vals[[0, 1, 3, 4], 0:3])
    assert np.isnan(f[2, 0, 1]) and f[2, 0, 0] == vals[2, 0]
    assert np.all(np.isnan(T[:, :3])) and np.all(T[:, 4] == vals[:, 6])


def test_ungrouped_sensors_use_the_mean_of_the_triads_and_the_only_temperature():
    N = 5
    vals = np.column_stack([np.full((N, 3), 1.0), np.full((N, 3), 3.0), np.full(N, 40.0)])
    valid = np.ones((N, 7), bool)
    valid[0, 3:6] = False                                # second triad missing at sample 0
    aux = AuxChannels(("accel",) * 6 + ("temperature",),
                      ("a.x", "a.y", "a.z", "b.x", "b.y", "b.z", "board"), ("",) * 7, vals,
                      valid)
    f, T, avail = flight_effect_inputs(_flight(aux))
    assert f.shape == (N, 6, 3) and np.all(f[1:] == 2.0) and np.all(f[0] == 1.0)
    assert avail["temperature"] == list(range(6)) and np.all(T == 40.0)


def test_no_aux_no_inputs():
    f, T, avail = flight_effect_inputs(_flight(None))
    assert f is None and T is None and avail == {"specific_force": [], "temperature": []}
