"""Slots: which frames carry which values of a channel map, and how a frame is matched.

A *slot* is one DBC message (for J1939: its PGN and the sensor's source address) on one
bus channel, carrying the values of one or more sensors (:func:`build_slots`) or auxiliary
columns (:func:`build_aux_slots`), with the signals of its checks (rolling counter, CRC,
sample counter, status). Frames are matched to slots by a key (:func:`frame_keys`): the id
and its format, or for J1939 the PGN and the source address.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import cantools
import numpy as np

from fdi.errors import ConfigError
from replay.channel_map import ChannelMap
from replay.frames import MessageLayout, message_layout

__all__ = [
    "Slot",
    "aux_columns",
    "build_aux_slots",
    "build_slots",
    "frame_keys",
    "sibling_keys",
]

_EXT = 1 << 40
"""Key bit of an extended (29-bit) id."""
_J1939 = 1 << 41
"""Key bit of a J1939 key: (PGN << 8) | source address."""


@dataclass(frozen=True)
class Slot:
    """One message (one source address, one channel) carrying some sensors' values.

    Attributes
    ----------
    key : int
        Frame key (:func:`frame_keys`).
    channel : object
        Bus channel filter (None: any).
    layout : MessageLayout
    sensors : tuple of int
        0-based sensor indices, and ``signals`` their signal names.
    signals : tuple of str
    counter, crc, sample_counter, status : str or None
        Signal names of the checks.
    message : cantools Message
        The DBC message.
    """

    key: int
    channel: object
    layout: MessageLayout
    sensors: tuple[int, ...]
    signals: tuple[str, ...]
    counter: str | None
    crc: str | None
    sample_counter: str | None
    status: str | None
    message: cantools.database.can.Message


def _pgn(arb: np.ndarray) -> np.ndarray:
    pf = (arb >> 16) & 0xFF
    ps = (arb >> 8) & 0xFF
    dp = (arb >> 24) & 0x3
    return (dp << 16) | (pf << 8) | np.where(pf >= 240, ps, 0)


def frame_keys(arb: np.ndarray, extended: np.ndarray, j1939: bool) -> np.ndarray:
    """Matching key of each frame: id and format, or J1939 (PGN, source address)."""
    a = np.asarray(arb, np.int64)
    ext = np.asarray(extended, bool)
    if j1939:
        return np.where(ext, _J1939 | (_pgn(a) << 8) | (a & 0xFF), a)
    return a | np.where(ext, _EXT, 0)


def _message_key(msg: cantools.database.can.Message, sa: int | None, j1939: bool) -> int:
    fid = int(msg.frame_id)
    if j1939:
        if not msg.is_extended_frame:
            raise ConfigError(f"J1939 map: DBC message {msg.name} is not an extended frame")
        pgn = int(_pgn(np.array([fid], np.int64))[0])
        return _J1939 | (pgn << 8) | (fid & 0xFF if sa is None else sa)
    return fid | (_EXT if msg.is_extended_frame else 0)


def _message(db: cantools.database.can.Database, name: str,
             where: str) -> cantools.database.can.Message:
    """The DBC message ``name`` (``where``: the map entry naming it, for the error)."""
    try:
        return db.get_message_by_name(name)
    except KeyError:
        raise ConfigError(f"{where}: message {name!r} is not in the DBC") from None


def _check_signals(msg: cantools.database.can.Message, wanted: tuple[str | None, ...],
                   where: str) -> None:
    names = {sg.name for sg in msg.signals}
    for what in wanted:
        if what is not None and what not in names:
            raise ConfigError(f"{where}: signal {what!r} is not in message {msg.name}")


def _checked_layout(msg: cantools.database.can.Message, crc_signal: str | None,
                    source: object) -> MessageLayout:
    """The message's layout, checked for the block decoder: a CRC signal is the last byte,
    payloads are at most 8 bytes and not multiplexed."""
    lay = message_layout(msg)
    if crc_signal is not None:
        cs = lay.signals[crc_signal]
        if cs.length != 8 or cs.big_endian or cs.shift != 8 * (msg.length - 1):
            raise ConfigError(f"channel map {source}: CRC signal {crc_signal} of "
                              f"{msg.name} must be the last byte")
    if not lay.vectorisable:
        raise ConfigError(f"message {msg.name}: payloads over 8 bytes or multiplexed "
                          "messages are not supported by the block decoder")
    return lay


def build_slots(db: cantools.database.can.Database, cmap: ChannelMap) -> list[Slot]:
    """Group the map's sensors into slots (one per message, source address and channel).

    Raises
    ------
    ConfigError
        A message or signal the map names is not in the DBC, or the slot's sensors
        disagree on their check signals.
    """
    groups: dict[tuple[int, object], list[int]] = {}
    msgs: dict[tuple[int, object], cantools.database.can.Message] = {}
    for i, s in enumerate(cmap.sensors):
        where = f"channel map {cmap.source}: sensor {i + 1} ({s.name})"
        msg = _message(db, s.message, where)
        _check_signals(msg, (s.signal, s.counter_signal, s.crc_signal,
                             s.sample_counter_signal, s.status_signal), where)
        k = (_message_key(msg, s.source_address, cmap.j1939), s.channel)
        groups.setdefault(k, []).append(i)
        msgs[k] = msg
    slots = []
    for (key, ch), idx in groups.items():
        first = cmap.sensors[idx[0]]
        checks = (first.counter_signal, first.crc_signal, first.sample_counter_signal,
                  first.status_signal)
        for i in idx[1:]:
            s = cmap.sensors[i]
            if (s.counter_signal, s.crc_signal, s.sample_counter_signal,
                    s.status_signal) != checks:
                raise ConfigError(f"channel map {cmap.source}: sensors {idx[0] + 1} and "
                                  f"{i + 1} share message {s.message} but name different "
                                  "counter/CRC/sample/status signals")
        msg = msgs[(key, ch)]
        lay = _checked_layout(msg, first.crc_signal, cmap.source)
        slots.append(Slot(key=key, channel=ch, layout=lay, sensors=tuple(idx),
                          signals=tuple(cmap.sensors[i].signal for i in idx),
                          counter=checks[0], crc=checks[1], sample_counter=checks[2],
                          status=checks[3], message=msg))
    return slots


def aux_columns(cmap: ChannelMap) -> list[tuple[int, int]]:
    """The auxiliary columns: (entry, signal) indices, entry by entry, in signal order."""
    return [(k, j) for k, a in enumerate(cmap.auxiliary) for j in range(len(a.signals))]


def build_aux_slots(db: cantools.database.can.Database, cmap: ChannelMap,
                    taken: set[int] | None = None) -> list[Slot]:
    """Group the auxiliary columns into slots (one per message, source address, channel).

    A slot's ``sensors`` are the column numbers (:func:`aux_columns`); it has no sample
    counter.

    Raises
    ------
    ConfigError
        A message or signal not in the DBC, entries of one message naming different check
        signals, or a message a monitored sensor already uses (``taken``).
    """
    groups: dict[tuple[int, object], list[int]] = {}
    msgs: dict[tuple[int, object], cantools.database.can.Message] = {}
    cols = aux_columns(cmap)
    for c, (k, j) in enumerate(cols):
        a = cmap.auxiliary[k]
        where = f"channel map {cmap.source}: auxiliary {k + 1} ({a.name})"
        msg = _message(db, a.message, where)
        _check_signals(msg, (a.signals[j], a.counter_signal, a.crc_signal, a.status_signal),
                       where)
        key = (_message_key(msg, a.source_address, cmap.j1939), a.channel)
        if taken and key[0] in taken:
            raise ConfigError(f"{where}: message {a.message} also carries monitored sensors; "
                              "an auxiliary channel needs a message of its own")
        groups.setdefault(key, []).append(c)
        msgs[key] = msg
    slots = []
    for (key, ch), idx in groups.items():
        entries = [cmap.auxiliary[cols[c][0]] for c in idx]
        checks = (entries[0].counter_signal, entries[0].crc_signal, entries[0].status_signal)
        for a in entries[1:]:
            if (a.counter_signal, a.crc_signal, a.status_signal) != checks:
                raise ConfigError(f"channel map {cmap.source}: auxiliary channels "
                                  f"{entries[0].name} and {a.name} share message {a.message} "
                                  "but name different counter/CRC/status signals")
        msg = msgs[(key, ch)]
        lay = _checked_layout(msg, checks[1], cmap.source)
        slots.append(Slot(key=key, channel=ch, layout=lay, sensors=tuple(idx),
                          signals=tuple(cmap.auxiliary[cols[c][0]].signals[cols[c][1]]
                                        for c in idx),
                          counter=checks[0], crc=checks[1], sample_counter=None,
                          status=checks[2], message=msg))
    return slots


def sibling_keys(db: cantools.database.can.Database, slots: list[Slot],
                 j1939: bool) -> dict[int, str]:
    """Frame keys of the DBC messages named like a mapped one but for digits."""
    if j1939:
        return {}
    shape = {re.sub(r"\d+", "#", s.message.name) for s in slots}
    used = {s.message.name for s in slots}
    out = {}
    for m in db.messages:
        if m.name not in used and re.sub(r"\d+", "#", m.name) in shape:
            out[_message_key(m, None, False)] = m.name
    return out
