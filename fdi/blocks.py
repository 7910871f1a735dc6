"""Per-sample answers stacked into a block: the one place a :class:`~fdi.answer.BlockResult`
is built from :class:`~fdi.answer.Answer` objects, and the one capability table's codes.

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

from fdi.answer import CAPABILITIES, Answer, BlockResult

__all__ = ["CAPABILITY_CODE", "CAPABILITY_DTYPE", "CAPABILITY_NAMES", "block_from_answers",
           "capability_names"]

CAPABILITY_DTYPE = np.dtype(object)
"""dtype of ``BlockResult.capability`` (Python ``str`` objects, as ``Monitor.run`` gives)."""
CAPABILITY_CODE: dict[str, int] = {c: k for k, c in enumerate(CAPABILITIES)}
"""Capability name → integer code (its position in :data:`fdi.answer.CAPABILITIES`)."""
CAPABILITY_NAMES = np.array(CAPABILITIES, dtype=CAPABILITY_DTYPE)
"""Integer code → capability name, as an array to index with codes."""

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
    return BlockResult(**kw)
