"""Reading rimu's JSON and TOML files and writing JSON: one place for the loud errors.

Every file rimu writes is an object with ``"schema": "rimu.<name>/<version>"``.
:func:`read_json_object` and :func:`read_toml_object` read one and check that header,
naming the file (and the line for JSON syntax errors); :func:`to_jsonable` turns numpy
values into plain JSON types.

:class:`Fields` is the one field reader every loader uses: a mapping read from a file,
bound to the file's path and a location inside it (``sensors.gyro[2]``, a step number),
with typed getters (:meth:`Fields.number`, :meth:`Fields.integer`, :meth:`Fields.string`,
:meth:`Fields.choice`, :meth:`Fields.boolean`, :meth:`Fields.array`,
:meth:`Fields.numbers`, :meth:`Fields.mapping`, :meth:`Fields.tables`) that raise a
one-line :class:`~fdi.errors.FileFormatError` naming the file, the line where it is known
(TOML files), the step and the field, and what was expected. :meth:`Fields.finish` refuses
every key the loader did not read (a typo such as ``axis_nomnal`` would otherwise switch a
check off silently), suggesting the closest known key.

Every JSON and TOML file goes through :func:`read_json_object` or :func:`read_toml_object`,
which bound what a file may hold before anything else looks at it: at most
:data:`MAX_FILE_BYTES` bytes, nesting at most :data:`MAX_DEPTH` deep, number literals of at
most :data:`MAX_NUMBER_CHARS` characters (a 100 000-deep nesting or a 5000-digit number is
one line naming the file, not a traceback).

:func:`check_numbers` applies a schema's declarative table of :class:`NumberRule` (which
paths must be ``>= 0``, positive, a probability, ...) to every number of a document, after
the conventions every rimu file follows (:data:`CONVENTION_RULES`: ``*_sd`` >= 0, ``*_hz``
> 0, ``*p_value`` in [0, 1], ...); every number not covered by a rule must be finite. The
loader of each schema calls it once, so every command that reads the file refuses the same
values with the same line.
"""

from __future__ import annotations

import difflib
import fnmatch
import functools
import json
import logging
import math
import re
import tomllib
import warnings
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fdi.errors import FileFormatError

__all__ = ["CONVENTION_RULES", "MAX_DEPTH", "MAX_FILE_BYTES", "MAX_NUMBER_CHARS", "REQUIRED",
           "Fields", "NumberRule", "check_numbers", "check_schema", "number_rule",
           "read_json_object", "read_text", "read_toml_object", "to_jsonable",
           "toml_key_line"]

MAX_FILE_BYTES = 256 << 20
"""Largest JSON or TOML file read (256 MiB; rimu's own are kilobytes to a few megabytes)."""
MAX_DEPTH = 64
"""Deepest nesting of objects and arrays in a JSON or TOML file (rimu writes at most ~10)."""
MAX_NUMBER_CHARS = 100
"""Longest number literal in a JSON file (a float needs at most ~25 characters)."""


class _Required:
    """Marker: the field has no default (see :data:`REQUIRED`)."""

    def __repr__(self) -> str:
        return "REQUIRED"


REQUIRED: Any = _Required()
"""Default of every :class:`Fields` getter: the key must be present."""
_DEFAULT: Any = object()
_log = logging.getLogger("rimu.files")


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


def check_schema(doc: Mapping[str, Any], path: str, schema: str | Sequence[str], *,
                 default: str | None = None) -> str:
    """Check ``doc["schema"]`` against ``"rimu.<name>/<version>"``; return the version read.

    Parameters
    ----------
    doc : mapping
    path : str
        The file, for the message.
    schema : str or sequence of str
        The schema this rimu writes, first, then older versions it still reads.
    default : str, optional
        Taken when the document has no ``schema`` (files written by hand where the header
        is optional); without it the header is required.

    Raises
    ------
    FileFormatError
        Field ``schema`` missing, of another file kind, or of an unsupported version.
    """
    known = (schema,) if isinstance(schema, str) else tuple(schema)
    got = doc.get("schema", default)
    if not isinstance(got, str):
        raise FileFormatError(path, f"missing; expected '{known[0]}'", field="schema")
    name, _, _ = got.partition("/")
    if name != known[0].partition("/")[0]:
        raise FileFormatError(path, f"expected '{known[0]}', got {got!r}", field="schema")
    if got not in known:
        reads = " or ".join(f"'{s}'" for s in known)
        raise FileFormatError(path, f"unsupported version {got!r}; this rimu reads {reads}",
                              field="schema")
    return got


