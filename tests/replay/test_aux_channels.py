"""Auxiliary channels of a channel map: loader round trip and errors, decoding beside the
monitored sensors, and the sample-and-hold onto the samples' times."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from can import Message
from hypothesis import given, settings
from hypothesis import strategies as st

from fdi.errors import ConfigError, FileFormatError
from replay.accounting import FrameAccounting
from replay.assemble import BlockDecoder, Samples, decode_frames
from replay.channel_map import (
    AUX_TIMEOUT_S,
    EXAMPLE_J1939_AUX_MAP,
    AuxChannel,
    aux_assignment,
    channel_map_toml,
    default_channel_map,
    load_channel_map,
    write_channel_map,
)
from replay.effect_inputs import map_available, map_effect_inputs
from replay.frames import encode_imu_frames, load_dbc
from replay.raw_frames import RawFrames

# -- loader -------------------------------------------------------------------------------

_FIELDS = ("name", "quantity", "message", "signals", "unit", "sensors", "timeout_s",
           "source_address", "channel", "counter_signal", "crc_signal", "status_signal")


def _same_aux(a: AuxChannel, b: AuxChannel) -> None:
    for f in _FIELDS:
        assert getattr(a, f) == getattr(b, f), f
    if a.axes is None:
        assert b.axes is None
    else:
        np.testing.assert_allclose(a.axes, b.axes)


def test_example_aux_map_loads_and_round_trips(tmp_path):
    cmap = load_channel_map(EXAMPLE_J1939_AUX_MAP)
    assert cmap.n == 9 and len(cmap.auxiliary) == 6
    acc, temp = cmap.auxiliary[2], cmap.auxiliary[3]
    assert (acc.quantity, acc.source_address, acc.unit) == ("specific_force", 0x81, "m/s^2")
    assert acc.sensors == ("imu2_pitch", "imu2_roll", "imu2_yaw") and len(acc.signals) == 3
    assert (temp.quantity, temp.message, temp.timeout_s) == ("temperature", "IMUT", 5.0)
    asg = aux_assignment(cmap)
    assert asg["specific_force"] == [(0,)] * 3 + [(2,)] * 3 + [(4,)] * 3
    assert asg["temperature"] == [(1,)] * 3 + [(3,)] * 3 + [(5,)] * 3
    assert map_available(cmap) == {"specific_force": list(range(9)),
                                   "temperature": list(range(9))}
    p = tmp_path / "m.toml"
    write_channel_map(cmap, p)
    back = load_channel_map(p)
    assert back.dbc.resolve() == cmap.dbc.resolve() and back.j1939
    assert [s.name for s in back.sensors] == [s.name for s in cmap.sensors]
    for a, b in zip(cmap.auxiliary, back.auxiliary, strict=True):
        _same_aux(a, b)
    assert channel_map_toml(back) == channel_map_toml(cmap)


def test_default_map_with_aux_round_trips_and_old_maps_stay_valid(tmp_path):
    aux = (AuxChannel("t1", "temperature", "RIMU_TEMP_01", ("RAW",), "K",
                      sensors=("g2", "g3"), timeout_s=0.5),
           AuxChannel("fx", "specific_force", "RIMU_ACCEL_01", ("RAW",), "g",
                      axes=np.array([[0.0, 0.0, -1.0]])),
           AuxChannel("fyz", "specific_force", "RIMU_ACCEL_02", ("RAW",), "m/s^2",
                      axes=np.array([[1.0, 0.0, 0.0]])),
           AuxChannel("f3", "specific_force", "RIMU_ACCEL_03", ("RAW",), "m/s^2",
                      axes=np.array([[0.0, 1.0, 0.0]])))
    cmap = default_channel_map(4, names=("g1", "g2", "g3", "g4"), auxiliary=aux)
    p = tmp_path / "m.toml"
    write_channel_map(cmap, p)
    back = load_channel_map(p)
    for a, b in zip(aux, back.auxiliary, strict=True):
        _same_aux(a, b)
    assert back.auxiliary[0].to_si == (1.0, -273.15)
    assert map_available(back) == {"specific_force": [0, 1, 2, 3], "temperature": [1, 2]}
    # a map without [[auxiliary]] (every /1 map written before) reads as before
    plain = default_channel_map(4, names=("g1", "g2", "g3", "g4"))
    write_channel_map(plain, p)
    assert load_channel_map(p).auxiliary == ()
    assert "[[auxiliary]]" not in p.read_text()


_HEAD = """schema = "rimu.channel_map/1"
kind = "gyro"
j1939 = {j1939}

