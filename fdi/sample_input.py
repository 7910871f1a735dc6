"""What the streaming monitor is handed, read into the kernel's rows; never raises.

:class:`SampleReader` turns one sample (raw outputs, valid flags, run-time correction) of
any type into the (1, n) float64 and bool rows the compiled kernel reads
(:func:`fdi.kernel.advance`), quickly for C-contiguous float64 arrays, and names a sample of
the wrong length once per run of them (a ``health`` event ``"length"``). :func:`env_code`
and :func:`envelope_runs` read operating-envelope codes, one per sample or per block.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from fdi.answer import Event

__all__ = ["ENV_LIMIT", "SampleReader", "env_code", "envelope_runs", "to_float"]

_NAN = float("nan")
_F64 = np.dtype(np.float64)
_BOOL = np.dtype(bool)

ENV_LIMIT = 1 << 16
"""Envelope codes are bit sets below 2^16; anything else counts as 0 (inside)."""


class SampleReader:
    """Reads samples of n sensors into the kernel's rows.

    Parameters
    ----------
    n : int
        Sensors per sample.

    Attributes
    ----------
    all_valid : ndarray of bool, shape (1, n)
        Every sensor delivered (the row when no flags are given; compared by identity).
    no_correction : ndarray, shape (1, n)
        Zeros (the row when no usable correction is given).
    length_bad : bool
        The last sample read had the wrong length (its event was given).
    """

    def __init__(self, n: int) -> None:
        self.n = n
        self.all_valid = np.ones((1, n), bool)
        self.no_correction = np.zeros((1, n))
        self.length_bad = False
        self._shape1 = (n,)

    def read(self, raw: Any, valid: Any, correction: Any, t: float
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[Event] | None]:
        """One sample as (1, n) raw, valid and correction rows, and the events of reading
        it (None: none); C-contiguous float64 and bool arrays of shape (n,) go quickly."""
        if (type(raw) is np.ndarray and raw.dtype is _F64 and raw.shape == self._shape1
                and raw.flags.c_contiguous):
            self.length_bad = False
            corr = self.no_correction if correction is None else self._plain(correction, _F64)
            ok = self.all_valid if valid is None else self._plain(valid, _BOOL)
            if corr is not None and ok is not None:
                return raw[None], ok, corr, None
        events: list[Event] = []
        u, ok = self.parse(raw, valid, t, events)
        return u, ok, self.correction(correction, 1), events

    def _plain(self, a: Any, dtype: np.dtype) -> np.ndarray | None:
        """A C-contiguous (n,) array of ``dtype`` as a (1, n) row; None for anything else
        (the general path then reads it)."""
        if (type(a) is np.ndarray and a.dtype is dtype and a.shape == self._shape1
                and a.flags.c_contiguous):
            return a[None]
        return None

    def parse(self, raw: Any, valid: Any, t: float, events: list[Event]
              ) -> tuple[np.ndarray, np.ndarray]:
        """One sample as a (1, n) float64 row and a (1, n) bool row; never raises."""
        n = self.n
        if (valid is None and type(raw) is np.ndarray and raw.dtype is _F64
                and raw.shape == (n,) and raw.flags.c_contiguous):
            self.length_bad = False                          # the common case, quickly
            return raw.reshape(1, n), self.all_valid
        vals = self._values(raw)
        ok = self.all_valid if valid is None else self._valid(valid)
        if vals is None or ok is None:
            if not self.length_bad:
                events.append(Event(t, None, "health", "length"))
            self.length_bad = True
            return np.full((1, n), _NAN), np.zeros((1, n), bool)
        self.length_bad = False
        return vals, ok

    def _values(self, raw: Any) -> np.ndarray | None:
        """Raw values as a (1, n) float64 row (NaN for what is not a real number), None when
        there are not n of them."""
        n = self.n
        try:
            if type(raw) is np.ndarray and raw.shape == (n,) and raw.dtype.kind == "f":
                return np.ascontiguousarray(raw, np.float64).reshape(1, n)
            seq = list(raw)
        except Exception:
            return None
        if len(seq) != n:
            return None
        return np.array([to_float(x) for x in seq], np.float64).reshape(1, n)

    def _valid(self, valid: Any) -> np.ndarray | None:
        """The valid flags as a (1, n) bool row, None when there are not n of them."""
        n = self.n
        try:
            if type(valid) is np.ndarray and valid.shape == (n,):
                return np.ascontiguousarray(valid.astype(bool, copy=False)).reshape(1, n)
            ok = [bool(v) for v in valid]
        except Exception:
            return None
        return np.array(ok, bool).reshape(1, n) if len(ok) == n else None

    def correction(self, correction: Any, N: int) -> np.ndarray:
        """The correction as a C-contiguous float array of shape (N, n) or (1, n); zeros when
        absent or not of a usable shape."""
        if correction is None:
            return self.no_correction
        try:
            c = np.asarray(correction, dtype=np.float64)
        except (TypeError, ValueError):
            return self.no_correction
        if c.shape == (self.n,):
            return np.ascontiguousarray(c).reshape(1, self.n)
        if c.ndim == 2 and c.shape[1] == self.n and c.shape[0] in (1, N):
            return np.ascontiguousarray(c)
        return self.no_correction


def env_code(x: Any) -> int:
    """An envelope code as an int in [0, 2^16); 0 for anything else (never raises)."""
    if type(x) is int:
        return x if 0 < x < ENV_LIMIT else 0
    try:
        v = int(x)
    except Exception:
        return 0
    return v if 0 < v < ENV_LIMIT and v == x else 0


def to_float(x: Any) -> float:
    """A raw value as float; NaN for what is not a real number."""
    if isinstance(x, complex):
        return _NAN
    try:
        return float(x)
    except (TypeError, ValueError, OverflowError):
        return _NAN


def envelope_runs(envelope: Any, N: int, current: int) -> list[tuple[int, int, int]]:
    """(r0, r1, code) runs of equal envelope code over N rows; one run at ``current`` when
    there is no usable envelope (None, another shape, not integers)."""
    if envelope is None or N == 0:
        return [(0, N, current)] if N else []
    try:
        e = np.asarray(envelope)
        if e.shape != (N,) or e.dtype.kind not in "iub":
            return [(0, N, current)]
        e = e.astype(np.int64)
        e = np.where((e > 0) & (e < ENV_LIMIT), e, 0)
    except (TypeError, ValueError):
        return [(0, N, current)]
    cut = np.flatnonzero(np.diff(e)) + 1
    starts = np.concatenate([[0], cut])
    ends = np.concatenate([cut, [N]])
    return [(int(a), int(b), int(e[a])) for a, b in zip(starts, ends, strict=True)]
