"""The one place the monitor's answers are built, and the one capability table's codes.

A sample's :class:`~fdi.answer.Answer` is made by :func:`make_answer` (the streaming step and
its fallback on an internal error); a block's :class:`~fdi.answer.BlockResult` by
:func:`block_result`, which both block builders end in: :class:`BlockRows`, the block path
of :meth:`fdi.monitor.Monitor.run` (the kernel's output columns and the per-row outputs that
change only at the monitor's stops), and :func:`block_from_answers` (stepped answers: the
row-by-row fallback, the monitoring chain, the live bus).

:func:`block_from_answers` copies every field that :class:`~fdi.answer.BlockResult` and
:class:`~fdi.answer.Answer` share, by name (``dataclasses.fields``), so a field added to both
flows through without an edit here: ``events`` are concatenated in order, ``parity`` is kept
only when asked for, every other field is stacked into an array of shape (N, ...) whose
trailing shape is the answers' value's shape. The dtypes are fixed per kind of value: float64
for real numbers, bool for flags, int64 for integer codes, and :data:`CAPABILITY_DTYPE`
(object) for text such as the capability, as :meth:`fdi.monitor.Monitor.run` returns it.

An empty block (N = 0) has the widths of a block of the same monitor: (0, 3) for the rate
and its sd, (0, n) health, (0, K) statistics and thresholds, (0, max(n − 3, 0)) parity (or
None when not asked for), (0,) for per-sample scalars. A field not listed in
:data:`_EMPTY_WIDTH` is taken as one value per sample (trailing shape ()).

The capability names are :data:`fdi.answer.CAPABILITIES` (the one table, best first); their
integer codes (the compiled kernel's, :mod:`fdi.state`) are the positions in that table:
:data:`CAPABILITY_CODE` and :func:`capability_names` derive from it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np

from fdi.answer import CAPABILITIES, TIME_STATUSES, Answer, BlockResult, Event

__all__ = ["CAPABILITY_CODE", "CAPABILITY_DTYPE", "CAPABILITY_NAMES", "BlockRows",
           "block_from_answers", "block_result", "capability_names", "make_answer"]

CAPABILITY_DTYPE = np.dtype(object)
"""dtype of ``BlockResult.capability`` (Python ``str`` objects, as ``Monitor.run`` gives)."""
CAPABILITY_CODE: dict[str, int] = {c: k for k, c in enumerate(CAPABILITIES)}
"""Capability name → integer code (its position in :data:`fdi.answer.CAPABILITIES`)."""
CAPABILITY_NAMES = np.array(CAPABILITIES, dtype=CAPABILITY_DTYPE)
"""Integer code → capability name, as an array to index with codes."""
_TIME_NAMES = np.array(TIME_STATUSES, dtype=CAPABILITY_DTYPE)
_INF = float("inf")

# trailing shape of an empty block's fields: "n" sensors, "K" scales, "p" parity entries
_EMPTY_WIDTH: dict[str, tuple[Any, ...]] = {
    "omega": (3,), "omega_sd": (3,), "healthy": ("n",), "statistics": ("K",),
    "thresholds": ("K",), "parity": ("p",), "unverified": (3,)}
# dtype of an empty block's fields (a filled block takes it from the values)
_EMPTY_DTYPE: dict[str, Any] = {"healthy": bool, "capability": CAPABILITY_DTYPE,
                                "time_status": CAPABILITY_DTYPE,
                                "unverified": bool, "envelope": np.int64}


def capability_names(codes: np.ndarray) -> np.ndarray:
    """Capability names (:data:`CAPABILITY_DTYPE`) of integer codes, same shape."""
    return CAPABILITY_NAMES[np.asarray(codes, dtype=np.intp)]


def _dtype_of(values: Sequence[Any]) -> Any:
    """The block dtype of a field whose per-sample values are ``values`` (non-empty)."""
    v = values[0]
    if isinstance(v, str):
        return CAPABILITY_DTYPE
    a = np.asarray(v)
    if a.dtype.kind == "b":
        return bool
    if a.dtype.kind in "iu":
        return np.int64
    if a.dtype.kind in "US":
        return CAPABILITY_DTYPE
    if a.dtype.kind == "O":
        return CAPABILITY_DTYPE
    return np.float64


def _width(name: str, n: int, K: int) -> tuple[int, ...]:
    dims = {"n": n, "K": K, "p": max(n - 3, 0)}
    return tuple(dims.get(d, d) for d in _EMPTY_WIDTH.get(name, ()))


def _stack(name: str, values: list[Any], n: int, K: int) -> np.ndarray:
    N = len(values)
    if N == 0:
        return np.zeros((0, *_width(name, n, K)), dtype=_EMPTY_DTYPE.get(name, np.float64))
    dt = _dtype_of(values)
    if dt is CAPABILITY_DTYPE:
        out = np.empty(N, dtype=CAPABILITY_DTYPE)
        for k, v in enumerate(values):
            out[k] = v
        return out
    return np.array(values, dtype=dt).reshape(N, *np.shape(values[0]))


def block_from_answers(answers: Sequence[Answer], n: int, K: int,
                       parity: bool = True) -> BlockResult:
    """Stack per-sample answers into a :class:`~fdi.answer.BlockResult`.

    Parameters
    ----------
    answers : sequence of Answer, length N
        In time order.
    n : int
        Sensors of the monitor (the width of ``healthy`` in an empty block).
    K : int
        Statistics per sample (scales, plus the CUSUM bank where there is one).
    parity : bool
        Keep the parity vectors, shape (N, max(n − 3, 0)); None otherwise.

    Returns
    -------
    BlockResult
        Every field shared with :class:`Answer` stacked to (N, ...); events concatenated.
    """
    answers = list(answers)
    have = {f.name for f in dataclasses.fields(Answer)}
    kw: dict[str, Any] = {}
    for f in dataclasses.fields(BlockResult):
        if f.name not in have:
            continue                                 # a block-only field keeps its default
        if f.name == "events":
            kw["events"] = [e for a in answers for e in a.events]
        elif f.name == "parity":
            kw["parity"] = (_stack("parity", [a.parity for a in answers], n, K)
                            if parity else None)
        else:
            kw[f.name] = _stack(f.name, [getattr(a, f.name) for a in answers], n, K)
    return block_result(kw)


def block_result(fields: dict[str, Any]) -> BlockResult:
    """The :class:`~fdi.answer.BlockResult` of its fields by name (a field not given keeps
    its default); the one constructor both block builders end in."""
    return BlockResult(**fields)


def make_answer(fields: dict[str, Any]) -> Answer:
    """The :class:`~fdi.answer.Answer` of every one of its fields by name, without the frozen
    dataclass's per-field ``__setattr__`` calls (a third of the step's Python time once):
    the same object as ``Answer(**fields)``."""
    a = object.__new__(Answer)
    object.__setattr__(a, "__dict__", fields)
    return a


class BlockRows:
    """The block path's per-row outputs that change only at the monitor's stops: health,
    capability, ω̂ sd, envelope, unverified axes and whether the answer is verified.

    Parameters
    ----------
    N : int
        Rows of the block.
    n : int
        Sensors of the monitor.
    """

    def __init__(self, N: int, n: int) -> None:
        self.healthy = np.empty((N, n), bool)
        self.cap = np.empty(N, np.int8)
        self.omega_sd = np.empty((N, 3))
        self.envelope = np.empty(N, np.int64)
        self.unverified = np.empty((N, 3), bool)
        self.verified = np.empty(N, bool)

    def fill(self, r0: int, r1: int, healthy: np.ndarray, capability: str,
             omega_sd: np.ndarray, envelope: int, unverified: np.ndarray,
             verified: bool) -> None:
        """Rows r0 … r1−1 share these outputs."""
        if r1 <= r0:
            return
        _fill_rows(self.healthy, r0, r1, healthy)
        self.cap[r0:r1] = CAPABILITY_CODE[capability]
        _fill_rows(self.omega_sd, r0, r1, omega_sd)
        self.envelope[r0:r1] = envelope
        _fill_rows(self.unverified, r0, r1, unverified)
        self.verified[r0:r1] = verified

    def result(self, t: np.ndarray, omega: np.ndarray, statistics: np.ndarray,
               thresholds: np.ndarray, protection_level: np.ndarray,
               parity: np.ndarray | None, time_codes: np.ndarray,
               events: list[Event]) -> BlockResult:
        """The block's result from the kernel's output columns (views, kept), with an
        infinite protection level where the answer is not verified (as the step gives)."""
        pl = protection_level
        pl[~self.verified] = _INF                    # not verified: no bound (as step)
        return block_result(dict(
            t=t, omega=omega, omega_sd=self.omega_sd, healthy=self.healthy,
            statistics=statistics, thresholds=thresholds, protection_level=pl,
            capability=CAPABILITY_NAMES[self.cap], events=events, parity=parity,
            envelope=self.envelope, unverified=self.unverified,
            time_status=_TIME_NAMES[time_codes.astype(np.intp)]))


def _fill_rows(a: np.ndarray, r0: int, r1: int, row: np.ndarray) -> None:
    """a[r0:r1] = row by doubling contiguous copies (a row-major array with a few columns:
    ~6× faster than numpy's broadcast, which loops over the rows)."""
    a[r0] = row
    k = 1
    while r0 + k < r1:
        m = min(k, r1 - r0 - k)
        a[r0 + k:r0 + k + m] = a[r0:r0 + m]
        k += m
