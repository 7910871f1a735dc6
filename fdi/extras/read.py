"""Readers shared by the typed extras: JSON values (or their in-memory form) to Python types,
each naming the bad field through :class:`fdi.fileio.Fields`."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from fdi.fileio import Fields
from fdi.units import MS

__all__ = ["floats", "ints", "matrix", "ms_field", "optional_number", "plain", "strings"]


def plain(obj: Any) -> Any:
    """Numpy arrays and scalars, tuples and mappings to plain Python types (NaN kept), so that
    a record built in memory is checked as its JSON would be."""
    if isinstance(obj, np.ndarray):
        return plain(obj.tolist())
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Mapping):
        return {str(k): plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [plain(v) for v in obj]
    return obj


def ms_field(r: Fields, key: str, default: float | None) -> float | None:
    """A time in ms read as s (null or absent: ``default``, in s)."""
    v = r.number(key, None, finite=False)
    return default if v is None else v * MS



def floats(r: Fields, key: str, default: Any = (), scale: float = 1.0) -> Any:
    """A list of numbers (null: NaN) as a tuple of float times ``scale``."""
    v = r.get(key, None)
    if v is None:
        return default
    if not isinstance(v, list) or any(x is not None and (isinstance(x, bool) or not
                                                         isinstance(x, int | float))
                                      for x in v):
        raise r.error(key, "expected a list of numbers")
    return tuple(float("nan") if x is None else float(x) * scale for x in v)


def ints(r: Fields, key: str) -> tuple[int, ...]:
    """A list of integers as a tuple (absent or null: empty)."""
    v = r.get(key, [])
    if not isinstance(v, list) or any(isinstance(x, bool) or not isinstance(x, int)
                                      for x in v):
        raise r.error(key, "expected a list of integers")
    return tuple(v)


def matrix(r: Fields, key: str) -> tuple[tuple[float, ...], ...]:
    """A list of rows of numbers (null: NaN); ``[]`` gives ``()``."""
    v = r.get(key, [])
    if not isinstance(v, list):
        raise r.error(key, "expected a list of rows of numbers")
    names = [f"{r.name(key)}[{k}]" for k in range(1, len(v) + 1)]
    rows = Fields(dict(zip(names, v, strict=True)), r.path)
    return tuple(floats(rows, k) for k in names)


def strings(r: Fields, key: str) -> tuple[str, ...]:
    """A list of strings as a tuple (absent or null: empty); a bad item is named ``key[k]``."""
    v = r.get(key, [])
    if not isinstance(v, list):
        raise r.error(key, "expected a list of strings")
    bad = next((k for k, w in enumerate(v, start=1) if not isinstance(w, str)), None)
    if bad is not None:
        raise r.error(f"{key}[{bad}]", "expected a string")
    return tuple(v)


def optional_number(r: Fields, key: str) -> float | None:
    """A number, NaN allowed; None when absent or null."""
    return r.number(key, None, finite=False)


