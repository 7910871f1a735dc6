"""The auxiliary hold: auxiliary channels (temperature, specific force) onto sample times.

Auxiliary channels of a channel map (:class:`~replay.channel_map.AuxChannel`: the effect
terms' inputs) are decoded beside the sensors (:class:`~replay.assemble.BlockDecoder`) but
take no part in the assembly. :class:`AuxHold` keeps each auxiliary column's history and
gives every handed over sample the latest value not later than its time (``Samples.aux``,
in °C or m/s²), NaN before the first value and once the latest is older than the entry's
``timeout_s``.
"""

from __future__ import annotations

import numpy as np

from replay.channel_map import ChannelMap
from replay.slots import aux_columns

__all__ = ["AuxHold"]


class AuxHold:
    """Sample-and-hold of the auxiliary columns onto sample times.

    Each column keeps its decoded values (converted to °C or m/s² along the signal's axis)
    with their frame times, in time order; :meth:`at` gives, for each sample time, the latest
    value not later than it, NaN before the first value and when that value is older than
    the column's ``timeout_s`` (stale). A J1939 'not available' value is held as NaN.

    Parameters
    ----------
    cmap : ChannelMap
    keep_s : float
        History kept before the latest sample handed over (:meth:`trim`).
    """

    def __init__(self, cmap: ChannelMap, keep_s: float = 1.0) -> None:
        self.columns = aux_columns(cmap)
        self.m = len(self.columns)
        aux = cmap.auxiliary
        self.timeout_s = np.array([aux[k].timeout_s for k, _ in self.columns], float)
        conv = [aux[k].to_si for k, _ in self.columns]
        self.factor = np.array([f for f, _ in conv], float)
        self.offset = np.array([o for _, o in conv], float)
        self.keep_s = float(max(keep_s, float(self.timeout_s.max()) if self.m else 0.0))
        self._t = [np.zeros(0) for _ in range(self.m)]
        self._v = [np.zeros(0) for _ in range(self.m)]
        self.received = np.zeros(self.m, np.int64)
        """Values received per column (finite or not)."""

    def add(self, col: int, t: np.ndarray, value: np.ndarray) -> None:
        """Append decoded values (decoded unit) of column ``col`` at times ``t`` (ascending,
        not earlier than the column's last)."""
        if t.size == 0:
            return
        v = np.asarray(value, float) * self.factor[col] + self.offset[col]
        self._t[col] = np.concatenate([self._t[col], np.asarray(t, float)])
        self._v[col] = np.concatenate([self._v[col], v])
        self.received[col] += t.size

    def at(self, ts: np.ndarray) -> np.ndarray:
        """Held values at sample times ``ts``, shape (S, m): °C or m/s², NaN where none."""
        ts = np.asarray(ts, float)
        out = np.full((ts.size, self.m), np.nan)
        for c in range(self.m):
            tc = self._t[c]
            if tc.size == 0:
                continue
            k = np.searchsorted(tc, ts, side="right") - 1
            has = k >= 0
            kk = np.where(has, k, 0)
            fresh = has & (ts - tc[kk] <= self.timeout_s[c])
            out[:, c] = np.where(fresh, self._v[c][kk], np.nan)
        return out

    def trim(self, t_done: float) -> None:
        """Forget values older than ``keep_s`` before ``t_done`` (keeping the one held)."""
        for c in range(self.m):
            tc = self._t[c]
            k = int(np.searchsorted(tc, t_done - self.keep_s, side="right")) - 1
            if k > 0:
                self._t[c], self._v[c] = tc[k:], self._v[c][k:]
