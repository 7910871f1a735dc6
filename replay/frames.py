"""CAN frame layouts from a DBC (cantools) and vectorised decoding of frame blocks.

cantools reads the DBC; its signal layout (start bit, length, byte order, sign, float,
scale, offset) is turned into a :class:`SignalLayout` that extracts the signal's raw
integer from a block of payloads at once (``np.frombuffer`` over the stacked payloads)
instead of calling cantools once per frame (about 7 µs each). ``tests/replay/test_frames.py``
checks that the block decode equals cantools' own ``decode`` bit for bit.

The shipped DBC ``replay/dbc/rimu_imu.dbc`` describes a redundant IMU: message
``RIMU_GYRO_ii`` (0x100 + i) and ``RIMU_ACCEL_ii`` (0x180 + i), i = 1..12, one frame per
sensor per sample, 8 bytes, little endian::

    RAW     bits  0..31  float32 IEEE, the raw output in the calibration's raw unit
    SAMPLE  bits 32..47  16-bit sample counter, equal for all sensors of one sample
    STATUS  bits 48..51  0 OK, 1 DEGRADED, 2 FAILED, 3 INIT
    COUNTER bits 52..55  4-bit rolling counter per message (+1 mod 16)
    CRC     bits 56..63  CRC-8 SAE J1850 over bytes 0..6 (see :mod:`replay.crc`)

float32 keeps a relative resolution of 6e-8 (24-bit mantissa): a raw output of 10⁴ mV
is carried to 0.6 µV, far below any sensor noise, and needs no scale choice per sensor.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cantools
import numpy as np

from fdi.errors import ConfigError, FileFormatError
from replay.crc import crc8_j1850_block

__all__ = [
    "DEFAULT_DBC",
    "IMU_ACCEL_BASE_ID",
    "IMU_GYRO_BASE_ID",
    "MessageLayout",
    "SignalLayout",
    "encode_imu_frames",
    "imu_message_name",
    "load_dbc",
    "message_layout",
]

DEFAULT_DBC = Path(__file__).with_name("dbc") / "rimu_imu.dbc"
"""The DBC shipped with rimu for its redundant-IMU frames."""
IMU_GYRO_BASE_ID = 0x100
"""Frame id of gyro i is ``IMU_GYRO_BASE_ID + i`` (i = 1..12)."""
IMU_ACCEL_BASE_ID = 0x180
"""Frame id of accelerometer i is ``IMU_ACCEL_BASE_ID + i`` (i = 1..12)."""
IMU_MAX_SENSORS = 12


def imu_message_name(kind: str, i: int) -> str:
    """Message name of sensor ``i`` (1-based) of ``kind`` in the shipped DBC."""
    if kind not in ("gyro", "accel"):
        raise ConfigError(f"unknown sensor kind {kind!r}; expected 'gyro' or 'accel'")
    if not 1 <= i <= IMU_MAX_SENSORS:
        raise ConfigError(f"the shipped DBC carries sensors 1..{IMU_MAX_SENSORS}, not {i}")
    return f"RIMU_{kind.upper()}_{i:02d}"


def load_dbc(path: str | Path | None = None) -> cantools.database.can.Database:
    """Load a DBC with cantools (the shipped ``rimu_imu.dbc`` when ``path`` is None).

    Raises
    ------
    FileFormatError
        The file is missing or cantools cannot parse it.
    """
    p = DEFAULT_DBC if path is None else Path(path)
    try:
        return cantools.database.load_file(str(p), database_format="dbc", strict=False)
    except OSError as exc:
        raise FileFormatError(str(p), f"cannot read DBC ({exc.strerror or exc})") from None
    except Exception as exc:  # cantools raises its own parse errors
        raise FileFormatError(str(p), f"not a valid DBC ({exc})") from None


@dataclass(frozen=True)
class SignalLayout:
    """Where one signal sits in a payload, and how its raw integer scales.

    Attributes
    ----------
    name : str
    shift : int
        Bit position of the signal's least significant bit in the payload read as a
        64-bit integer (little-endian integer for Intel signals, big-endian for Motorola).
    length : int
        Bits.
    big_endian : bool
    signed, is_float : bool
    scale, offset : float
        physical = raw·scale + offset.
    unit : str
    """

    name: str
    shift: int
    length: int
    big_endian: bool
    signed: bool
    is_float: bool
    scale: float
    offset: float
    unit: str = ""

    def raw(self, words_le: np.ndarray, words_be: np.ndarray) -> np.ndarray:
        """Raw integer of the signal in each frame (int64; uint bits of floats).

        Parameters
        ----------
        words_le, words_be : ndarray of uint64, shape (N,)
            The payloads (zero-padded to 8 bytes) read as little- and big-endian words.
        """
        w = words_be if self.big_endian else words_le
        mask = np.uint64((1 << self.length) - 1) if self.length < 64 else np.uint64(2**64 - 1)
        v = (w >> np.uint64(self.shift)) & mask
        if self.is_float:
            return v
        v = v.astype(np.int64) if self.length < 64 else v.view(np.int64)
        if self.signed and self.length < 64:
            sign = np.int64(1) << np.int64(self.length - 1)
            v = (v ^ sign) - sign
        return v

    def physical(self, raw: np.ndarray) -> np.ndarray:
        """Physical value (float64) from :meth:`raw`."""
        if self.is_float:
            with np.errstate(invalid="ignore"):  # signalling NaN payloads are NaN
                if self.length == 32:
                    f = raw.astype(np.uint32).view(np.float32).astype(np.float64)
                else:
                    f = raw.view(np.float64).copy()
                return f * self.scale + self.offset
        return raw.astype(np.float64) * self.scale + self.offset


@dataclass(frozen=True)
class MessageLayout:
    """A DBC message as block-decodable signal layouts.

    Attributes
    ----------
    name : str
    frame_id : int
    length : int
        Payload bytes the DBC declares.
    is_extended : bool
    signals : dict of str to SignalLayout
    vectorisable : bool
        False for payloads over 8 bytes or multiplexed messages (decoded by cantools).
    """

    name: str
    frame_id: int
    length: int
    is_extended: bool
    signals: dict[str, SignalLayout]
    vectorisable: bool

    def words(self, payload: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Little- and big-endian 64-bit words of a payload block (N, length) uint8."""
        p = np.asarray(payload, dtype=np.uint8)
        n = p.shape[0]
        if p.shape[1] < 8:
            q = np.zeros((n, 8), dtype=np.uint8)
            q[:, : p.shape[1]] = p
            p = q
        elif p.shape[1] > 8:
            raise ConfigError(f"message {self.name}: block decode handles up to 8 bytes")
        p = np.ascontiguousarray(p)
        return p.view("<u8").ravel(), p.view(">u8").ravel()

    def decode_block(self, payload: np.ndarray,
                     names: list[str] | None = None) -> dict[str, np.ndarray]:
        """Physical values of the signals ``names`` (all when None) for each frame.

        Parameters
        ----------
        payload : ndarray of uint8, shape (N, length)

        Returns
        -------
        dict of str to ndarray, shape (N,)
        """
        le, be = self.words(payload)
        out = {}
        for name in names or list(self.signals):
            s = self.signals[name]
            out[name] = s.physical(s.raw(le, be))
        return out