def read_json_object(path: str | Path, schema: str | Sequence[str] | None = None, *,
                     hint: str = "") -> dict[str, Any]:
    """Read a JSON object from ``path``; with ``schema``, also check its header.

    Parameters
    ----------
    path : str or Path
    schema : str or sequence of str, optional
        Expected ``"rimu.<name>/<version>"`` (see :func:`check_schema`).
    hint : str
        Appended to the "cannot read" message (e.g. what the directory should hold).

    Raises
    ------
    FileFormatError
        Unreadable file, invalid JSON (with the line), not an object, wrong schema.
    """
    p = str(path)
    try:
        _check_size(path)
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        why = getattr(exc, "strerror", None) or str(exc)
        raise FileFormatError(p, f"cannot read ({why}){hint}") from None
    try:
        doc = json.loads(text, parse_int=_json_number(p, int),
                         parse_float=_json_number(p, float))
    except json.JSONDecodeError as exc:
        raise FileFormatError(p, f"not valid JSON ({exc.msg})", line=exc.lineno) from None
    except RecursionError:
        raise FileFormatError(p, f"nested deeper than {MAX_DEPTH} levels") from None
    _check_depth(doc, p)
    if not isinstance(doc, dict):
        raise FileFormatError(p, "expected a JSON object")
    if schema is not None:
        check_schema(doc, p, schema)
    return doc


def _check_size(path: str | Path) -> None:
    """Refuse a file above :data:`MAX_FILE_BYTES` before reading it (OSError: unreadable)."""
    size = Path(path).stat().st_size
    if size > MAX_FILE_BYTES:
        raise FileFormatError(str(path), f"{size} bytes, more than the {MAX_FILE_BYTES >> 20} "
                              "MiB a rimu JSON or TOML file may hold")


def _json_number(path: str, convert: Any):
    """A ``json.loads`` number hook that refuses a literal above :data:`MAX_NUMBER_CHARS`
    before ``convert`` (int or float) reads it."""
    def parse(text: str) -> Any:
        if len(text) > MAX_NUMBER_CHARS:
            size = (f"{len(text)} digits (at most {MAX_NUMBER_CHARS} characters"
                    if convert is int else f"{len(text)} characters (at most {MAX_NUMBER_CHARS}")
            raise FileFormatError(path, f"a number of {size} per number)")
        return convert(text)
    return parse


def _check_depth(doc: Any, path: str) -> None:
    """Refuse nesting deeper than :data:`MAX_DEPTH` (iteratively: no recursion)."""
    stack = [(doc, 1)]
    while stack:
        v, d = stack.pop()
        if isinstance(v, dict):
            items = v.values()
        elif isinstance(v, list):
            items = v
        else:
            continue
        if d > MAX_DEPTH:
            raise FileFormatError(path, f"nested deeper than {MAX_DEPTH} levels")
        stack.extend((x, d + 1) for x in items if isinstance(x, dict | list))


def read_text(path: str | Path) -> str:
    """The UTF-8 text of ``path``.

    Raises
    ------
    FileFormatError
        The file cannot be read, or is not UTF-8 (naming the byte).
    """
    p = str(path)
    try:
        return Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise FileFormatError(p, f"cannot read ({exc.strerror})") from None
    except UnicodeDecodeError as exc:
        raise FileFormatError(p, f"not UTF-8 text ({exc.reason} at byte {exc.start})") \
            from None


def _read_toml(path: str | Path) -> tuple[dict[str, Any], str]:
    p = str(path)
    try:
        _check_size(path)
    except OSError as exc:
        raise FileFormatError(p, f"cannot read ({exc.strerror})") from None
    text = read_text(path)
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise FileFormatError(p, f"not valid TOML ({exc})") from None
    except RecursionError:
        raise FileFormatError(p, f"nested deeper than {MAX_DEPTH} levels") from None
    _check_depth(doc, p)
    return doc, text


