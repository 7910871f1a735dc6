"""Calibration sessions on disk: ``DIR/manifest.json`` + ``DIR/samples.csv`` (``rimu.session/1``).

A session directory holds (a simulated one also ``truth.json``, see :mod:`calibration.truth`)::

    DIR/manifest.json
    {
      "schema": "rimu.session/1",
      "sample_rate_hz": 100.0,
      "latitude_deg": -23.2,
      "gravity_mps2": 9.7877,                 # local gravity; null: normal gravity at latitude
      "configuration": {                      # nominal axes (MB frame), inline
        "gyro":  {"name": "tetrad", "sensor_names": ["g1", ...],
                  "axes": [[x, y, z], ...], "groups": [[1, 2, 3], [4]]},   # 1-based
        "accel": null                          # or the same layout
      },
      "raw_units": {"gyro": "mV", "accel": "LSB"},   # one of fdi.units.RAW_UNITS
      "steps": [{"index": 1, "kind": "rate" | "position", "mount": "x_inner_y_up",
                 "mat_pb": [[...3x3...]], "label": "Table 1 row 1", "pair": 2 | null}, ...],
      "samples": {"file": "samples.csv", "columns": ["t", "step", ...], "rows": 57600},
      "meta": {...}                            # free (sequence, seed, effects, ...)
    }

    DIR/samples.csv   (comma-separated, one header line, one row per sample)
    t,step,inner_deg,outer_deg,inner_rate_dps,outer_rate_dps,gyro.g1,...,accel.x1,...

Optional temperature columns (°C): ``temp_degC`` for the whole set, or ``temp_degC.<name>``
for every gyro (one per gyro, all of them); the session then carries
``Session.temperature_degC`` (shape (N,) or (N, n_g)) and the writer writes them back. A
temperature column must hold finite numbers (NaN is refused naming the file, line and
column); a column that starts with ``temp`` but is neither form is refused too (a typo would
otherwise drop the temperature silently).

``t`` in s, ``step`` the 1-based step number of the sample (a number in the manifest's
steps), table angles in ° and rates in °/s (right-handed, :mod:`calibration.turntable`),
then the raw output of every gyro (``gyro.<name>``) and accelerometer (``accel.<name>``) in
its raw unit. Columns may come in any order; extra columns are ignored. Every value must be
a finite number. Every step of the manifest needs at least :data:`MIN_STEP_SAMPLES` samples;
when the manifest gives ``samples.rows`` the file must hold that many rows (a truncated copy
is an error). To edit samples by hand, drop ``rows`` or update it.

Numbers are written with 17 significant digits: a save/load round trip returns ``t``,
``step`` and the raw outputs bit for bit; the angle and rate columns go through one ° ↔ rad
conversion (within 2 ulp), and save → load → save reproduces the files byte for byte.
Loading parses with numpy's C reader (a 16-step 100 Hz session, 58k rows, in about 0.1 s).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from calibration.session import Session, Step
from calibration.turntable import MOUNTS
from fdi.errors import ConfigError, FileFormatError
from fdi.fileio import Fields, to_jsonable
from fdi.geometry import Configuration
from fdi.units import DEG, DPS, RAW_UNITS

__all__ = ["MIN_STEP_SAMPLES", "SESSION_SCHEMA", "TABLE_COLUMNS", "TEMPERATURE_COLUMN",
           "load_session", "save_session"]

SESSION_SCHEMA = "rimu.session/1"
MIN_STEP_SAMPLES = 10
"""Fewest samples a step may have."""
TABLE_COLUMNS = ("t", "step", "inner_deg", "outer_deg", "inner_rate_dps", "outer_rate_dps")
"""The fixed leading columns of ``samples.csv``."""
_KINDS = ("gyro", "accel")
TEMPERATURE_COLUMN = "temp_degC"
"""Name of the set temperature column; per gyro ``temp_degC.<name>``."""


def _mount_name(session: Session, st: Step) -> str:
    name = (session.meta.get("mounts") or {}).get(str(st.index))
    if name in MOUNTS and np.allclose(MOUNTS[name], st.mat_pb):
        return name
    for k, m in MOUNTS.items():
        if np.allclose(m, st.mat_pb, atol=1e-12):
            return k
    return "custom"


def _config_dict(c: Configuration) -> dict[str, Any]:
    return {"name": c.name, "sensor_names": list(c.sensor_names), "axes": c.H.tolist(),
            "groups": [[i + 1 for i in g] for g in c.groups]}


def _temperature_columns(session: Session) -> tuple[list[str], np.ndarray | None]:
    T = getattr(session, "temperature_degC", None)
    if T is None:
        return [], None
    T = np.asarray(T, float)
    if T.ndim == 1:
        return [TEMPERATURE_COLUMN], T[:, None]
    return [f"{TEMPERATURE_COLUMN}.{n}" for n in session.gyro_config.sensor_names], T


def _columns(session: Session) -> tuple[list[str], list[str]]:
    g = [f"gyro.{n}" for n in session.gyro_config.sensor_names]
    a = ([] if session.accel_config is None or session.raw_accel is None else
         [f"accel.{n}" for n in session.accel_config.sensor_names])
    return g, a


def save_session(session: Session, directory: str | Path) -> Path:
    """Write ``manifest.json`` and ``samples.csv`` into ``directory`` (created if needed).

    Returns
    -------
    Path
        The directory.
    """
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    gcols, acols = _columns(session)
    tcols, temp = _temperature_columns(session)
    columns = [*TABLE_COLUMNS, *gcols, *acols, *tcols]
    manifest = {
        "schema": SESSION_SCHEMA,
        "sample_rate_hz": float(session.sample_rate_hz),
        "latitude_deg": float(session.latitude_deg),
        "gravity_mps2": None if session.gravity is None else float(session.gravity),
        "configuration": {
            "gyro": _config_dict(session.gyro_config),
            "accel": None if not acols else _config_dict(session.accel_config),
        },
        "raw_units": {"gyro": session.gyro_raw_unit,
                      "accel": session.accel_raw_unit if acols else None},
        "steps": [{"index": int(s.index), "kind": s.kind, "mount": _mount_name(session, s),
                   "mat_pb": np.asarray(s.mat_pb, float).tolist(), "label": s.label,
                   "pair": None if s.pair is None else int(s.pair)} for s in session.steps],
        "samples": {"file": "samples.csv", "columns": columns, "rows": int(session.t.size)},
        "meta": to_jsonable(dict(session.meta)),
    }
    (d / "manifest.json").write_text(json.dumps(manifest, indent=1) + "\n", encoding="utf-8")
    parts = [session.t[:, None], session.step[:, None].astype(float),
             np.column_stack([session.inner / DEG, session.outer / DEG,
                              session.inner_rate / DPS, session.outer_rate / DPS]),
             session.raw_gyro]
    if acols:
        parts.append(session.raw_accel)
    if temp is not None:
        parts.append(temp)
    data = np.hstack(parts)
    fmt = ["%.17g", "%d"] + ["%.17g"] * (data.shape[1] - 2)
    np.savetxt(d / "samples.csv", data, fmt=fmt, delimiter=",", header=",".join(columns),
               comments="")
    return d


# -- reading ------------------------------------------------------------------------------
def load_session(directory: str | Path) -> Session:
    """Read and validate a session directory.

    Raises
    ------
    FileFormatError
        Missing file, bad JSON, wrong schema or version, missing, malformed or unknown
        manifest field, unknown raw unit, missing column, non-numeric or non-finite sample,
        a step number not in the manifest, a step with fewer than :data:`MIN_STEP_SAMPLES`
        samples. The message names the file, the line, the step and the field, and what
        was expected.
    """
    d = Path(directory)
    if not d.is_dir():
        raise FileFormatError(str(d), "no such session directory (expected a directory with "
                              "manifest.json and samples.csv)")
    r = Fields.from_json(d / "manifest.json", SESSION_SCHEMA, hint="; a session directory "
                         "holds manifest.json and samples.csv")
    fs = r.number("sample_rate_hz", positive=True)
    lat = r.number("latitude_deg", lo=-90.0, hi=90.0)
    grav = r.number("gravity_mps2", None, positive=True)
    gcfg, acfg = _configurations(r.mapping("configuration"))
    units = _raw_units(r.mapping("raw_units"), acfg is not None)
    steps, mounts = _steps(r.tables("steps"))
    table = _SampleTable.read(d, r.mapping("samples"))
    meta = r.free("meta", {})
    r.finish()
    gcols = [f"gyro.{n}" for n in gcfg.sensor_names]
    acols = [] if acfg is None else [f"accel.{n}" for n in acfg.sensor_names]
    table.require([*TABLE_COLUMNS, *gcols, *acols])
    step_no = table.check(steps)
    temp = table.temperature(gcfg.sensor_names)
    meta["mounts"] = mounts
    return Session(
        gyro_config=gcfg, accel_config=acfg, sample_rate_hz=fs, latitude_deg=lat,
        steps=steps, t=table.column("t").copy(), step=step_no,
        inner=table.column("inner_deg") * DEG, outer=table.column("outer_deg") * DEG,
        inner_rate=table.column("inner_rate_dps") * DPS,
        outer_rate=table.column("outer_rate_dps") * DPS, raw_gyro=table.columns(gcols),
        raw_accel=table.columns(acols) if acols else None, gyro_raw_unit=units["gyro"],
        accel_raw_unit=units.get("accel", "raw"), gravity=grav, source=str(d), meta=meta,
        temperature_degC=temp)


def _configurations(c: Fields) -> tuple[Configuration, Configuration | None]:
    """``configuration.gyro`` and the optional ``configuration.accel``."""
    gcfg = _configuration(c.mapping("gyro"), "gyro")
    acc = c.mapping("accel", None)
    acfg = None if acc is None else _configuration(acc, "accel")
    c.finish()
    return gcfg, acfg


def _configuration(c: Fields, kind: str) -> Configuration:
    H = c.array("axes", (None, 3))
    n = H.shape[0]
    names = c.get("sensor_names", None) or [f"s{i + 1}" for i in range(n)]
    if (not isinstance(names, list) or len(names) != n
            or not all(isinstance(x, str) and x for x in names)):
        raise c.error("sensor_names", f"expected {n} names")
    groups = c.get("groups", None) or [list(range(1, n + 1))]
    try:
        g0 = tuple(tuple(int(i) - 1 for i in g) for g in groups)
    except (TypeError, ValueError, OverflowError):
        raise c.error("groups", "expected lists of 1-based sensor numbers") from None
    name = str(c.get("name", kind))
    c.finish()
    try:
        return Configuration(name, H, tuple(names), g0)
    except ConfigError as exc:
        raise c.error(None, str(exc)) from None


def _raw_units(u: Fields, with_accel: bool) -> dict[str, str]:
    """``raw_units``: one of :data:`fdi.units.RAW_UNITS` per sensor kind present."""
    units = {kind: u.choice(kind, sorted(RAW_UNITS)) for kind in _KINDS
             if kind == "gyro" or with_accel}
    u.finish(accept=_KINDS)
    return units


def _steps(tables: list[Fields]) -> tuple[tuple[Step, ...], dict[str, str]]:
    """The manifest's steps (unique numbers, rotation matrices, pairs within the manifest)
    and their mounting names."""
    steps: list[Step] = []
    mounts: dict[str, str] = {}
    for s in tables:
        idx = s.integer("index", lo=1)
        if str(idx) in mounts:
            raise s.error("index", f"expected a unique step number >= 1, got {idx!r}")
        s = s.with_step(idx)
        steps.append(Step(index=idx, kind=s.choice("kind", ("rate", "position")),
                          mat_pb=_rotation(s), label=str(s.get("label", "")),
                          pair=s.integer("pair", None)))
        mounts[str(idx)] = str(s.get("mount", "custom"))
        s.finish()
    for st, s in zip(steps, tables, strict=True):
        if st.pair is not None and str(st.pair) not in mounts:
            raise s.with_step(st.index).error("pair", f"pair {st.pair} is not a step of "
                                              "this manifest")
    return tuple(steps), mounts


def _rotation(s: Fields) -> np.ndarray:
    try:
        R = s.array("mat_pb", (3, 3))
    except FileFormatError:
        R = None
    if (R is None or not np.allclose(R.T @ R, np.eye(3), atol=1e-6)
            or np.linalg.det(R) < 0):
        raise s.error("mat_pb", "expected a 3×3 rotation matrix (body axes as columns in "
                      "plate coordinates)")
    return R


class _SampleTable:
    """``samples.csv``: the header and the numbers, with errors naming line and column."""

    def __init__(self, csv: Path, cols: list[str], data: np.ndarray, manifest: str) -> None:
        self.csv, self.path, self.cols, self.data = csv, str(csv), cols, data
        self.manifest = manifest
        self.pos = {c: i for i, c in enumerate(cols)}

    @classmethod
    def read(cls, d: Path, samp: Fields) -> _SampleTable:
        """Read the file the ``samples`` object names; check ``samples.rows``."""
        csv = d / samp.string("file")
        rows = samp.get("rows", None)
        samp.finish(accept=("columns",))
        mname = Path(samp.path).name
        cols = cls._header(csv, mname)
        try:
            data = np.loadtxt(csv, delimiter=",", skiprows=1, dtype=float, ndmin=2)
        except ValueError:
            line, j, what = _bad_cell(csv, len(cols), None)
            if j is None:
                raise FileFormatError(str(csv), f"malformed row: {what}", line=line) from None
            raise FileFormatError(str(csv), f"expected a number, got {what!r}", line=line,
                                  field=cols[j]) from None
        if data.shape[1] != len(cols):
            raise FileFormatError(str(csv), f"rows hold {data.shape[1]} values, the header "
                                  f"{len(cols)}", line=2)
        if isinstance(rows, int) and not isinstance(rows, bool) and rows != data.shape[0]:
            raise FileFormatError(str(csv), f"holds {data.shape[0]} sample rows, the manifest "
                                  f"says {rows} (truncated or edited file? see {mname})",
                                  field="samples.rows")
        return cls(csv, cols, data, mname)

    @staticmethod
    def _header(csv: Path, mname: str) -> list[str]:
        try:
            with csv.open(encoding="utf-8") as fh:
                header = fh.readline()
        except OSError as exc:
            raise FileFormatError(str(csv), f"cannot read ({exc.strerror}); {mname} names it "
                                  "as the sample file", field="samples.file") from None
        except UnicodeDecodeError as exc:
            raise FileFormatError(str(csv), f"not UTF-8 text ({exc.reason} at byte "
                                  f"{exc.start})", line=1) from None
        return [c.strip() for c in header.strip().split(",")]

    def require(self, need: list[str]) -> None:
        """Every column of ``need`` present, every value in them finite."""
        for c in need:
            if c not in self.pos:
                raise FileFormatError(self.path, f"missing column; the header must hold "
                                      f"{', '.join(need)} (as {self.manifest} says)", line=1,
                                      field=c)
        bad = ~np.isfinite(self.data[:, [self.pos[c] for c in need]])
        if bad.any():
            r, jj = np.argwhere(bad)[0]
            sc = self.data[r, self.pos["step"]]
            st = int(sc) if np.isfinite(sc) and sc == round(sc) else None
            raise self.error(int(r), f"expected a finite number, got "
                             f"{float(self.data[r, self.pos[need[jj]]])!r}", need[jj], st)

    def error(self, row: int, message: str, column: str, step: int | None = None
              ) -> FileFormatError:
        """The error at data row ``row`` (0-based), naming its line in the file."""
        line, _, _ = _bad_cell(self.csv, len(self.cols), row)
        return FileFormatError(self.path, message, line=line, field=column, step=step)

    def temperature(self, gyro_names: tuple[str, ...]) -> np.ndarray | None:
        """The optional temperature column(s): (N,), (N, n_g) or None (module docstring)."""
        per = [f"{TEMPERATURE_COLUMN}.{n}" for n in gyro_names]
        found = [c for c in self.cols if c.lower().startswith("temp")]
        for c in found:
            if c != TEMPERATURE_COLUMN and c not in per:
                raise FileFormatError(self.path, f"unknown temperature column; expected "
                                      f"{TEMPERATURE_COLUMN} (whole set) or "
                                      f"{TEMPERATURE_COLUMN}.<gyro name> (one per gyro: "
                                      f"{', '.join(per)})", line=1, field=c)
        if TEMPERATURE_COLUMN in self.pos:
            if any(c in self.pos for c in per):
                raise FileFormatError(self.path, "both a set temperature and per-gyro "
                                      "temperatures; expected one or the other", line=1,
                                      field=TEMPERATURE_COLUMN)
            self.require([TEMPERATURE_COLUMN])
            return self.column(TEMPERATURE_COLUMN).copy()
        have = [c for c in per if c in self.pos]
        if not have:
            return None
        if len(have) != len(per):
            missing = [c for c in per if c not in self.pos]
            raise FileFormatError(self.path, "per-gyro temperatures need one column per "
                                  "gyro", line=1, field=missing[0])
        self.require(per)
        return self.columns(per).copy()

    def column(self, name: str) -> np.ndarray:
        return self.data[:, self.pos[name]]

    def columns(self, names: list[str]) -> np.ndarray:
        return self.data[:, [self.pos[c] for c in names]]

    def check(self, steps: tuple[Step, ...]) -> np.ndarray:
        """Step numbers of the manifest, time increasing, enough samples per step;
        returns the step column as integers."""
        step_col = self.column("step")
        steps_arr = np.rint(step_col).astype(np.int64)
        known = np.array(sorted(s.index for s in steps))
        wrong = (steps_arr != step_col) | ~np.isin(steps_arr, known)
        if wrong.any():
            r = int(np.flatnonzero(wrong)[0])
            raise self.error(r, f"step {step_col[r]:g} is not a step of the manifest (steps "
                             f"{known.min()}..{known.max()})", "step")
        t = self.column("t")
        if t.size > 1 and np.any(np.diff(t) <= 0):
            r = int(np.flatnonzero(np.diff(t) <= 0)[0]) + 1
            raise self.error(r, "time must increase from row to row", "t",
                             int(steps_arr[r]))
        counts = np.bincount(steps_arr, minlength=int(known.max()) + 1)
        for st in steps:
            c = int(counts[st.index])
            if c < MIN_STEP_SAMPLES:
                raise FileFormatError(self.path, f"step has {c} samples, expected at least "
                                      f"{MIN_STEP_SAMPLES}", field="step", step=st.index)
        return steps_arr


def _bad_cell(csv: Path, ncols: int, data_row: int | None) -> tuple[int, int | None, str]:
    """Scan the file (error path only): (line, column index or None, text) of the first
    unparseable cell, or of data row ``data_row`` (0-based, blank lines skipped)."""
    with csv.open(encoding="utf-8", errors="replace") as fh:
        next(fh, None)
        r = -1
        for lineno, line in enumerate(fh, start=2):
            s = line.strip()
            if not s or s.startswith("#"):
                continue
            r += 1
            cells = s.split(",")
            if data_row is not None:
                if r == data_row:
                    return lineno, None, s
                continue
            if len(cells) != ncols:
                return lineno, None, f"{len(cells)} values, expected {ncols}"
            for j, c in enumerate(cells):
                try:
                    float(c)
                except ValueError:
                    return lineno, j, c
    return 0, None, ""
