"""Tables of samples: CSV (numpy), MATLAB ``.mat`` (scipy.io), R ``.rda`` (rdata).

Each file becomes a table of named columns; a ``rimu.ingest-map/1`` map
(:mod:`replay.ingest.ingest_map`) says which columns are which IMU's gyro, accelerometer,
temperature and time, and in what unit. Without a map:

- a CSV whose header follows rimu's naming (``time_ms`` / ``time_s`` / ``time_us``, and
  ``<imu>_gyr_<x|y|z>_<rps|dps>``, ``<imu>_acc_<x|y|z>_<mps2|g>``, ``<imu>_temp_c``) is
  read by that naming;
- a ``.mat`` file is searched for structs with a time field ``t`` (s) and a gyro field
  ``wb``/``gyro``/``gyr``/``omega`` (rad/s) and optionally ``fb``/``accel``/``acc``
  (m/s²): one IMU per struct; the units are *assumed* SI and the report says so;
- an R object holds no units: a map is required.

Damage: a CSV line with the wrong number of cells or a cell that is not a number is
refused, naming its line; ``--salvage`` drops every such line, counts it and keeps the
rows after it (each run of bad lines reported as a damaged stretch); a ``.mat`` or
``.rda`` file that its library cannot read has no usable rows (compressed formats), which
the error says.
"""

from __future__ import annotations

import contextlib
import io
import re
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from fdi.errors import ConfigError, FileFormatError
from fdi.fileio import read_text
from fdi.units import DPS, G0, TIME_UNITS
from replay.ingest.ingest_map import ImuColumns, IngestMap, load_ingest_map
from replay.ingest.stream import Damage, ImuStream, LogRead

__all__ = ["Table", "read_csv_table", "read_mat_table", "read_rda_table", "read_tabular"]

_INDEXED = re.compile(r"^(.*)\[(\d+)\]$")


class Table:
    """Named columns of one file (1-D arrays, or 2-D arrays addressed as ``name[j]``).

    Parameters
    ----------
    path : str
    columns : dict of str to ndarray
    attrs : dict
        File attributes (R ``freq``...).
    damage : Damage or None
    """

    def __init__(self, path: str, columns: dict[str, np.ndarray],
                 attrs: dict[str, Any] | None = None, damage: Damage | None = None) -> None:
        self.path = path
        self.columns = columns
        self.attrs = attrs or {}
        self.damage = damage

    def get(self, name: str, where: str) -> np.ndarray:
        """Column ``name`` (or ``name[j]``) as float; ``where`` names the map field."""
        if name in self.columns:
            return np.asarray(self.columns[name], float)
        m = _INDEXED.match(name)
        if m and m.group(1) in self.columns:
            a = np.asarray(self.columns[m.group(1)], float)
            j = int(m.group(2))
            if a.ndim == 2 and j < a.shape[1]:
                return a[:, j]
            raise FileFormatError(self.path, f"{m.group(1)} has shape {a.shape}; column {j} "
                                             f"does not exist", field=where)
        known = ", ".join(sorted(self.columns)[:12])
        raise FileFormatError(self.path, f"no column {name!r} (the file has {known}"
                                         f"{', ...' if len(self.columns) > 12 else ''})",
                              field=where)


# -- CSV -------------------------------------------------------------------------------
def _non_numbers(lines: list[str], header: list[str],
                 rows: np.ndarray) -> dict[int, tuple[str, str]]:
    """The ``rows`` (0-based in ``lines``) holding a cell that is neither empty, NaN nor a
    number: ``{row: (the first such cell, its column name)}``."""
    out: dict[int, tuple[str, str]] = {}
    for r in rows:
        for c, cell in enumerate(lines[r].split(",")):
            text = cell.strip().lower()
            if text and text not in ("nan", "+nan", "-nan"):
                try:
                    float(text)
                except ValueError:
                    out[int(r)] = (cell.strip(), header[c])
                    break
    return out


def _bad_line_runs(bad: dict[int, str]) -> list[dict[str, Any]]:
    """Consecutive bad data rows (0-based) merged into damaged stretches (file lines)."""
    out: list[dict[str, Any]] = []
    for r in sorted(bad):
        if out and r + 2 == out[-1]["last_line"] + 1:
            out[-1]["last_line"] = r + 2
            out[-1]["lost"]["lines"] += 1
        else:
            out.append({"line": r + 2, "last_line": r + 2, "what": bad[r],
                        "lost": {"lines": 1}})
    return out


