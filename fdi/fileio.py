"""Reading rimu's JSON and TOML files and writing JSON: one place for the loud errors.

Every file rimu writes is an object with ``"schema": "rimu.<name>/<version>"``.
:func:`read_json_object` and :func:`read_toml_object` read one and check that header,
naming the file (and the line for JSON syntax errors); :func:`to_jsonable` turns numpy
values into plain JSON types.
"""

from __future__ import annotations

import json
import math
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from fdi.errors import FileFormatError

__all__ = ["check_schema", "read_json_object", "read_toml_object", "to_jsonable"]


def to_jsonable(obj: Any) -> Any:
    """Numpy arrays and scalars, tuples and mappings to plain JSON types; NaN/inf to null."""
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return to_jsonable(obj.item())
    if isinstance(obj, Mapping):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def check_schema(doc: Mapping[str, Any], path: str, schema: str) -> None:
    """Check ``doc["schema"]`` against ``"rimu.<name>/<version>"``.

    Raises
    ------
    FileFormatError
        Field ``schema`` missing, of another file kind, or of an unsupported version.
    """
    got = doc.get("schema")
    if not isinstance(got, str):
        raise FileFormatError(path, f"missing; expected '{schema}'", field="schema")
    name, _, _ = got.partition("/")
    if name != schema.partition("/")[0]:
        raise FileFormatError(path, f"expected '{schema}', got {got!r}", field="schema")
    if got != schema:
        raise FileFormatError(path, f"unsupported version {got!r}; this rimu reads "
                              f"'{schema}'", field="schema")


def read_json_object(path: str | Path, schema: str | None = None, *,
                     hint: str = "") -> dict[str, Any]:
    """Read a JSON object from ``path``; with ``schema``, also check its header.

    Parameters
    ----------
    path : str or Path
    schema : str, optional
        Expected ``"rimu.<name>/<version>"``.
    hint : str
        Appended to the "cannot read" message (e.g. what the directory should hold).

    Raises
    ------
    FileFormatError
        Unreadable file, invalid JSON (with the line), not an object, wrong schema.
    """
    p = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        why = getattr(exc, "strerror", None) or str(exc)
        raise FileFormatError(p, f"cannot read ({why}){hint}") from None
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise FileFormatError(p, f"not valid JSON ({exc.msg})", line=exc.lineno) from None
    if not isinstance(doc, dict):
        raise FileFormatError(p, "expected a JSON object")
    if schema is not None:
        check_schema(doc, p, schema)
    return doc


def read_toml_object(path: str | Path, schema: str | None = None) -> dict[str, Any]:
    """Read a TOML document from ``path``; with ``schema``, also check its header.

    Raises
    ------
    FileFormatError
        Unreadable file, not UTF-8, invalid TOML, wrong schema.
    """
    p = str(path)
    try:
        doc = tomllib.loads(Path(path).read_text(encoding="utf-8"))
    except OSError as exc:
        raise FileFormatError(p, f"cannot read ({exc.strerror})") from None
    except UnicodeDecodeError as exc:
        raise FileFormatError(p, f"not UTF-8 text ({exc.reason} at byte {exc.start})") \
            from None
    except tomllib.TOMLDecodeError as exc:
        raise FileFormatError(p, f"not valid TOML ({exc})") from None
    if schema is not None:
        check_schema(doc, p, schema)
    return doc
