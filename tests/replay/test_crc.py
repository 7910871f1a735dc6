"""CRC-8 SAE J1850: check value, crccheck agreement, vectorised block equals per-frame."""

import numpy as np
from crccheck.crc import Crc8SaeJ1850

from replay.crc import CRC8_CHECK, crc8_j1850, crc8_j1850_block


def test_check_value_is_0x4b():
    assert CRC8_CHECK == 0x4B
    assert Crc8SaeJ1850.calc(b"123456789") == 0x4B
    assert crc8_j1850(b"123456789") == 0x4B
    blk = np.frombuffer(b"123456789", np.uint8)[None, :]
    assert int(crc8_j1850_block(blk)[0]) == 0x4B


def test_block_equals_crccheck_and_detects_every_single_bit_flip():
    rng = np.random.default_rng(3)
    p = rng.integers(0, 256, (2000, 7), dtype=np.uint8)
    blk = crc8_j1850_block(p)
    ref = np.array([Crc8SaeJ1850.calc(r.tobytes()) for r in p], np.uint8)
    np.testing.assert_array_equal(blk, ref, err_msg="vectorised CRC differs from crccheck")
    # a CRC-8 with poly 0x1D detects every single-bit error in 7 bytes
    row = p[0]
    for bit in range(56):
        q = row.copy()
        q[bit // 8] ^= np.uint8(1 << (bit % 8))
        assert crc8_j1850(q.tobytes()) != crc8_j1850(row.tobytes()), f"bit {bit}"