def read_csv_table(path: str | Path) -> Table:
    """A CSV file with one header line; empty cells are NaN.

    A line with the wrong number of cells or a cell that is not a number is dropped and
    counted (runs of such lines are the table's damaged stretches, :attr:`Damage.stretches`);
    the rows after it are kept. :attr:`Table.damage` names the first one; ``rows_before``
    in :attr:`Table.attrs` counts the rows before it.
    """
    p = str(path)
    text = read_text(path)
    lines = text.splitlines()
    if not lines or not lines[0].strip():
        raise FileFormatError(p, "empty file: expected a header line", line=1)
    header = [h.strip() for h in lines[0].split(",")]
    ncol = len(header)
    body = lines[1:]
    while body and not body[-1].strip():
        body.pop()
    counts = np.array([ln.count(",") + 1 for ln in body], int)
    bad: dict[int, str] = {int(r): f"{counts[r]} cells, expected {ncol} (truncated or "
                                   f"corrupt line)" for r in np.flatnonzero(counts != ncol)}
    ok_rows = np.flatnonzero(counts == ncol)
    good = [body[r] for r in ok_rows]
    vals = np.zeros((0, ncol))
    if good:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            vals = np.genfromtxt(io.StringIO("\n".join(good)), delimiter=",", dtype=float,
                                 ndmin=2, invalid_raise=False)
        vals = vals.reshape(-1, ncol)
        nan_rows = np.flatnonzero(np.isnan(vals).any(axis=1))
        found = _non_numbers(good, header, nan_rows)
        for r, (cell, column) in found.items():
            bad[int(ok_rows[r])] = f"{cell!r} is not a number (column {column!r})"
        if found:
            keep = np.ones(vals.shape[0], bool)
            keep[list(found)] = False
            vals = vals[keep]
    damage = None
    attrs: dict[str, Any] = {}
    if bad:
        first = min(bad)
        runs = _bad_line_runs(bad)
        damage = Damage(p, bad[first], line=first + 2, stretches=tuple(runs))
        attrs["rows_before"] = first
    cols = {h: vals[:, j] for j, h in enumerate(header)}
    return Table(p, cols, attrs=attrs, damage=damage)


# -- MATLAB ----------------------------------------------------------------------------
def _flatten_mat(prefix: str, v: Any, out: dict[str, np.ndarray]) -> None:
    if isinstance(v, np.ndarray) and v.dtype.names:
        if v.size != 1:
            return
        rec = v.reshape(-1)[0]
        for name in v.dtype.names:
            _flatten_mat(f"{prefix}.{name}", rec[name], out)
    elif isinstance(v, np.ndarray) and v.dtype.kind in "fiub" and v.ndim <= 2:
        a = np.asarray(v, float)
        if a.ndim == 2 and 1 in a.shape:
            a = a.reshape(-1)
        out[prefix] = a


@contextlib.contextmanager
def _whole_file_errors(p: str, what: str, ext: str) -> Iterator[None]:
    """Turn what a whole-file reader library raises into one :class:`FileFormatError`
    (such files are read whole: a damaged one has nothing to salvage)."""
    try:
        yield
    except OSError as exc:
        if exc.errno is not None:
            raise FileFormatError(p, f"cannot read ({exc.strerror})") from None
        raise FileFormatError(p, f"truncated or corrupt {what} ({exc}); a damaged {ext} "
                                 f"has no samples to salvage") from None
    except Exception as exc:
        raise FileFormatError(p, f"not a readable {what} ({type(exc).__name__}: {exc}); a "
                                 f"damaged {ext} has no samples to salvage") from None


def read_mat_table(path: str | Path) -> Table:
    """A MATLAB v4/v5/v7 ``.mat`` file, structs flattened to ``var.field``."""
    import scipy.io

    p = str(path)
    with _whole_file_errors(p, "MATLAB file", ".mat"):   # scipy: ValueError, MatReadError...
        m = scipy.io.loadmat(p)
    cols: dict[str, np.ndarray] = {}
    for k, v in m.items():
        if not k.startswith("__"):
            _flatten_mat(k, v, cols)
    return Table(p, cols)


_MAT_GYRO = ("wb", "gyro", "gyr", "omega")
_MAT_ACCEL = ("fb", "accel", "acc")


def _auto_mat_map(t: Table) -> list[ImuColumns]:
    structs = sorted({k.split(".")[0] for k in t.columns if "." in k})
    imus = []
    for s in structs:
        gy = next((f"{s}.{g}" for g in _MAT_GYRO if f"{s}.{g}" in t.columns), None)
        if f"{s}.t" not in t.columns or gy is None:
            continue
        ac = next((f"{s}.{a}" for a in _MAT_ACCEL if f"{s}.{a}" in t.columns), None)
        imus.append(ImuColumns(f"imu{len(imus) + 1}", (gy,), 1.0, (ac,) if ac else (), 1.0,
                               None, f"{s}.t"))
    if not imus:
        raise FileFormatError(t.path, "no struct with a time field 't' and a gyro field "
                                      f"({', '.join(_MAT_GYRO)}); give --map")
    return imus