[[sensors]]
name = "a"
message = "RIMU_GYRO_01"
signal = "RAW"
source_address = 1

[[sensors]]
name = "b"
message = "RIMU_GYRO_02"
signal = "RAW"
source_address = 2
"""

_T = '[[auxiliary]]\nquantity = "temperature"\nmessage = "RIMU_TEMP_01"\nsignal = "RAW"\n'
_F = ('[[auxiliary]]\nquantity = "specific_force"\nmessage = "RIMU_ACCEL_01"\n'
      'signals = ["RAW"]\nunit = "m/s^2"\naxes = [[1, 0, 0]]\n')


@pytest.mark.parametrize("aux, field, expect", [
    ('[[auxiliary]]\nquantity = "pressure"\nmessage = "M"\nsignal = "S"\nunit = "Pa"\n',
     "auxiliary[1].quantity", "expected one of 'temperature', 'specific_force'"),
    (_T + 'unit = "degF"\n', "auxiliary[1].unit", "expected one of 'degC', 'K'"),
    (_T, "auxiliary[1].unit", "missing"),
    (_T + 'unit = "degC"\nsensors = ["a", "c"]\n', "auxiliary[1].sensors",
     "unknown sensor 'c'; the map's sensors are a, b"),
    (_T + 'unit = "degC"\nsensors = "some"\n', "auxiliary[1].sensors", "expected \"all\""),
    (_T + 'unit = "degC"\ntimeout_s = -1\n', "auxiliary[1].timeout_s",
     "expected a positive number"),
    (_T + 'unit = "degC"\ntimout_s = 2\n', "auxiliary[1].timout_s", "did you mean 'timeout_s'"),
    (_T + 'unit = "degC"\naxis_nominal = [1, 0, 0]\n', "auxiliary[1].axis_nominal",
     "unknown key"),
    (_T + 'unit = "degC"\n' + _T + 'unit = "K"\n', "auxiliary",
     "sensor a has two temperatures (temperature1 and temperature2)"),
    (_T + 'unit = "degC"\nname = "x"\n' + _T + 'unit = "K"\nname = "x"\nsensors = ["a"]\n',
     "auxiliary[2].name", "auxiliary name 'x' used twice"),
    ('[[auxiliary]]\nquantity = "specific_force"\nmessage = "RIMU_ACCEL_01"\nsignal = "RAW"\n'
     'unit = "m/s^2"\n', "auxiliary[1].axis_nominal", "needs the body axis it measures"),
    ('[[auxiliary]]\nquantity = "specific_force"\nmessage = "RIMU_ACCEL_01"\nsignal = "RAW"\n'
     'unit = "m/s^2"\naxis_nominal = [0, 0, 0]\n', "auxiliary[1].axis_nominal", "not all zero"),
    ('[[auxiliary]]\nquantity = "specific_force"\nmessage = "M"\nsignals = ["X", "Y"]\n'
     'unit = "g"\n', "auxiliary[1].axes", "2 signals: give their body axes"),
    ('[[auxiliary]]\nquantity = "specific_force"\nmessage = "M"\nsignals = ["X", "Y", "Z", "W"]\n'
     'unit = "g"\n', "auxiliary[1].signals", "expected a list of 1 to 3 signal names"),
    ('[[auxiliary]]\nquantity = "specific_force"\nmessage = "M"\nsignal = "X"\n'
     'signals = ["X"]\nunit = "g"\n', "auxiliary[1].signal", "not both"),
    (_F, "auxiliary", "the specific-force axes of sensor a (specific_force1) span 1 "
     "dimension(s); expected 3"),
    (_F.replace("axes = [[1, 0, 0]]", "axes = [[1, 0, 0], [0, 1, 0]]"), "auxiliary[1].axes",
     "expected shape 1×3, got 2×3"),
])
def test_bad_aux_entries_are_named(tmp_path, aux, field, expect):
    p = tmp_path / "bad.toml"
    p.write_text(_HEAD.format(j1939="false") + "\n" + aux, encoding="utf-8")
    with pytest.raises(FileFormatError) as ei:
        load_channel_map(p)
    msg = str(ei.value)
    assert str(p) in msg and field in msg and expect in msg, msg
    assert "\n" not in msg


def test_j1939_aux_needs_its_source_address(tmp_path):
    p = tmp_path / "bad.toml"
    p.write_text(_HEAD.format(j1939="true") + "\n" + _T + 'unit = "degC"\n', encoding="utf-8")
    with pytest.raises(FileFormatError, match=r"auxiliary\[1\]\.source_address.*source "
                                              "address"):
        load_channel_map(p)


def test_aux_message_not_in_dbc_or_shared_with_a_sensor_is_refused():
    db = load_dbc()
    bad = default_channel_map(2, auxiliary=(AuxChannel("t", "temperature", "NOPE", ("RAW",),
                                                       "degC"),))
    with pytest.raises(ConfigError, match="auxiliary 1 \\(t\\): message 'NOPE' is not in"):
        BlockDecoder(db, bad, sample_rate_hz=100.0)
    shared = default_channel_map(2, auxiliary=(AuxChannel(
        "t", "temperature", "RIMU_GYRO_02", ("RAW",), "degC"),))
    with pytest.raises(ConfigError, match="also carries monitored sensors"):
        BlockDecoder(db, shared, sample_rate_hz=100.0)


# -- decoding and sample-and-hold ---------------------------------------------------------
FS = 100.0
N = 120
T0 = 1.7e9


def _frames(rng, *, temp_times, temp_values, acc_times, acc_values):
    """Four gyro sensors of the shipped DBC every 10 ms (sample k at T0 + k/FS + i·0.2 ms;
    sample 40 of sensor 3 and sample 60 of every sensor lost), temperature frames
    (RIMU_TEMP_01, degC) and three accelerometer axes (RIMU_ACCEL_01..03, m/s², one frame
    per axis) at the given times."""
    db = load_dbc()
    msgs = []
    for i in range(4):
        m = db.get_message_by_name(f"RIMU_GYRO_{i + 1:02d}")
        k = np.array([k for k in range(N) if not (i == 2 and k == 40) and k != 60])
        for kk, data in zip(k, encode_imu_frames(m, rng.normal(0, 1, k.size), k,
                                                 np.arange(k.size)), strict=True):
            msgs.append(Message(timestamp=T0 + kk / FS + i * 2e-4, arbitration_id=m.frame_id,
                                is_extended_id=False, data=data, channel=0))
    m = db.get_message_by_name("RIMU_TEMP_01")
    for j, (t, d) in enumerate(zip(temp_times, encode_imu_frames(
            m, temp_values, np.zeros(len(temp_times), int), np.arange(len(temp_times))),
            strict=True)):
        msgs.append(Message(timestamp=T0 + t, arbitration_id=m.frame_id, is_extended_id=False,
                            data=d, channel=0))
        del j
    for ax in range(3):
        m = db.get_message_by_name(f"RIMU_ACCEL_{ax + 1:02d}")
        for t, d in zip(acc_times, encode_imu_frames(
                m, acc_values[:, ax], np.zeros(len(acc_times), int),
                np.arange(len(acc_times))), strict=True):
            msgs.append(Message(timestamp=T0 + t + ax * 1e-5, arbitration_id=m.frame_id,
                                is_extended_id=False, data=d, channel=0))
    msgs.sort(key=lambda m: m.timestamp)
    return RawFrames.from_messages(msgs)


def _aux_map(timeout_temp=0.25):
    checks = {"counter_signal": "COUNTER", "crc_signal": "CRC", "status_signal": "STATUS"}
    temp = AuxChannel("board", "temperature", "RIMU_TEMP_01", ("RAW",), "degC",
                      sensors=("g1", "g2"), timeout_s=timeout_temp, **checks)
    acc = [AuxChannel(f"acc{ax}", "specific_force", f"RIMU_ACCEL_{ax + 1:02d}", ("RAW",),
                      "m/s^2", axes=np.eye(3)[[ax]], timeout_s=0.05, **checks)
           for ax in range(3)]
    aux = (temp, *acc)
    return default_channel_map(4, names=("g1", "g2", "g3", "g4"), auxiliary=aux)


def _held(times, values, ts, timeout):
    """The expected hold, by brute force: the latest value at or before each time."""
    out = np.full(ts.size, np.nan)
    for k, t in enumerate(ts):
        before = [j for j, tj in enumerate(times) if tj <= t]
        if before and t - times[before[-1]] <= timeout:
            out[k] = values[before[-1]]
    return out


@pytest.fixture(scope="module")
def scene():
    rng = np.random.default_rng(3)
    temp_t = np.array([0.205, 0.305, 0.405, 0.505, 0.605])       # then silent
    temp_v = np.array([20.0, 21.0, 22.0, 23.5, 24.0])
    acc_t = np.concatenate([np.arange(0, 0.5, 0.01), np.arange(0.8, N / FS, 0.01)]) + 0.0013
    acc_v = rng.normal(0, 3, (acc_t.size, 3)) + np.array([0.0, 0.0, -9.8])
    fr = _frames(rng, temp_times=temp_t, temp_values=temp_v, acc_times=acc_t, acc_values=acc_v)
    return fr, temp_t, temp_v, acc_t, acc_v


def test_aux_values_are_held_onto_the_samples(scene):
    fr, temp_t, temp_v, acc_t, acc_v = scene
    cmap = _aux_map()
    acct = FrameAccounting()
    s = decode_frames(fr, load_dbc(), cmap, acct, sample_rate_hz=FS)
    assert s.t.size == N - 1 and s.aux.shape == (N - 1, 4)
    ts = s.t - T0
    exp_T = _held(temp_t, temp_v, ts, 0.25)
    np.testing.assert_array_equal(np.isnan(s.aux[:, 0]), np.isnan(exp_T))
    np.testing.assert_allclose(s.aux[:, 0], exp_T, atol=1e-5)      # float32 on the bus
    assert np.isnan(s.aux[ts < 0.205, 0]).all()                     # before the first
    assert np.isnan(s.aux[ts > 0.605 + 0.25 + 1e-9, 0]).all()       # stale after the timeout
    assert np.isfinite(s.aux[(ts >= 0.21) & (ts <= 0.85), 0]).all()
    for ax in range(3):
        exp = _held(acc_t + ax * 1e-5, acc_v[:, ax], ts, 0.05)
        np.testing.assert_allclose(s.aux[:, 1 + ax], exp, atol=1e-5)
    gap = (ts > 0.49 + 0.05 + 0.0014) & (ts < 0.8013)                # accelerometers silent
    assert gap.sum() > 20 and np.isnan(s.aux[gap, 1:]).all()
    # the inputs per sensor: temperature for g1, g2 only; specific force for all
    force, temp = map_effect_inputs(cmap, s.aux)
    np.testing.assert_array_equal(temp[:, 0], s.aux[:, 0])
    assert np.isnan(temp[:, 2:]).all()
    np.testing.assert_allclose(force[:, 3], s.aux[:, 1:4])
    # every frame used or rejected; the auxiliary frames are used
    assert acct.balanced() and acct.n_rejected == 0
    assert acct.used == fr.t.size


def test_aux_never_changes_the_samples_or_their_loss_accounting(scene):
    fr = scene[0]
    db = load_dbc()
    with_aux, plain = FrameAccounting(), FrameAccounting()
    s1 = decode_frames(fr, db, _aux_map(), with_aux, sample_rate_hz=FS)
    s0 = decode_frames(fr, db, dataclasses.replace(_aux_map(), auxiliary=()), plain,
                       sample_rate_hz=FS)
    np.testing.assert_array_equal(s1.t, s0.t)
    np.testing.assert_array_equal(s1.raw, s0.raw)
    np.testing.assert_array_equal(s1.valid, s0.valid)
    assert s0.aux is None and not s1.valid[40, 2]
    assert with_aux.lost_samples == plain.lost_samples == 1          # sample 60
    assert with_aux.lost_frames == plain.lost_frames
    n_aux = with_aux.used - plain.used
    assert plain.rejected["unknown_id"] == n_aux > 0


@pytest.mark.parametrize("chunk", [1, 37, 500])
def test_hold_is_the_same_whatever_the_block_split(scene, chunk):
    fr = scene[0]
    db = load_dbc()
    whole = decode_frames(fr, db, _aux_map(), FrameAccounting(), sample_rate_hz=FS)
    dec = BlockDecoder(db, _aux_map(), sample_rate_hz=FS)
    parts = []
    for a in range(0, len(fr), chunk):
        idx = np.arange(a, min(a + chunk, len(fr)))
        sub = RawFrames(fr.t[idx], fr.arbitration_id[idx], fr.extended[idx], fr.channel[idx],
                        np.concatenate([fr.block(np.array([i]), int(fr.lengths[i])).ravel()
                                        for i in idx]), fr.lengths[idx], fr.frame_type[idx])
        parts.append(dec.feed(sub))
    parts.append(dec.flush())
    got = Samples.concat(parts, 4)
    np.testing.assert_array_equal(got.t, whole.t)
    np.testing.assert_array_equal(got.aux, whole.aux)
    assert dec.acct.balanced()


def test_corrupt_aux_frames_are_rejected_and_counted_apart(scene):
    fr = scene[0]
    db = load_dbc()
    temp_id = db.get_message_by_name("RIMU_TEMP_01").frame_id
    k = np.flatnonzero(fr.arbitration_id == temp_id)
    pay = fr.payload.copy()
    pay[fr.offsets[k[1]] + 2] ^= 0xFF                                # CRC now wrong
    bad = dataclasses.replace(fr, payload=pay)
    acct = FrameAccounting()
    dec = BlockDecoder(db, _aux_map(), acct, sample_rate_hz=FS)
    s = Samples.concat([dec.feed(bad), dec.flush()], 4)
    assert acct.rejected["crc"] == 1 and acct.balanced()
    assert dec.aux_stats["rejected"] == {"crc": 1} and dec.aux_stats["received"][0] == 4
    # the second temperature (21 °C at 0.305 s) never arrived: the first is held until stale
    ts = s.t - T0
    w = (ts >= 0.305) & (ts < 0.405)
    np.testing.assert_allclose(s.aux[w & (ts <= 0.455), 0], 20.0)
    assert np.isnan(s.aux[w & (ts > 0.4551), 0]).all()


def test_specific_force_from_skewed_axes_and_a_missing_axis():
    """Four accelerometer axes (three body axes and a skewed one): the least-squares force;
    with one axis missing the other three still span, with two missing it is NaN."""
    sk = np.array([1.0, 1.0, 1.0]) / np.sqrt(3)
    aux = tuple(AuxChannel(f"a{j}", "specific_force", f"RIMU_ACCEL_{j + 1:02d}", ("RAW",),
                           "m/s^2", axes=ax[None, :])
                for j, ax in enumerate([*np.eye(3), sk]))
    cmap = default_channel_map(4, auxiliary=aux)
    f_true = np.array([[0.3, -1.2, -9.7], [2.0, 0.5, -9.0], [1.0, 1.0, 1.0]])
    A = np.vstack([a.axes for a in aux])
    a = f_true @ A.T
    a[1, 0] = np.nan                 # one axis missing: x from the skewed axis
    a[2, :2] = np.nan                # two missing: no solution
    force, temp = map_effect_inputs(cmap, a)
    assert temp is None and force.shape == (3, 4, 3)
    np.testing.assert_allclose(force[0, 0], f_true[0], atol=1e-12)
    np.testing.assert_allclose(force[1, 2], f_true[1], atol=1e-12)
    assert np.isnan(force[2]).all()


def test_default_timeouts_and_programmatic_checks():
    assert AUX_TIMEOUT_S == {"temperature": 5.0, "specific_force": 0.1}
    assert AuxChannel("t", "temperature", "M", ("S",), "K").timeout_s == 5.0
    assert AuxChannel("f", "specific_force", "M", ("S",), "g",
                      axes=np.eye(3)[:1]).timeout_s == 0.1
    with pytest.raises(ConfigError, match="unit 'g' is not one of"):
        AuxChannel("t", "temperature", "M", ("S",), "g")
    with pytest.raises(ConfigError, match="one body axis per signal"):
        AuxChannel("f", "specific_force", "M", ("X", "Y"), "g", axes=np.eye(3)[:1])


def test_j1939_example_map_decodes_each_imus_acc_and_temperature():
    """The shipped J1939 example: ARI (gyros), ACC and IMUT from three source addresses;
    each IMU's gyros get that IMU's specific force and temperature; a 'not available'
    temperature is held as no value (not the previous one)."""
    cmap = load_channel_map(EXAMPLE_J1939_AUX_MAP)
    db = load_dbc(cmap.dbc)
    ari, acc, imut = (db.get_message_by_name(m) for m in ("ARI", "ACC", "IMUT"))
    rng = np.random.default_rng(5)
    n_s = 50
    force = rng.normal(0, 2, (n_s, 3, 3)) + np.array([0.0, 0.0, -9.8])
    temp = {0: 30.0, 1: 35.5, 2: 41.25}
    msgs = []
    for k in range(n_s):
        t = T0 + k / FS
        for i, sa in enumerate((0x80, 0x81, 0x82)):
            d = ari.encode({"PitchRate": 1.0, "RollRate": 2.0, "YawRate": 3.0,
                            "PitchRateFigureOfMerit": 0, "RollRateFigureOfMerit": 0,
                            "YawRateFigureOfMerit": 0, "RateMeasurementLatency": 1},
                           strict=False)
            msgs.append(Message(timestamp=t + 3e-4 * i, arbitration_id=(ari.frame_id & ~0xFF)
                                | sa, is_extended_id=True, data=d))
            lon, lat, ver = force[k, i]
            d = acc.encode({"LongitudinalAcceleration": lon, "LateralAcceleration": lat,
                            "VerticalAcceleration": ver,
                            "LateralAccelerationFigureOfMerit": 0,
                            "LongitudinalAccelerationFigureOfMerit": 0,
                            "VerticalAccelerationFigureOfMerit": 0}, strict=False)
            msgs.append(Message(timestamp=t + 3e-4 * i + 1e-4,
                                arbitration_id=(acc.frame_id & ~0xFF) | sa,
                                is_extended_id=True, data=d))
            if k in (10, 30):
                raw = 0xFFFF if (k == 30 and i == 1) else round((temp[i] + 273) / 0.03125)
                d = imut.encode({"SensorTemperature": raw}, scaling=False, strict=False)
                msgs.append(Message(timestamp=t + 3e-4 * i + 2e-4,
                                    arbitration_id=(imut.frame_id & ~0xFF) | sa,
                                    is_extended_id=True, data=d))
    acct = FrameAccounting()
    s = decode_frames(RawFrames.from_messages(msgs), db, cmap, acct, sample_rate_hz=FS)
    assert s.t.size == n_s and acct.balanced()
    assert acct.rejected == {"j1939_not_available": 1}        # IMU 2's second temperature
    f, T = map_effect_inputs(cmap, s.aux)
    for i in range(3):
        rows = slice(3 * i, 3 * i + 3)
        # the sample's ACC frame leaves after its ARI frame: sample k holds sample k-1's
        np.testing.assert_allclose(f[1:, rows], np.repeat(force[:-1, i][:, None], 3, axis=1),
                                   atol=0.006)                       # 0.01 m/s² resolution
        assert np.isnan(f[0]).all()
        assert np.isnan(T[:11, rows]).all()
        np.testing.assert_allclose(T[11:31, rows], temp[i])
    np.testing.assert_allclose(T[31:, 0:3], temp[0])
    assert np.isnan(T[31:, 3:6]).all()                               # 'not available'
    np.testing.assert_allclose(T[31:, 6:9], temp[2])


def test_imu_set_log_gives_the_folder_inputs_one_sample_late(tmp_path):
    """A simulated set of three IMUs (accelerometer triad and temperature per IMU) written
    as a CAN log: the map ``write_flight_log`` returns gives each gyro its own IMU's specific
    force and temperature, equal (float32) to what the flight folder gives, one sample late
    (the auxiliary frames leave after their sample's first frame)."""
    from replay.can_read import read_frames
    from replay.can_write import write_flight_log
    from replay.effect_inputs import flight_effect_inputs
    from replay.imu_set import ImuEffects, ImuSetSpec, simulate_imu_set

    fl = simulate_imu_set(ImuSetSpec(imus=3, duration_s=4.0, seed=2,
                                     effects=ImuEffects(temperature_coeff=1e-4)))
    assert fl.aux.kinds.count("temperature") == 3
    log = tmp_path / "set.log"
    aux = write_flight_log(fl, log, temperature_every=1)
    assert [a.sensors for a in aux[:3]] == [("imu1.x", "imu1.y", "imu1.z")] * 3
    cmap = default_channel_map(fl.n, names=fl.sensor_names, auxiliary=aux)
    frames, acct = read_frames(log, progress=False)
    s = decode_frames(frames, load_dbc(), cmap, acct, sample_rate_hz=fl.sample_rate_hz)
    assert acct.balanced() and acct.n_rejected == 0 and s.t.size == fl.t.size
    f_can, T_can = map_effect_inputs(cmap, s.aux)
    f_dir, T_dir, avail = flight_effect_inputs(fl)
    assert map_available(cmap) == avail
    np.testing.assert_allclose(f_can[1:], f_dir[:-1], rtol=1e-6, atol=1e-5)
    np.testing.assert_allclose(T_can[1:], T_dir[:-1], rtol=1e-6, atol=1e-4)
    assert np.isnan(f_can[0]).all() and np.isnan(T_can[0]).all()


@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_hold_with_trimming_equals_brute_force(data):
    """Any aux times and values, any increasing sample times, queried block by block with
    the history trimmed after each block (as the decoder does): the brute-force hold."""
    from replay.aux_hold import AuxHold

    timeout = data.draw(st.floats(0.01, 2.0), label="timeout")
    cmap = default_channel_map(1, auxiliary=(AuxChannel(
        "t", "temperature", "RIMU_TEMP_01", ("RAW",), "degC", timeout_s=timeout),))
    gaps = data.draw(st.lists(st.floats(0.0, 1.5), min_size=0, max_size=40), label="aux")
    at = np.cumsum(gaps)
    av = np.array(data.draw(st.lists(st.floats(-50, 150) | st.just(float("nan")),
                                     min_size=at.size, max_size=at.size), label="values"))
    sg = data.draw(st.lists(st.floats(0.0, 1.0), min_size=1, max_size=60), label="samples")
    ts = np.cumsum(sg) - 0.5
    hold = AuxHold(cmap)
    cuts = sorted(data.draw(st.lists(st.integers(0, ts.size), max_size=5), label="cuts"))
    got, a0 = [], 0
    for lo, hi in zip([0, *cuts], [*cuts, ts.size], strict=True):
        a1 = int(np.searchsorted(at, ts[hi - 1], side="right")) if hi > lo else a0
        a1 = max(a1, a0)
        hold.add(0, at[a0:a1], av[a0:a1])             # what has arrived by then
        a0 = a1
        if hi > lo:
            got.append(hold.at(ts[lo:hi])[:, 0])
            hold.trim(float(ts[hi - 1]))
    got = np.concatenate(got)
    exp = _held(at, av, ts, timeout)
    np.testing.assert_array_equal(np.isnan(got), np.isnan(exp))
    np.testing.assert_allclose(got[~np.isnan(got)], exp[~np.isnan(exp)])
