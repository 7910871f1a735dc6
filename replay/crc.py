"""CRC-8 SAE J1850 for the rimu IMU frames, per frame and vectorised.

Polynomial 0x1D, initial value 0xFF, final XOR 0xFF, no reflection (SAE J1850, also
AUTOSAR E2E Profile 1/2's CRC-8). Check value on ``b"123456789"`` is 0x4B. The per-frame
function delegates to :class:`crccheck.crc.Crc8SaeJ1850` (installed with cantools); the
vectorised one runs the same table over a block of payloads column by column.
"""

from __future__ import annotations

import numpy as np
from crccheck.crc import Crc8SaeJ1850

__all__ = ["CRC8_CHECK", "crc8_j1850", "crc8_j1850_block"]

CRC8_CHECK = 0x4B
"""CRC-8 SAE J1850 of ``b"123456789"``."""

_POLY = 0x1D


def _table() -> np.ndarray:
    t = np.zeros(256, dtype=np.uint8)
    for i in range(256):
        c = i
        for _ in range(8):
            c = ((c << 1) ^ _POLY) & 0xFF if c & 0x80 else (c << 1) & 0xFF
        t[i] = c
    return t


_TABLE = _table()


def crc8_j1850(data: bytes) -> int:
    """CRC-8 SAE J1850 of one byte string (via ``crccheck``)."""
    return int(Crc8SaeJ1850.calc(bytes(data)))


def crc8_j1850_block(payload: np.ndarray) -> np.ndarray:
    """CRC-8 SAE J1850 of each row of a byte block.

    Parameters
    ----------
    payload : ndarray of uint8, shape (N, L)
        N frames, the L bytes the CRC covers.

    Returns
    -------
    ndarray of uint8, shape (N,)
    """
    p = np.asarray(payload, dtype=np.uint8)
    crc = np.full(p.shape[0], 0xFF, dtype=np.uint8)
    for j in range(p.shape[1]):
        crc = _TABLE[crc ^ p[:, j]]
    return crc ^ np.uint8(0xFF)