# -- R data ----------------------------------------------------------------------------
def _r_attrs(robj: Any) -> dict[str, Any]:
    out: dict[str, Any] = {}
    a = getattr(robj, "attributes", None)
    for _ in range(64):
        if a is None or not getattr(a, "value", None):
            break
        try:
            tag = a.tag.value.value.decode() if a.tag is not None else None
            val = a.value[0].value
            if tag and isinstance(val, np.ndarray) and val.dtype.kind in "fi":
                out[tag] = val.tolist()
        except (AttributeError, IndexError, UnicodeDecodeError):
            pass
        a = a.value[1] if len(a.value) > 1 else None
    return out


def read_rda_table(path: str | Path, obj: str | None = None) -> Table:
    """An R ``.rda``/``.RData`` file: one matrix or data frame object (``obj``, or the only
    one), its column names as the table's; numeric attributes (``freq``) kept."""
    import rdata

    p = str(path)
    # rdata raises ValueError, NotImplementedError, EOFError...
    with _whole_file_errors(p, "R data file", ".rda"), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        parsed = rdata.parser.parse_file(p)
        conv = rdata.conversion.convert(parsed)
    names = list(conv)
    if obj is None:
        if len(names) != 1:
            raise FileFormatError(p, f"holds {len(names)} objects ({', '.join(names)}); name "
                                     f"one with 'object' in the map")
        obj = names[0]
    if obj not in conv:
        raise FileFormatError(p, f"no object {obj!r} (it has {', '.join(names)})",
                              field="object")
    x = conv[obj]
    attrs: dict[str, Any] = {}
    try:
        attrs = _r_attrs(parsed.object.value[names.index(obj)])
    except (AttributeError, IndexError):
        pass
    cols: dict[str, np.ndarray] = {}
    if hasattr(x, "coords") and getattr(x, "ndim", 0) == 2:      # xarray matrix
        dim = x.dims[1]
        labels = [str(v) for v in x.coords[dim].values] if dim in x.coords else \
            [f"V{j + 1}" for j in range(x.shape[1])]
        vals = np.asarray(x.values, float)
        cols = {lab: vals[:, j] for j, lab in enumerate(labels)}
    elif hasattr(x, "columns"):                                  # data frame
        cols = {str(c): np.asarray(x[c], float) for c in x.columns}
    else:
        raise FileFormatError(p, f"object {obj!r} is a {type(x).__name__}; expected a "
                                 f"matrix with column names or a data frame")
    return Table(p, cols, attrs)


# -- CSV naming convention -------------------------------------------------------------
_CSV_COL = re.compile(r"^(imu\d+)_(gyr|acc)_([xyz])_(rps|dps|mps2|g)$")
_CSV_TEMP = re.compile(r"^(imu\d+)_temp_c$")
_CSV_UNIT = {"rps": 1.0, "dps": DPS, "mps2": 1.0, "g": G0}


def _auto_csv_map(t: Table) -> tuple[list[ImuColumns], str, float]:
    tcol = next((c for c in ("time_s", "time_ms", "time_us", "t") if c in t.columns), None)
    found: dict[str, dict[str, Any]] = {}
    for c in t.columns:
        m = _CSV_COL.match(c)
        if m:
            d = found.setdefault(m.group(1), {})
            d[(m.group(2), m.group(3))] = c
            d[m.group(2) + "_unit"] = _CSV_UNIT[m.group(4)]
        m = _CSV_TEMP.match(c)
        if m:
            found.setdefault(m.group(1), {})["temp"] = c
    imus = []
    for name in sorted(found, key=lambda s: int(s[3:])):
        d = found[name]
        if not all(("gyr", a) in d for a in "xyz"):
            continue
        acc = tuple(d[("acc", a)] for a in "xyz") if all(("acc", a) in d for a in "xyz") \
            else ()
        imus.append(ImuColumns(name, tuple(d[("gyr", a)] for a in "xyz"), d["gyr_unit"],
                               acc, d.get("acc_unit", 1.0), d.get("temp")))
    if tcol is None or not imus:
        raise FileFormatError(t.path, "the columns do not follow rimu's naming (time_ms, "
                                      "imu1_gyr_x_rps, ...); give --map")
    unit = {"time_s": "s", "time_ms": "ms", "time_us": "us", "t": "s"}[tcol]
    return imus, tcol, TIME_UNITS[unit]