def read_toml_object(path: str | Path, schema: str | Sequence[str] | None = None
                     ) -> dict[str, Any]:
    """Read a TOML document from ``path``; with ``schema``, also check its header.

    Raises
    ------
    FileFormatError
        Unreadable file, not UTF-8, invalid TOML, wrong schema.
    """
    doc, _ = _read_toml(path)
    if schema is not None:
        check_schema(doc, str(path), schema)
    return doc


_HEADER = re.compile(r"^\s*\[(\[)?\s*([A-Za-z0-9_.\-\"' ]+?)\s*\]")
_KEY = re.compile(r"^\s*([A-Za-z0-9_\-]+|\"[^\"]*\"|'[^']*')\s*=")


def toml_key_line(text: str, key: str, table: str | None = None,
                  index: int | None = None) -> int | None:
    """1-based line of ``key = ...`` in a TOML text, or None when it cannot be found.

    Parameters
    ----------
    text : str
        The TOML source.
    key : str
        A bare key.
    table : str, optional
        The ``[table]`` or ``[[array]]`` that holds the key (None: the top level).
    index : int, optional
        1-based element of an ``[[array]]`` table; without ``key`` matches its header.
    """
    current: tuple[str | None, int | None] = (None, None)
    counts: dict[str, int] = {}
    for lineno, line in enumerate(text.splitlines(), start=1):
        h = _HEADER.match(line)
        if h:
            name = h.group(2).strip()
            if h.group(1):
                counts[name] = counts.get(name, 0) + 1
                current = (name, counts[name])
            else:
                current = (name, None)
            if key == "" and current == (table, index):
                return lineno
            continue
        k = _KEY.match(line)
        if k and k.group(1).strip("\"'") == key and current == (table, index):
            return lineno
    return None