def _signal_layout(sig: cantools.database.can.Signal) -> SignalLayout:
    big = sig.byte_order == "big_endian"
    if big:
        # DBC (sawtooth) numbering: bit b is bit b%8 of byte b//8; in a big-endian word
        # byte k occupies bits 63-8k..56-8k. sig.start is the MSB for Motorola signals.
        msb = (7 - sig.start // 8) * 8 + sig.start % 8
        shift = msb - (sig.length - 1)
    else:
        shift = sig.start
    return SignalLayout(name=sig.name, shift=shift, length=sig.length, big_endian=big,
                        signed=bool(sig.is_signed), is_float=bool(sig.is_float),
                        scale=float(sig.scale), offset=float(sig.offset),
                        unit=sig.unit or "")


def message_layout(msg: cantools.database.can.Message) -> MessageLayout:
    """Block-decodable layout of a cantools message."""
    sigs = {s.name: _signal_layout(s) for s in msg.signals}
    ok = msg.length <= 8 and not msg.is_multiplexed() and all(
        0 <= s.shift and s.shift + s.length <= 64 for s in sigs.values())
    return MessageLayout(name=msg.name, frame_id=int(msg.frame_id), length=int(msg.length),
                         is_extended=bool(msg.is_extended_frame), signals=sigs,
                         vectorisable=ok)


def encode_imu_frames(msg: cantools.database.can.Message, raw: np.ndarray,
                      sample: np.ndarray, counter: np.ndarray,
                      status: np.ndarray | None = None) -> list[bytes]:
    """Encode frames of one shipped-DBC IMU message through cantools, with their CRC.

    Parameters
    ----------
    msg : cantools Message
        A ``RIMU_GYRO_ii``/``RIMU_ACCEL_ii`` message of the shipped DBC.
    raw : ndarray, shape (N,)
        Raw outputs; clipped to the float32 range before encoding (NaN passes as NaN).
    sample : ndarray of int, shape (N,)
        Sample counters (taken modulo 65536).
    counter : ndarray of int, shape (N,)
        Rolling counters (taken modulo 16).
    status : ndarray of int, shape (N,), optional
        Status codes (default 0, OK).

    Returns
    -------
    list of bytes
        N payloads of 8 bytes, CRC in byte 7.
    """
    f32 = float(np.finfo(np.float32).max)
    r = np.clip(np.asarray(raw, dtype=np.float64), -f32, f32)
    smp = np.asarray(sample, dtype=np.int64) % 65536
    ctr = np.asarray(counter, dtype=np.int64) % 16
    st = np.zeros(len(r), np.int64) if status is None else np.asarray(status, np.int64) % 16
    enc = msg.encode
    data = bytearray()
    for k in range(len(r)):
        data += enc({"RAW": float(r[k]), "SAMPLE": int(smp[k]), "STATUS": int(st[k]),
                     "COUNTER": int(ctr[k]), "CRC": 0}, scaling=True, padding=False,
                    strict=False)
    block = np.frombuffer(bytes(data), dtype=np.uint8).reshape(-1, 8).copy()
    block[:, 7] = crc8_j1850_block(block[:, :7])
    return [b.tobytes() for b in block]