# -- map → streams ---------------------------------------------------------------------
def _axes(t: Table, names: tuple[str, ...], where: str) -> np.ndarray:
    if len(names) == 1:
        a = t.get(names[0], where)
        if a.ndim != 2 or a.shape[1] != 3:
            raise FileFormatError(t.path, f"{names[0]} has shape {a.shape}; expected (N, 3) "
                                          f"or three column names", field=where)
        return a
    return np.column_stack([t.get(n, f"{where}[{k}]") for k, n in enumerate(names)])


def _streams(t: Table, imus: list[ImuColumns] | tuple[ImuColumns, ...], tcol: str | None,
             tfac: float, rate: float | None, t0: float, notes: tuple[str, ...]
             ) -> list[ImuStream]:
    out = []
    for imu in imus:
        g = _axes(t, imu.gyro, f"{imu.name}.gyro") * imu.gyro_factor
        n = g.shape[0]
        col = imu.time or tcol
        if col is not None:
            ts = t.get(col, f"{imu.name}.time") * tfac
        else:
            ts = t0 + np.arange(n) / float(rate)
        if ts.shape[0] != n:
            raise FileFormatError(t.path, f"{imu.name}: {ts.shape[0]} times for {n} gyro "
                                          f"samples", field=f"{imu.name}.time")
        acc = _axes(t, imu.accel, f"{imu.name}.accel") * imu.accel_factor if imu.accel \
            else None
        temp = t.get(imu.temperature, f"{imu.name}.temperature") if imu.temperature \
            else None
        keep = ~np.all(np.isnan(g), axis=1)
        s = ImuStream(imu.name, ts, g, acc, temp,
                      source=", ".join(imu.gyro), notes=notes)
        if not keep.all():
            s = s.take(keep)
            s = ImuStream(s.name, s.t, s.gyro, s.accel, s.temperature, s.source,
                          notes=(*notes, f"{int((~keep).sum())} rows with no gyro value "
                                         f"(empty cells) left out"))
        out.append(s)
    return out


def read_tabular(path: str | Path, fmt: str, *, map_path: str | Path | None = None,
                 salvage: bool = False) -> LogRead:
    """Read a CSV, ``.mat`` or ``.rda`` file through a map (or the defaults above).

    Raises
    ------
    FileFormatError
        Unreadable file, a column the map names that the file lacks, damage (without
        ``salvage``).
    ConfigError
        The map is for another format.
    """
    mp: IngestMap | None = load_ingest_map(map_path) if map_path is not None else None
    if mp is not None and mp.format is not None and mp.format != fmt:
        raise ConfigError(f"{map_path}: the map is for {mp.format} files, the log is {fmt}")
    p = str(path)
    if fmt == "csv":
        table = read_csv_table(path)
    elif fmt == "mat":
        table = read_mat_table(path)
    elif fmt == "rda":
        table = read_rda_table(path, mp.object if mp is not None else None)
    else:
        raise ConfigError(f"{p}: format {fmt!r} is not a table format")
    notes: tuple[str, ...] = ()
    if mp is not None:
        imus, tcol, tfac, rate, t0 = mp.imus, mp.time_column, mp.time_factor, mp.rate_hz, \
            mp.t0_s
    elif fmt == "csv":
        imus, tcol, tfac = _auto_csv_map(table)
        rate, t0 = None, 0.0
        notes = ("columns and units from rimu's CSV naming (no map)",)
    elif fmt == "mat":
        imus, tcol, tfac, rate, t0 = _auto_mat_map(table), None, 1.0, None, 0.0
        notes = ("no map: units assumed SI (t in s, gyro rad/s, accel m/s^2)",)
    else:
        raise FileFormatError(p, "R data files carry no units; give --map with gyro_unit "
                                 "(and accel_unit, [time] rate_hz)")
    if table.damage is not None:
        n_rows = min((len(v) for v in table.columns.values()), default=0)
        before = int(table.attrs.pop("rows_before", n_rows))
        dmg = Damage(p, table.damage.message, line=table.damage.line,
                     samples_before=before * len(imus), stretches=table.damage.stretches,
                     samples_after=(n_rows - before) * len(imus))
        if not salvage:
            raise dmg.error()
    else:
        dmg = None
    streams = _streams(table, imus, tcol, tfac, rate, t0, notes)
    meta = {"columns": len(table.columns), "attributes": table.attrs}
    return LogRead(p, fmt, tuple(streams), dmg, meta)
