"""Shipped DBC layout and the vectorised block decoder against cantools' own decode."""

import os
from pathlib import Path

import cantools
import numpy as np
import pytest

from replay.channel_map import EXAMPLE_J1939_MAP, load_channel_map
from replay.crc import crc8_j1850
from replay.frames import (
    DEFAULT_DBC,
    IMU_ACCEL_BASE_ID,
    IMU_GYRO_BASE_ID,
    encode_imu_frames,
    imu_message_name,
    load_dbc,
    message_layout,
)

COMMA_DBC = (Path(os.environ.get("RIMU_SHARED_DATA",
                                 DEFAULT_DBC.parents[2] / ".." / "shared" / "data"))
             / "comma2k19_can" / "toyota_2017_kinematics_excerpt.dbc")


def test_shipped_dbc_messages_and_signals():
    db = load_dbc()
    for kind, base in (("gyro", IMU_GYRO_BASE_ID), ("accel", IMU_ACCEL_BASE_ID)):
        for i in (1, 6, 12):
            m = db.get_message_by_name(imu_message_name(kind, i))
            assert m.frame_id == base + i and m.length == 8 and not m.is_extended_frame
            sig = {s.name: s for s in m.signals}
            assert sig["RAW"].is_float and sig["RAW"].length == 32
            assert (sig["SAMPLE"].start, sig["SAMPLE"].length) == (32, 16)
            assert (sig["STATUS"].start, sig["STATUS"].length) == (48, 4)
            assert (sig["COUNTER"].start, sig["COUNTER"].length) == (52, 4)
            assert (sig["CRC"].start, sig["CRC"].length) == (56, 8)


def test_encoded_frames_carry_crc_counter_and_decode_through_cantools():
    db = load_dbc()
    m = db.get_message_by_name("RIMU_GYRO_04")
    rng = np.random.default_rng(5)
    raw = rng.normal(0, 3e4, 40)
    raw[3] = np.nan
    raw[4] = 1e300  # clipped to the float32 range before encoding
    frames = encode_imu_frames(m, raw, np.arange(40) + 65520, np.arange(40) + 14)
    for k, f in enumerate(frames):
        assert crc8_j1850(f[:7]) == f[7], f"frame {k}: CRC byte"
        d = m.decode(f, decode_choices=False)
        assert d["SAMPLE"] == (65520 + k) % 65536 and d["COUNTER"] == (14 + k) % 16
        if k == 3:
            assert np.isnan(d["RAW"])
        elif k == 4:
            assert d["RAW"] == pytest.approx(float(np.finfo(np.float32).max), rel=1e-7)
        else:
            assert d["RAW"] == pytest.approx(raw[k], rel=6e-8), f"frame {k}: RAW"


def _check_block_equals_cantools(msg, payload):
    lay = message_layout(msg)
    assert lay.vectorisable
    blk = lay.decode_block(payload)
    for k in range(payload.shape[0]):
        ref = msg.decode(payload[k].tobytes(), decode_choices=False, scaling=True)
        for name, v in ref.items():
            got = blk[name][k]
            if isinstance(v, float) and np.isnan(v):
                assert np.isnan(got), f"{msg.name}.{name} frame {k}"
            else:
                assert got == v, f"{msg.name}.{name} frame {k}: {got} != {v}"


def test_block_decode_equals_cantools_little_endian_float_and_j1939():
    rng = np.random.default_rng(11)
    p = rng.integers(0, 256, (500, 8), dtype=np.uint8)
    db = load_dbc()
    _check_block_equals_cantools(db.get_message_by_name("RIMU_ACCEL_02"), p)
    jdb = load_dbc(load_channel_map(EXAMPLE_J1939_MAP).dbc)
    for name in ("ARI", "ACC"):
        _check_block_equals_cantools(jdb.get_message_by_name(name), p)


def test_block_decode_equals_cantools_big_endian_and_signed():
    rng = np.random.default_rng(12)
    p = rng.integers(0, 256, (500, 8), dtype=np.uint8)
    dbc = """VERSION ""
BO_ 300 MIXED: 8 X
 SG_ A : 7|12@0- (0.5,-3) [0|0] "" X
 SG_ B : 11|9@0+ (1,0) [0|0] "" X
 SG_ C : 24|13@1- (0.25,1) [0|0] "" X
 SG_ D : 47|16@0- (2,0) [0|0] "" X
 SG_ E : 63|8@0+ (1,0) [0|0] "" X
"""
    db = cantools.database.load_string(dbc, database_format="dbc")
    _check_block_equals_cantools(db.get_message_by_name("MIXED"), p)
    if COMMA_DBC.is_file():
        cdb = cantools.database.load_file(str(COMMA_DBC))
        _check_block_equals_cantools(cdb.get_message_by_frame_id(36), p)