def _is_number(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def _shape_text(shape: Sequence[int | None]) -> str:
    return "×".join("n" if s is None else str(s) for s in shape) or "scalar"


class Fields:
    """One object (JSON object, TOML table) of a file, read field by field.

    Every getter takes the key and optional constraints, marks the key as read, and raises
    a one-line :class:`~fdi.errors.FileFormatError` naming the file (and the TOML line), the
    step and the field (``prefix.key``) when the value is missing or wrong. A getter given a
    ``default`` returns it when the key is absent or null (JSON ``null``); without one the
    key is required. :meth:`finish` refuses the keys nobody read.

    Parameters
    ----------
    doc : mapping
        The object. Anything else is refused (naming ``prefix``).
    path : str
        The file, for the messages.
    prefix : str
        Where the object sits in the file (``""`` top level, ``"sensors.gyro[2]"``).
    step : int, optional
        1-based test-sequence step the object belongs to (sessions and sequences name
        fields of a step by their bare key plus the step).
    text : str, optional
        TOML source, to name the line of a field.
    table : tuple of (str, int or None), optional
        The ``[[array]]`` name and element (1-based) of this object in ``text``.
    """

    def __init__(self, doc: Any, path: str | Path, prefix: str = "", *,
                 step: int | None = None, text: str | None = None,
                 table: tuple[str, int | None] | None = None) -> None:
        self.path = str(path)
        self.prefix = prefix
        self.step = step
        self._text = text
        self._table = table
        if not isinstance(doc, Mapping):
            what = "a table" if text is not None else "an object"
            raise FileFormatError(self.path, f"expected {what}, got {_show(doc)}",
                                  line=self._line(""), field=prefix or None, step=step)
        self.doc: Mapping[str, Any] = doc
        self._read: set[str] = set()

    # -- construction -------------------------------------------------------------------
    @classmethod
    def from_json(cls, path: str | Path, schema: str | Sequence[str] | None = None, *,
                  hint: str = "") -> Fields:
        """Read a JSON object file (see :func:`read_json_object`); the schema is read."""
        f = cls(read_json_object(path, schema, hint=hint), path)
        if schema is not None:
            f._read.add("schema")
        return f

    @classmethod
    def from_toml(cls, path: str | Path, schema: str | Sequence[str] | None = None, *,
                  schema_default: str | None = None) -> Fields:
        """Read a TOML file; with ``schema``, check its header (optional when
        ``schema_default`` is given). Errors on fields then name their line."""
        doc, text = _read_toml(path)
        f = cls(doc, path, text=text)
        if schema is not None:
            f.schema(schema, default=schema_default)
        return f

    # -- naming and errors --------------------------------------------------------------
    def name(self, key: str | int) -> str:
        """Field name of ``key`` in the file (``prefix.key``; ``prefix[k]`` for an index)."""
        if isinstance(key, int):
            return f"{self.prefix}[{key}]"
        return f"{self.prefix}.{key}" if self.prefix else key

    def _line(self, key: str) -> int | None:
        if self._text is None:
            return None
        table, index = self._table or (None, None)
        line = toml_key_line(self._text, key, table, index) if key else None
        if line is None and table is not None:
            line = toml_key_line(self._text, "", table, index)
        return line

    def error(self, key: str | None, message: str) -> FileFormatError:
        """The error for field ``key`` (None: this object as a whole)."""
        field = self.name(key) if key is not None else (self.prefix or None)
        return FileFormatError(self.path, message, line=self._line(key or ""), field=field,
                               step=self.step)

    def with_step(self, step: int) -> Fields:
        """The same object, its fields named by bare key and ``step`` (read keys shared)."""
        f = Fields.__new__(Fields)
        f.__dict__.update(self.__dict__)
        f.prefix, f.step = "", step
        return f

    # -- raw access ---------------------------------------------------------------------
    def __contains__(self, key: str) -> bool:
        return key in self.doc and self.doc[key] is not None

    def keys(self) -> list[str]:
        """Keys of the object, in file order."""
        return [str(k) for k in self.doc]

    def get(self, key: str, default: Any = REQUIRED) -> Any:
        """The raw value (any type); ``default`` when absent or null."""
        v = self._fetch(key, default)
        return default if v is _DEFAULT else v

    def _fetch(self, key: str, default: Any) -> Any:
        self._read.add(key)
        if key not in self.doc:
            if default is REQUIRED:
                raise self.error(key, "missing" + self._typo_hint(key))
            return _DEFAULT
        v = self.doc[key]
        return _DEFAULT if v is None and default is not REQUIRED else v

    def _typo_hint(self, key: str) -> str:
        others = [k for k in map(str, self.doc) if k not in self._read]
        close = difflib.get_close_matches(key, others, n=1, cutoff=0.75)
        return f" (the file has '{close[0]}': a typo?)" if close else ""

    def accept(self, *keys: str) -> None:
        """Mark keys as known without reading them (derived values the writer adds)."""
        self._read.update(keys)

    def table_name(self, plural: str) -> str:
        """The key under which the file holds its ``[[<plural>]]`` tables.

        rimu names arrays of tables in the plural (``[[sensors]]``, ``[[steps]]``,
        ``[[faults]]``); the older singular spelling is still read, with a
        :class:`DeprecationWarning` and a logged warning. A file with both is refused.
        """
        old = plural.removesuffix("s")
        if old not in self.doc:
            return plural
        if plural in self.doc:
            raise self.error(old, f"give the [[{plural}]] tables only ([[{old}]] is the old "
                             "spelling of the same thing)")
        msg = (f"{self.path}: [[{old}]] is deprecated; name the tables [[{plural}]] (as in "
               "every rimu file)")
        warnings.warn(msg, DeprecationWarning, stacklevel=3)
        _log.warning(msg)
        return old

    def finish(self, *, accept: Iterable[str] = ()) -> None:
        """Refuse every key that no getter read and ``accept`` does not list.

        Raises
        ------
        FileFormatError
            Naming the first unknown key, with the closest known key when there is one.
        """
        known = self._read | set(accept)
        for k in map(str, self.doc):
            if k in known:
                continue
            close = difflib.get_close_matches(k, sorted(known), n=1, cutoff=0.6)
            hint = (f"did you mean '{close[0]}'?" if close else
                    f"expected one of {', '.join(sorted(known))}")
            raise self.error(k, f"unknown key; {hint}")

    # -- typed getters ------------------------------------------------------------------
    def schema(self, schema: str | Sequence[str], *, default: str | None = None) -> str:
        """Check the ``schema`` header (see :func:`check_schema`); return the version read."""
        self._read.add("schema")
        try:
            return check_schema(self.doc, self.path, schema, default=default)
        except FileFormatError as exc:
            raise self.error("schema", exc.detail) from None

    def number(self, key: str, default: Any = REQUIRED, *, positive: bool = False,
               nonnegative: bool = False, lo: float | None = None, hi: float | None = None,
               finite: bool = True) -> Any:
        """A number (int or float, not bool) as float.

        ``positive`` (> 0), ``nonnegative`` (≥ 0), ``lo``/``hi`` (inclusive bounds) and
        ``finite`` (default) constrain it; the default is returned as given.
        """
        v = self._fetch(key, default)
        if v is _DEFAULT:
            return default
        return self._check_number(v, key, positive=positive, nonnegative=nonnegative,
                                  lo=lo, hi=hi, finite=finite)

    def _check_number(self, v: Any, key: str, *, positive: bool = False,
                      nonnegative: bool = False, lo: float | None = None,
                      hi: float | None = None, finite: bool = True) -> float:
        if not _is_number(v):
            raise self.error(key, f"expected a number, got {_show(v)}")
        try:
            x = float(v)
        except OverflowError:
            raise self.error(key, f"expected a number in floating-point range, got {v}") \
                from None
        if finite and not math.isfinite(x):
            raise self.error(key, f"expected a finite number, got {_show(v)}")
        if positive and not x > 0:
            raise self.error(key, f"expected a positive number, got {_show(v)}")
        if nonnegative and not x >= 0:
            raise self.error(key, f"expected a number >= 0, got {_show(v)}")
        if (lo is not None and not x >= lo) or (hi is not None and not x <= hi):
            rng = (f"in [{lo:g}, {hi:g}]" if lo is not None and hi is not None else
                   f">= {lo:g}" if lo is not None else f"<= {hi:g}")
            raise self.error(key, f"expected a number {rng}, got {_show(v)}")
        return x

    def integer(self, key: str, default: Any = REQUIRED, *, lo: int | None = None,
                hi: int | None = None) -> Any:
        """An integer (a float with an integral value is refused: files say what they mean)."""
        v = self._fetch(key, default)
        if v is _DEFAULT:
            return default
        if isinstance(v, bool) or not isinstance(v, int):
            raise self.error(key, f"expected an integer, got {_show(v)}")
        if (lo is not None and v < lo) or (hi is not None and v > hi):
            rng = (f"{lo}..{hi}" if lo is not None and hi is not None else
                   f">= {lo}" if lo is not None else f"<= {hi}")
            raise self.error(key, f"expected an integer {rng}, got {v}")
        return v

    def string(self, key: str, default: Any = REQUIRED, *, nonempty: bool = True) -> Any:
        """A string (non-empty unless ``nonempty=False``)."""
        v = self._fetch(key, default)
        if v is _DEFAULT:
            return default
        if not isinstance(v, str) or (nonempty and not v.strip()):
            what = "a non-empty string" if nonempty else "a string"
            raise self.error(key, f"expected {what}, got {_show(v)}")
        return v

    def choice(self, key: str, options: Iterable[str], default: Any = REQUIRED) -> Any:
        """One string of ``options``."""
        opts = list(options)
        v = self._fetch(key, default)
        if v is _DEFAULT:
            return default
        if not isinstance(v, str) or v not in opts:
            close = difflib.get_close_matches(str(v), opts, n=1, cutoff=0.6)
            hint = f"; did you mean '{close[0]}'?" if close else ""
            raise self.error(key, f"expected one of {', '.join(map(repr, opts))}, got "
                             f"{_show(v)}{hint}")
        return v

    def boolean(self, key: str, default: Any = REQUIRED) -> Any:
        """true or false."""
        v = self._fetch(key, default)
        if v is _DEFAULT:
            return default
        if not isinstance(v, bool):
            raise self.error(key, f"expected true or false, got {_show(v)}")
        return v

    def array(self, key: str, shape: Sequence[int | None], default: Any = REQUIRED, *,
              finite: bool = True) -> Any:
        """A nested list of numbers as a float array of ``shape`` (None: any length)."""
        v = self._fetch(key, default)
        if v is _DEFAULT:
            return default
        if isinstance(v, bool | str):
            raise self.error(key, f"expected an array of numbers, got {_show(v)}")
        try:
            a = np.array(v, dtype=float)
        except (TypeError, ValueError, OverflowError):
            raise self.error(key, "expected an array of numbers") from None
        if a.ndim != len(shape) or any(s is not None and s != d
                                       for s, d in zip(shape, a.shape, strict=True)):
            got = "×".join(map(str, a.shape)) or "scalar"
            raise self.error(key, f"expected shape {_shape_text(shape)}, got {got}")
        if finite and not np.all(np.isfinite(a)):
            raise self.error(key, "expected finite numbers, found a non-finite value")
        return a

    def numbers(self, key: str, default: Any = REQUIRED, *, length: int | None = None,
                positive: bool = False) -> Any:
        """A non-empty list of finite numbers as a tuple of float; items named ``key[k]``."""
        v = self._fetch(key, default)
        if v is _DEFAULT:
            return default
        if not isinstance(v, list) or not v:
            raise self.error(key, f"expected a non-empty list of numbers, got {_show(v)}")
        if length is not None and len(v) != length:
            raise self.error(key, f"expected {length} entries, got {len(v)}")
        return tuple(self._check_number(x, f"{key}[{j}]", positive=positive)
                     for j, x in enumerate(v, start=1))

    def mapping(self, key: str, default: Any = REQUIRED) -> Any:
        """A nested object as a :class:`Fields` named ``prefix.key`` (a mapping default is
        wrapped too)."""
        v = self._fetch(key, default)
        if v is _DEFAULT:
            if not isinstance(default, Mapping):
                return default
            v = default
        table = (key, None) if self._table is None and self._text is not None else None
        return Fields(v, self.path, self.name(key), step=self.step, text=self._text,
                      table=table)

    def free(self, key: str, default: Any = REQUIRED) -> Any:
        """A free-form object (``meta``, ``extra``: any keys) as a dict."""
        v = self._fetch(key, default)
        if v is _DEFAULT:
            return default
        if not isinstance(v, Mapping):
            raise self.error(key, f"expected an object, got {_show(v)}")
        return dict(v)

    def tables(self, key: str, default: Any = REQUIRED, *, nonempty: bool = True
               ) -> Any:
        """A list of objects (``[[key]]`` tables) as :class:`Fields` named ``key[k]``."""
        v = self._fetch(key, default)
        if v is _DEFAULT:
            return default
        if not isinstance(v, list) or (nonempty and not v):
            what = "one or more" if nonempty else "a list of"
            raise self.error(key, f"expected {what} [[{key}]] tables"
                             if self._text is not None else
                             f"expected {'a non-empty' if nonempty else 'a'} list of objects")
        top = self._text is not None and self._table is None
        return [Fields(e, self.path, f"{self.name(key)}[{k}]", step=self.step,
                       text=self._text, table=(key, k) if top else None)
                for k, e in enumerate(v, start=1)]


def _show(v: Any) -> str:
    """A value for a message: short, and plain Python for numpy scalars."""
    if isinstance(v, np.generic):
        v = v.item()
    s = repr(v)
    return s if len(s) <= 60 else s[:57] + "..."


# -- numbers: finiteness and range of every numeric field, by declarative rules -------------
@dataclass(frozen=True)
class NumberRule:
    """The range of the numbers at the paths a pattern matches.

    Parameters
    ----------
    pattern : str
        An :mod:`fnmatch` pattern over the field's path without indices, its keys joined
        by dots (``sensors.gyro.bias_sd`` for ``sensors.gyro[2].bias_sd``; ``*`` matches
        any run, dots included: ``*_sd`` is every standard deviation).
    lo, hi : float, optional
        Inclusive bounds (None: unbounded on that side).
    lo_open : bool
        Exclude ``lo`` itself (``> 0``).
    finite : bool
        False lets ``inf`` and ``nan`` pass (a field where they mean something).
    diagonal : bool
        Apply only where the last two indices are equal (a covariance's variances); the
        other entries fall through to the next rule.
    what : str
        How the message names the expected value (``"a standard deviation"``).
    """

    pattern: str
    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    finite: bool = True
    diagonal: bool = False
    what: str = ""

    def expected(self) -> str:
        """What the rule accepts, for a message."""
        if self.lo is not None and self.hi is not None:
            rng = f"in {'(' if self.lo_open else '['}{self.lo:g}, {self.hi:g}]"
        elif self.lo is not None:
            rng = f"{'>' if self.lo_open else '>='} {self.lo:g}"
        elif self.hi is not None:
            rng = f"<= {self.hi:g}"
        else:
            rng = ""
        text = " ".join(x for x in ("finite" if self.finite else "", "number", rng) if x)
        return f"{self.what} ({text})" if self.what else f"a {text}"

    def accepts(self, x: float) -> bool:
        """Whether the value ``x`` passes."""
        if math.isnan(x):
            return not self.finite
        if math.isinf(x) and self.finite:
            return False
        if self.lo is not None and (x < self.lo or (self.lo_open and x == self.lo)):
            return False
        return self.hi is None or x <= self.hi


_SD = "a standard deviation"
_P = "a probability"
CONVENTION_RULES: tuple[NumberRule, ...] = (
    NumberRule("*log10_p*", hi=0.0, what="a log10 probability"),
    NumberRule("*_sd", 0.0, what=_SD),
    NumberRule("*.sd_*", 0.0, what=_SD),
    NumberRule("*_sd_*", 0.0, what=_SD),
    NumberRule("*.sd", 0.0, what=_SD),
    NumberRule("*_rms", 0.0, what="an RMS"),
    NumberRule("*_rms_*", 0.0, what="an RMS"),
    NumberRule("*_hz", 0.0, lo_open=True, what="a rate"),
    NumberRule("*p_value", 0.0, 1.0, what=_P),
    NumberRule("*_p", 0.0, 1.0, what=_P),
    NumberRule("*.alpha", 0.0, 1.0, what=_P),
    NumberRule("*.level", 0.0, 1.0, what=_P),
    NumberRule("*.confidence", 0.0, 1.0, what=_P),
    NumberRule("*probability*", 0.0, 1.0, what=_P),
    NumberRule("*chi2*", 0.0, what="a chi-square statistic"),
    NumberRule("*.tau_s", 0.0, lo_open=True, what="an averaging time"),
    NumberRule("*.adev", 0.0, what="an Allan deviation"),
    NumberRule("*jitter*", 0.0, what="a timing jitter"),
    NumberRule("*cov", 0.0, diagonal=True, what="a variance"),
    NumberRule("*covariance.*", 0.0, diagonal=True, what="a variance"),
    NumberRule("*.variance*", 0.0, what="a variance"),
    NumberRule("*.samples*", 0.0, what="a count"),
    NumberRule("*count*", 0.0, what="a count"),
    NumberRule("*.windows", 0.0, what="a count"),
    NumberRule("*.independent", 0.0, what="a count"),
    NumberRule("*.dof", 0.0, what="a count"),
    NumberRule("*.df", 0.0, what="a count"),
    NumberRule("*.rank", 0.0, what="a count"),
    NumberRule("*_used", 0.0, what="a count"),
    NumberRule("*_max", 0.0, what="a largest magnitude"),
    NumberRule("*_abs_max", 0.0, what="a largest magnitude"),
    NumberRule("*duration*", 0.0, what="a duration"),
    NumberRule("*span_s", 0.0, what="a duration"),
    NumberRule("*block_s", 0.0, lo_open=True, what="a duration"),
    NumberRule("*condition*", 0.0, what="a condition number"),
    NumberRule("*ratio*", 0.0, what="a ratio"),
    NumberRule("*autocorrelation*", -1.0, 1.0, what="a correlation"),
    NumberRule("*excess_kurtosis", -2.0, what="an excess kurtosis"),
)
"""Ranges that follow from a field's name in every rimu file (standard deviations, rates,
probabilities, counts, ...); a schema's own table comes first and may override them."""


def _leaves(doc: Any) -> Iterator[tuple[tuple[str | int, ...], Any]]:
    """(path, value) of every number in a parsed JSON/TOML document (iteratively)."""
    stack: list[tuple[tuple[str | int, ...], Any]] = [((), doc)]
    while stack:
        path, v = stack.pop()
        if isinstance(v, Mapping):
            stack.extend(((*path, str(k)), x) for k, x in reversed(list(v.items())))
        elif isinstance(v, list | tuple):
            stack.extend(((*path, j), x) for j, x in reversed(list(enumerate(v))))
        elif _is_number(v):
            yield path, v


def _path_name(path: tuple[str | int, ...]) -> str:
    """``sensors.gyro[2].bias_sd`` (indices 1-based, as every rimu message counts)."""
    out = ""
    for k in path:
        out += f"[{k + 1}]" if isinstance(k, int) else (f".{k}" if out else k)
    return out


def _match(keys: str, pattern: str) -> bool:
    """``fnmatch`` of a dotted path; ``*.key`` also matches ``key`` at the top level."""
    return fnmatch.fnmatchcase(keys, pattern) or (
        pattern.startswith("*.") and fnmatch.fnmatchcase(keys, pattern[2:]))


def check_numbers(doc: Any, path: str | Path, rules: Sequence[NumberRule] = (), *,
                  skip: Sequence[str] = ()) -> None:
    """Check every number of ``doc`` against ``rules``, then :data:`CONVENTION_RULES`.

    The first rule whose pattern matches a field's path decides; a number that no rule
    matches must be finite. Integers too large for a float are refused.

    Parameters
    ----------
    doc : mapping or list
        The parsed file.
    path : str or Path
        The file, for the message.
    rules : sequence of NumberRule
        The schema's table.
    skip : sequence of str
        Patterns of paths left to the schema's own reader (free-form values it checks).

    Raises
    ------
    FileFormatError
        Naming the file, the field (``sensors.gyro[2].bias_sd``), what was expected and
        what the file holds.
    """
    table = tuple(rules)
    seen: dict[tuple[str, bool], Any] = {}
    for where, v in _leaves(doc):
        keys = ".".join(k for k in where if isinstance(k, str))
        if any(_match(keys, pat) for pat in skip):
            continue
        try:
            x = float(v)
        except OverflowError:
            raise FileFormatError(str(path), f"expected a number in floating-point range, got "
                                  f"an integer of {len(str(v))} digits",
                                  field=_path_name(where)) from None
        idx = [k for k in where if isinstance(k, int)]
        diag = len(idx) >= 2 and idx[-1] == idx[-2]
        rule = seen.get((keys, diag), _DEFAULT)
        if rule is _DEFAULT:
            rule = seen[keys, diag] = _rule(keys, table, diag)
        if rule is None:
            if math.isfinite(x):
                continue
            rule = NumberRule("*")
        if not rule.accepts(x):
            raise FileFormatError(str(path), f"expected {rule.expected()}, got {_show(v)}",
                                  field=_path_name(where))


def number_rule(keys: str, rules: Sequence[NumberRule] = (),
                indices: Sequence[int] = ()) -> NumberRule | None:
    """The rule :func:`check_numbers` applies to a field (None: only finite).

    Parameters
    ----------
    keys : str
        The field's keys joined by dots, without indices (``sensors.gyro.bias_sd``).
    rules : sequence of NumberRule
        The schema's table (:data:`CONVENTION_RULES` follow it).
    indices : sequence of int
        The field's indices (0-based; only a ``diagonal`` rule looks at them).
    """
    idx = list(indices)
    return _rule(keys, tuple(rules), len(idx) >= 2 and idx[-1] == idx[-2])


@functools.lru_cache(maxsize=4096)
def _rule(keys: str, rules: tuple[NumberRule, ...], diagonal: bool) -> NumberRule | None:
    return next((r for r in (*rules, *CONVENTION_RULES) if _match(keys, r.pattern)
                 and (not r.diagonal or diagonal)), None)
