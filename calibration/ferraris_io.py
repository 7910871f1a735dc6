"""Reading Ferraris sessions in imucal's formats.

Two layouts, both CSV with a header row and the columns ``gyr_x, gyr_y, gyr_z, acc_x, acc_y,
acc_z`` (raw outputs, any unit; other columns are ignored):

- *annotated*: a ``part`` column names the section of every row (``x_p`` … ``z_rot``; rows
  of other names or empty are not used);
- *with a section list*: a JSON file ``{"x_p": {"start": i, "end": j}, ...}`` of 0-based row
  numbers, ``end`` exclusive (imucal's ``ferraris_regions_from_section_list``).

The sample rate is not in either file: give it.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np

from calibration.ferraris import SECTIONS, FerrarisSession
from fdi.errors import FileFormatError
from fdi.fileio import Fields, read_text

__all__ = ["COLUMNS", "load_ferraris"]

COLUMNS = ("gyr_x", "gyr_y", "gyr_z", "acc_x", "acc_y", "acc_z")
"""Columns a Ferraris CSV must have."""


def _read_csv(path: str) -> tuple[np.ndarray, list[str] | None]:
    """Samples (N, 6) in :data:`COLUMNS` order and the ``part`` labels (or None)."""
    text = read_text(path)          # one line for a binary or unreadable file
    rows = csv.reader(io.StringIO(text, newline=""))
    data, labels = [], []
    try:
        cols, part = _columns(path, [h.strip() for h in next(rows, [])])
        for ln, row in enumerate(rows, start=2):
            if row:
                data.append(_numbers(path, ln, row, cols))
                if part is not None:
                    labels.append(row[part].strip() if part < len(row) else "")
    except csv.Error as e:
        raise FileFormatError(path, f"not a CSV file ({e})", line=rows.line_num) from None
    if not data:
        raise FileFormatError(path, "no samples; expected rows after the header", line=2)
    return np.array(data), (labels if part is not None else None)


def _columns(path: str, header: list[str]) -> tuple[list[int], int | None]:
    """Positions of :data:`COLUMNS` and of ``part`` (None when absent) in the header."""
    missing = [c for c in COLUMNS if c not in header]
    if missing:
        raise FileFormatError(path, f"missing column(s) {', '.join(missing)}; expected a "
                              f"header with {', '.join(COLUMNS)}", line=1, field=missing[0])
    return [header.index(c) for c in COLUMNS], (header.index("part") if "part" in header
                                                 else None)


def _numbers(path: str, line: int, row: list[str], cols: list[int]) -> list[float]:
    """The :data:`COLUMNS` values of one row, or the one-line error naming the field."""
    for c, j in zip(COLUMNS, cols, strict=True):
        if j >= len(row) or not _is_float(row[j]):
            raise FileFormatError(path, "expected a number", line=line, field=c)
    return [float(row[j]) for j in cols]


def _is_float(s: str) -> bool:
    try:
        float(s)
    except ValueError:
        return False
    return True


def _sections_from_list(path: str, n_rows: int) -> dict[str, np.ndarray]:
    f = Fields.from_json(path)
    out = {}
    for name in SECTIONS:
        sec = f.mapping(name)
        start = sec.integer("start", lo=0)
        end = sec.integer("end", lo=start + 1)
        if end > n_rows:
            raise sec.error("end", f"row {end} beyond the {n_rows} samples of the session")
        sec.finish()
        out[name] = np.arange(start, end)
    f.finish(accept=[k for k in f.keys() if k not in SECTIONS])
    return out


def _sections_from_labels(path: str, labels: list[str]) -> dict[str, np.ndarray]:
    lab = np.array(labels)
    out = {}
    for name in SECTIONS:
        idx = np.flatnonzero(lab == name)
        if idx.size == 0:
            raise FileFormatError(path, f"no row labelled {name!r}; expected every section "
                                  f"{', '.join(SECTIONS)}", field="part")
        if name.endswith("_rot") and np.any(np.diff(idx) != 1):
            raise FileFormatError(path, f"the rows of {name!r} are not contiguous; a rotation "
                                  "is integrated over consecutive samples", field="part")
        out[name] = idx
    return out


def load_ferraris(path: str | Path, sample_rate_hz: float, *,
                  sections: str | Path | None = None, gyro_raw_unit: str = "raw",
                  accel_raw_unit: str = "raw") -> FerrarisSession:
    """Read a Ferraris session (annotated CSV, or CSV plus section list).

    Raises
    ------
    FileFormatError
        Unreadable file, missing column, non-numeric value, missing section (naming the
        file, line and field).
    """
    p = str(path)
    if not (np.isfinite(sample_rate_hz) and sample_rate_hz > 0):
        raise FileFormatError(p, f"sample rate {sample_rate_hz}; expected a positive number "
                              "(Hz)", field="sample_rate_hz")
    data, labels = _read_csv(p)
    if sections is not None:
        sec = _sections_from_list(str(sections), data.shape[0])
    elif labels is not None:
        sec = _sections_from_labels(p, labels)
    else:
        raise FileFormatError(p, "no 'part' column and no section list; expected an "
                              "annotated CSV or a section list (JSON)", field="part")
    return FerrarisSession(sample_rate_hz=float(sample_rate_hz), gyro=data[:, :3],
                           accel=data[:, 3:], sections=sec, gyro_raw_unit=gyro_raw_unit,
                           accel_raw_unit=accel_raw_unit, source=p)
