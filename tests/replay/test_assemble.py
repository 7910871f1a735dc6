"""Sample assembly: sample-counter wrap, arrival jitter and reordering, duplicates, missing
values (never zero), time-tolerance assembly."""

import numpy as np
from can import Message

from replay.accounting import FrameAccounting
from replay.assemble import decode_frames
from replay.channel_map import ChannelMap, SensorChannel, default_channel_map
from replay.frames import encode_imu_frames, imu_message_name, load_dbc
from replay.raw_frames import RawFrames

DB = load_dbc()


def _frames(n, N, *, start_sample=0, rng=None, skip=(), order_jitter=0.0):
    """Shipped-DBC frames for n sensors, N samples (value = 1000·sensor + sample)."""
    rng = rng or np.random.default_rng(0)
    out = []
    for i in range(n):
        msg = DB.get_message_by_name(imu_message_name("gyro", i + 1))
        k = np.arange(N)
        data = encode_imu_frames(msg, 1000.0 * (i + 1) + k, start_sample + k, k + 3 * i)
        for kk in range(N):
            if (kk, i) in skip:
                continue
            t = 50.0 + kk / 100.0 + 1e-4 * i + rng.uniform(0, order_jitter)
            out.append(Message(timestamp=t, arbitration_id=msg.frame_id, is_extended_id=False,
                               data=data[kk], channel=0))
    out.sort(key=lambda m: m.timestamp)
    return out


def _decode(msgs, cmap):
    acct = FrameAccounting()
    s = decode_frames(RawFrames.from_messages(msgs), DB, cmap, acct, sample_rate_hz=100.0)
    return s, acct


def test_counter_assembly_across_wrap_with_jittered_interleaving():
    # jitter up to 9.5 ms: frames of neighbouring samples from different sensors interleave
    # (each sensor's own frames stay in order, as on a real bus)
    msgs = _frames(4, 300, start_sample=65400, order_jitter=0.0095,
                   rng=np.random.default_rng(1))
    s, acct = _decode(msgs, default_channel_map(4))
    assert acct.balanced() and acct.used == 1200 and not acct.rejected
    assert s.t.size == 300 and s.valid.all()
    np.testing.assert_array_equal(s.sample_index, np.arange(300))
    expect = 1000.0 * np.arange(1, 5)[None, :] + np.arange(300)[:, None]
    np.testing.assert_array_equal(s.raw, expect)


def test_missing_frame_is_missing_not_zero_and_duplicates_rejected():
    msgs = _frames(3, 50, skip={(10, 1), (11, 1), (30, 0)})
    dup = msgs[3 * 20]
    msgs.insert(3 * 20 + 1, Message(timestamp=dup.timestamp + 1e-5,
                                    arbitration_id=dup.arbitration_id, is_extended_id=False,
                                    data=dup.data))
    s, acct = _decode(msgs, default_channel_map(3))
    # the copy repeats the rolling counter: rejected before assembly
    assert dict(acct.rejected) == {"counter_repeat": 1}
    assert acct.used == 150 - 3 and acct.balanced()
    for k, i in [(10, 1), (11, 1), (30, 0)]:
        assert not s.valid[k, i] and np.isnan(s.raw[k, i])
    assert s.valid.sum() == 147


def test_time_assembly_without_counter():
    sensors = tuple(SensorChannel(f"g{i + 1}", imu_message_name("gyro", i + 1), "RAW")
                    for i in range(3))
    cmap = ChannelMap(sensors, time_tolerance_s=0.002)
    msgs = _frames(3, 40, skip={(5, 2)}, order_jitter=0.0005)
    s, acct = _decode(msgs, cmap)
    assert acct.used == 119 and acct.balanced() and not acct.rejected
    assert s.t.size == 40
    assert not s.valid[5, 2] and np.isnan(s.raw[5, 2])
    np.testing.assert_allclose(s.t, 50.0 + np.arange(40) / 100.0, atol=6e-4)
    # a same-sensor frame twice within one sample is a duplicate
    msgs2 = list(msgs)
    m = msgs2[9]
    msgs2.insert(10, Message(timestamp=m.timestamp + 1e-4, arbitration_id=m.arbitration_id,
                             is_extended_id=False, data=m.data))
    _, acct2 = _decode(msgs2, cmap)
    assert dict(acct2.rejected) == {"duplicate": 1} and acct2.balanced()


def test_status_not_ok_and_error_frames_are_rejected_with_reason():
    msg = DB.get_message_by_name(imu_message_name("gyro", 1))
    data = encode_imu_frames(msg, np.arange(5.0), np.arange(5), np.arange(5),
                             status=np.array([0, 0, 2, 0, 0]))
    msgs = [Message(timestamp=1.0 + k / 100, arbitration_id=msg.frame_id,
                    is_extended_id=False, data=d) for k, d in enumerate(data)]
    msgs.append(Message(timestamp=1.2, is_error_frame=True))
    msgs.append(Message(timestamp=1.3, arbitration_id=msg.frame_id, is_extended_id=False,
                        is_remote_frame=True, dlc=8))
    msgs.append(Message(timestamp=float("nan"), arbitration_id=msg.frame_id,
                        is_extended_id=False, data=data[0]))
    msgs.append(Message(timestamp=1.4, arbitration_id=msg.frame_id, is_extended_id=True,
                        data=data[0]))  # same id number, extended: a different frame
    s, acct = _decode(msgs, default_channel_map(1))
    assert dict(acct.rejected) == {"status": 1, "error_frame": 1, "remote_frame": 1,
                                   "nonfinite_time": 1, "unknown_id": 1}
    assert acct.used == 4 and acct.read == 9 and acct.balanced()
    np.testing.assert_array_equal(s.raw[:, 0], [0, 1, 3, 4])
