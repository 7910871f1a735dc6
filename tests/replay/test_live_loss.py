"""Issue 10: live loss accounting. Over a bus that drops frames, every frame read is used or
rejected with a reason, the first good frame after a gap is used (it was discarded as a
``counter_jump``), and every sample missing from the sequence is counted as lost.

The frames go through python-can's in-process virtual bus from a sender thread, with a
simulated gap pattern: a 20-sample outage of the whole bus (longer than the 4-bit rolling
counter's range), a 5-sample outage of one sensor, and single frames.
"""

from __future__ import annotations

import threading
import uuid

import can
import numpy as np
from test_logio import CAL

from fdi.monitor import Monitor
from replay.can_write import write_flight_log
from replay.flight import simulate_flight
from replay.live import StreamDecoder, run_live
from replay.logio import read_log, resolve_map
from replay.report import RunningReport

N_SAMPLES = 300
BUS_OUTAGE = range(50, 70)            # every sensor, 20 samples
SENSOR_OUTAGE = (3, range(100, 105))  # sensor 3 (0-based 2), 5 samples
SINGLES = [(200, 1), (250, 6)]        # (sample, sensor 1-based)


def _dropped(k: int, sensor: int) -> bool:
    return (k in BUS_OUTAGE or (sensor == SENSOR_OUTAGE[0] and k in SENSOR_OUTAGE[1])
            or (k, sensor) in SINGLES)


def _messages(tmp_path):
    f = simulate_flight(CAL, N_SAMPLES / CAL.sample_rate_hz, seed=21)
    p = tmp_path / "all.log"
    write_flight_log(f, p)
    db, _ = resolve_map(CAL)
    ids = {db.get_message_by_name(f"RIMU_GYRO_{i:02d}").frame_id: i for i in range(1, 7)}
    kept, k, seen = [], -1, set()
    for m in can.LogReader(str(p)):
        i = ids[m.arbitration_id]
        if i == 1 or i in seen:           # sensor 1 opens each sample
            k += 1 if i == 1 else 0
            seen = set()
        seen.add(i)
        if not _dropped(k, i):
            kept.append(m)
    return f, kept


def _expected_lost_frames() -> int:
    n = 6
    return len(BUS_OUTAGE) * n + len(SENSOR_OUTAGE[1]) + len(SINGLES)


def test_gaps_on_a_virtual_bus_are_counted_not_discarded(tmp_path):
    f, kept = _messages(tmp_path)
    channel = f"rimu-loss-{uuid.uuid4().hex}"
    db, cmap = resolve_map(CAL)
    dec = StreamDecoder(db, cmap, CAL.sample_rate_hz)
    acc = RunningReport()
    with can.Bus(interface="virtual", channel=channel, ignore_config=True,
                 preserve_timestamps=True) as rx:
        def send() -> None:
            with can.Bus(interface="virtual", channel=channel, ignore_config=True,
                         preserve_timestamps=True) as tx:
                for m in kept:
                    tx.send(m)

        th = threading.Thread(target=send, daemon=True)
        th.start()
        result, fr = run_live(rx, dec, Monitor(CAL), max_frames=len(kept),
                              idle_timeout_s=10.0, window=50, summary=acc)
        th.join(10)
    # every frame read is used (none is corrupt: the first frame after a gap is good)
    assert fr["read"] == len(kept) and fr["used"] == len(kept) and fr["rejected"] == {}
    assert fr["balanced"]
    # every missing frame and every missing sample is counted
    assert fr["lost_frames"] == _expected_lost_frames()
    assert fr["lost_samples"] == len(BUS_OUTAGE)
    assert acc.samples == N_SAMPLES - len(BUS_OUTAGE)
    assert acc.samples + fr["lost_samples"] == N_SAMPLES
    # the bounded window keeps the last 50 answers only
    assert len(result.t) == 50
    np.testing.assert_allclose(result.t[-1], f.t[-1], atol=1e-3)

    # the offline replay of the same frames accounts for them identically
    q = tmp_path / "gaps.log"
    with can.Logger(str(q)) as w:
        for m in kept:
            w.on_message_received(m)
    _, off = read_log(q, CAL, progress=False)
    for key in ("read", "used", "rejected", "lost_frames", "lost_samples"):
        assert off[key] == fr[key], key


def test_frame_by_frame_equals_one_batch(tmp_path):
    """The live decoder fed frame by frame, or in one batch, or the offline one: same
    samples and accounting (the decoder state carries across calls)."""
    _, kept = _messages(tmp_path)
    db, cmap = resolve_map(CAL)
    one = StreamDecoder(db, cmap, CAL.sample_rate_hz)
    s1 = [x for m in kept for x in one.feed(m)] + one.flush()
    many = StreamDecoder(db, cmap, CAL.sample_rate_hz)
    s2 = many.feed_many(kept) + many.flush()
    assert len(s1) == len(s2) == N_SAMPLES - len(BUS_OUTAGE)
    np.testing.assert_array_equal(np.array([x[0] for x in s1]), np.array([x[0] for x in s2]))
    np.testing.assert_array_equal(np.array([x[2] for x in s1]), np.array([x[2] for x in s2]))
    a, b = one.acct.to_dict(), many.acct.to_dict()
    assert a == b and a["balanced"]


def test_jittered_interleaving_frame_by_frame_equals_offline():
    """Frames of neighbouring samples interleave (9.5 ms jitter at 100 Hz): fed one at a
    time, the live decoder holds a sample until it is complete or two later samples were
    seen, so nothing is 'late' and the samples equal the offline ones."""
    from test_assemble import DB, _decode, _frames

    from replay.channel_map import default_channel_map

    msgs = _frames(4, 300, start_sample=65400, order_jitter=0.0095,
                   rng=np.random.default_rng(1))
    cmap = default_channel_map(4)
    off, acct_off = _decode(msgs, cmap)
    dec = StreamDecoder(DB, cmap, 100.0)
    got = [x for m in msgs for x in dec.feed(m)] + dec.flush()
    a = dec.acct.to_dict()
    assert a["rejected"] == {} and a["used"] == acct_off.used == 1200
    np.testing.assert_array_equal(np.array([x[0] for x in got]), off.t)
    np.testing.assert_array_equal(np.array([x[1] for x in got]), off.raw)
