"""Flight folders (``rimu.flight/1``) and truth sidecars: writing and loading.

Flight directory ``rimu.flight/1``
----------------------------------
``DIR/manifest.json``::

    {"schema": "rimu.flight/1", "sample_rate_hz": 100.0, "kind": "gyro",
     "sensor_names": ["g1", ...], "raw_unit": "mV", "columns": ["t", "g1", ...],
     "samples": N, "samples_file": "samples.csv", "source": "..."}

Unknown keys are refused (a typo must not switch a field off silently); a writer's own
information goes under ``"meta"`` (a free-form object).

``DIR/samples.csv``: one header line (the columns), then one line per sample: ``t`` (s) and
the raw output of each sensor in its raw unit; an **empty cell means no sample** from that
sensor (``valid = False``), while ``nan``/``inf`` are values the sensor sent.

``DIR/truth.json`` (optional; only simulated or fault-injected flights have one)::

    {"schema": "rimu.flight-truth/1", "faults": [Fault.to_dict(), ...],
     "true_parameters": {"axis": n×3, "scale_factor": [SI input per raw unit],
                         "bias": [SI], "noise_covariance": n×n SI², "source": ...},
     "rates_file": "truth_rates.npy", "seed": ..., ...}

``DIR/truth_rates.npy``: the true body rates, float64, shape (N, 3), rad/s.
:func:`write_truth_sidecar` / :func:`read_truth_sidecar` read and write the truth beside any
file (CAN logs use them too).

Channels beside the monitored sensors (optional, backward compatible)
---------------------------------------------------------------------
A flight made of several IMUs names its IMU groups and keeps its accelerometers and
temperatures beside the gyros. The manifest then has two more fields, which a reader that
does not know them may ignore (``samples.csv`` is unchanged)::

    "imu": ["imu1", "imu1", "imu1", "imu2", ...],          # one per sensor_names entry
    "aux": {"file": "aux.csv",
            "channels": [{"kind": "accel", "name": "imu1.x", "imu": "imu1",
                          "unit": "m/s^2"}, ...,
                         {"kind": "temperature", "name": "imu1", "imu": "imu1",
                          "unit": "degC"}, ...]}

Events the log declared (optional, backward compatible)
-------------------------------------------------------
``"events": [{"t": 86.6, "t_end": 120.1, "source": "ERR", "text": "ERR CRASH_CHECK 1:
crash", "code": 1, "category": "crash"}, ...]``: times in s on the samples' clock,
``t_end`` ``null`` when the event lasts to the end of the log; ``category`` is ``crash``
(declared out of the operating envelope), ``estimator`` or ``info``
(:mod:`replay.log_events`).

``DIR/aux.csv``: header ``t,<kind>:<name>,...`` (``accel:imu1.x``, ``temperature:imu1``),
one line per sample on the same times as ``samples.csv`` (same ``t`` column), empty cell
= no sample. Units are fixed per kind (:data:`replay.flight_data.AUX_UNITS`).
"""

from __future__ import annotations

import io
import json
import logging
import math
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from fdi.errors import ConfigError, FileFormatError
from fdi.fileio import Fields, NumberRule, check_numbers, read_json_object, to_jsonable
from replay.faults import Fault, fault_from_dict
from replay.flight_data import AUX_KINDS, AUX_UNITS, FLIGHT_TRUTH_SCHEMA, AuxChannels, Flight
from replay.log_events import LogEvent, event_from_dict, event_to_dict
from replay.time_base import check_rate, time_base

__all__ = [
    "AUX_FILE",
    "FLIGHT_NUMBER_RULES",
    "FLIGHT_SCHEMA",
    "FLIGHT_TRUTH_SCHEMA",
    "load_flight_dir",
    "read_truth_sidecar",
    "save_flight_dir",
    "write_truth_sidecar",
]

FLIGHT_SCHEMA = "rimu.flight/1"
FLIGHT_NUMBER_RULES: tuple[NumberRule, ...] = (
    NumberRule("samples", 0.0, what="a count of rows"),
)
"""Ranges of the flight manifest's numbers beyond :data:`fdi.fileio.CONVENTION_RULES`
(``sample_rate_hz`` > 0); every other number (event times, ``meta``) must be finite."""
AUX_FILE = "aux.csv"
"""File of the channels kept beside the monitored sensors."""


def _fmt_column(v: np.ndarray, ok: np.ndarray) -> np.ndarray:
    s = np.char.mod("%.17g", v).astype(object)
    s[~ok] = ""
    return s


def _write_csv(path: Path, header: Sequence[str], cols: Sequence[np.ndarray]) -> None:
    with open(path, "w", encoding="utf-8", newline="\n") as fh:
        fh.write(",".join(header) + "\n")
        step = 100_000
        for a in range(0, cols[0].shape[0], step):
            rows = [",".join(r) for r in zip(*(c[a:a + step] for c in cols), strict=True)]
            fh.write("\n".join(rows) + "\n")


def save_flight_dir(flight: Flight, directory: str | Path) -> None:
    """Write a flight as ``DIR/manifest.json``, ``DIR/samples.csv`` and the truth sidecar.

    The truth (``truth.json`` + ``truth_rates.npy``) is written when the flight has faults,
    true rates or a truth record; ``aux.csv`` and the manifest's ``imu``/``aux`` fields
    when the flight has IMU groups or channels beside its sensors.
    """
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    n = flight.n
    manifest: dict[str, Any] = {
        "schema": FLIGHT_SCHEMA, "sample_rate_hz": float(flight.sample_rate_hz),
        "kind": flight.kind, "sensor_names": list(flight.sensor_names),
        "raw_unit": flight.raw_unit, "columns": ["t", *flight.sensor_names],
        "samples": int(flight.t.shape[0]), "samples_file": "samples.csv",
        "source": flight.source}
    if flight.imu:
        manifest["imu"] = list(flight.imu)
    if flight.events:
        manifest["events"] = [event_to_dict(e) for e in flight.events]
    t_col = _fmt_column(flight.t, np.ones_like(flight.t, bool))
    cols = [t_col] + [_fmt_column(flight.raw[:, i], flight.valid[:, i]) for i in range(n)]
    _write_csv(d / "samples.csv", manifest["columns"], cols)
    aux = flight.aux
    if aux is not None and aux.m:
        manifest["aux"] = {"file": AUX_FILE, "channels": [
            {"kind": k, "name": nm, "imu": g, "unit": AUX_UNITS[k]}
            for k, nm, g in zip(aux.kinds, aux.names, aux.imu, strict=True)]}
        _write_csv(d / AUX_FILE, ["t", *aux.columns],
                   [t_col] + [_fmt_column(aux.values[:, j], aux.valid[:, j])
                              for j in range(aux.m)])
    else:
        (d / AUX_FILE).unlink(missing_ok=True)
    (d / "manifest.json").write_text(json.dumps(manifest, indent=1) + "\n", encoding="utf-8")
    if flight.faults or flight.omega_true is not None or flight.truth:
        write_truth_sidecar(flight, d / "truth.json")
    else:
        for name in ("truth.json", "truth_rates.npy"):
            (d / name).unlink(missing_ok=True)


def write_truth_sidecar(flight: Flight, path: str | Path) -> None:
    """Write the flight's truth as ``rimu.flight-truth/1`` JSON at ``path``.

    The true rates go to ``<stem>_rates.npy`` beside it (``truth_rates.npy`` for
    ``truth.json``), named in the JSON's ``"rates_file"``.
    """
    p = Path(path)
    doc = dict(flight.truth)
    doc["schema"] = FLIGHT_TRUTH_SCHEMA
    doc["faults"] = [f.to_dict() for f in flight.faults]
    doc["samples"] = int(flight.t.shape[0])
    doc["sample_rate_hz"] = float(flight.sample_rate_hz)
    if flight.omega_true is not None:
        rates = p.with_name(p.stem + "_rates.npy")
        np.save(rates, np.asarray(flight.omega_true, float))
        doc["rates_file"] = rates.name
        doc["rates_unit"] = "rad/s"
    else:
        doc.pop("rates_file", None)
    p.write_text(json.dumps(to_jsonable(doc), indent=1) + "\n", encoding="utf-8")


def read_truth_sidecar(path: str | Path, *, samples: int | None = None, mmap: bool = False
                       ) -> tuple[tuple[Fault, ...], dict[str, Any], np.ndarray | None]:
    """Read a ``rimu.flight-truth/1`` file: (faults, truth record, true rates or None).

    With ``mmap`` a float64 rates file is memory-mapped, not read (long logs).

    Raises
    ------
    FileFormatError
        Naming the file and the field (or the rates file and its shape).
    """
    p = Path(path)
    doc = read_json_object(p, FLIGHT_TRUTH_SCHEMA)
    raw_faults = doc.get("faults", [])
    if not isinstance(raw_faults, list):
        raise FileFormatError(str(p), "expected a list", field="faults")
    faults = []
    for j, fd in enumerate(raw_faults):
        if not isinstance(fd, Mapping):
            raise FileFormatError(str(p), "expected an object", field=f"faults[{j}]")
        try:
            faults.append(fault_from_dict(fd, f"faults[{j}]"))
        except ConfigError as exc:
            raise FileFormatError(str(p), str(exc), field=f"faults[{j}]") from None
    rates = None
    rf = doc.get("rates_file")
    if rf is not None:
        if not isinstance(rf, str) or not rf or Path(rf).name != rf:
            raise FileFormatError(str(p), f"expected a file name beside it, got {rf!r}",
                                  field="rates_file")
        rp = p.with_name(rf)
        try:
            rates = np.load(rp, allow_pickle=False, mmap_mode="r" if mmap else None)
        except Exception as exc:        # a damaged .npy header fails in many ways (EOFError,
            # ValueError, SyntaxError, tokenize.TokenError from its literal header, ...)
            why = exc.strerror if isinstance(exc, OSError) else f"{type(exc).__name__}: {exc}"
            raise FileFormatError(str(rp), f"cannot read the true rates {p.name} names "
                                  f"({why})",
                                  field="rates_file") from None
        if rates.dtype.kind not in "fiu":
            raise FileFormatError(str(rp), f"expected numbers, got dtype {rates.dtype}",
                                  field="rates_file")
        if rates.ndim != 2 or rates.shape[1] != 3 or (samples is not None
                                                       and rates.shape[0] != samples):
            want = f"({samples}, 3)" if samples is not None else "(N, 3)"
            raise FileFormatError(str(rp), f"expected shape {want}, got {rates.shape}")
        if not (mmap and rates.dtype == np.float64):
            rates = rates.astype(float)
    doc.pop("rates_file", None)
    return tuple(faults), doc, rates


_EMPTY_CELL = re.compile(rb"(?<=,)(?=,|\n)|^(?=,)", re.MULTILINE)


_CHUNK = 64 << 20


def _read_text_bytes(path: Path) -> bytes:
    """The bytes of a CSV file, read in chunks; a NUL byte (binary data, a sparse or
    zero-filled file) stops the read at once with one line, before the rest is read."""
    p = str(path)
    parts, at = [], 0
    try:
        with open(path, "rb") as fh:
            while chunk := fh.read(_CHUNK):
                nul = chunk.find(b"\0")
                if nul >= 0:
                    line = sum(c.count(b"\n") for c in parts) + chunk.count(b"\n", 0, nul) + 1
                    raise FileFormatError(p, f"binary data (a NUL byte at offset {at + nul}), "
                                          "not CSV text: a damaged or zero-filled file",
                                          line=line)
                parts.append(chunk)
                at += len(chunk)
    except OSError as exc:
        raise FileFormatError(p, f"cannot read ({exc.strerror})") from None
    return b"".join(parts)


def _load_samples(path: Path, ncol: int, columns: Sequence[str]) -> tuple[np.ndarray,
                                                                         np.ndarray]:
    """Numbers and missing-mask of a samples.csv: ((N, ncol) float, (N, ncol) bool)."""
    p = str(path)
    data = _read_text_bytes(path)
    data = data.replace(b"\r\n", b"\n")
    nl = data.find(b"\n")
    header = (data if nl < 0 else data[:nl]).decode("utf-8", "replace").strip()
    got = [h.strip() for h in header.split(",")]
    if got != list(columns):
        raise FileFormatError(p, f"header {got} does not match the manifest's columns "
                                 f"{list(columns)}", line=1)
    body = b"" if nl < 0 else data[nl + 1:]
    body = body.rstrip(b"\n")
    if body:
        body += b"\n"
    if not body:
        return np.zeros((0, ncol)), np.zeros((0, ncol), bool)
    b = np.frombuffer(body, np.uint8)
    nl_pos = np.flatnonzero(b == 10)
    delim = np.flatnonzero((b == 44) | (b == 10))
    # cells per line: delimiters up to and including each newline
    per_line = np.diff(np.concatenate([[0], np.searchsorted(delim, nl_pos, side="right")]))
    bad = np.flatnonzero(per_line != ncol)
    if bad.size:
        j = int(bad[0])
        raise FileFormatError(p, f"{per_line[j]} cells, expected {ncol}", line=j + 2)
    starts = np.concatenate([[0], delim[:-1] + 1])
    missing = (delim == starts).reshape(-1, ncol)
    if missing[:, 0].any():
        j = int(np.flatnonzero(missing[:, 0])[0])
        raise FileFormatError(p, "empty time", line=j + 2, field=columns[0])
    filled = _EMPTY_CELL.sub(b"nan", body) if missing.any() else body
    try:
        vals = np.loadtxt(io.BytesIO(filled), delimiter=",", dtype=float, ndmin=2)
    except ValueError:
        _locate_bad_cell(p, body.decode("utf-8", "replace"), columns)
        raise FileFormatError(p, "cannot parse") from None
    return vals.reshape(-1, ncol), missing


def _locate_bad_cell(p: str, text: str, columns: Sequence[str]) -> None:
    for j, line in enumerate(text.split("\n")):
        for c, cell in enumerate(line.split(",")):
            if cell.strip() == "" and c > 0:
                continue
            try:
                float(cell)
            except ValueError:
                raise FileFormatError(p, f"{cell!r} is not a number", line=j + 2,
                                      field=columns[c] if c < len(columns) else None) from None


def _positive_rate(man: Mapping[str, Any], mp: str) -> float:
    fs = man.get("sample_rate_hz")
    if isinstance(fs, bool) or not isinstance(fs, int | float) or not math.isfinite(fs) \
            or fs <= 0:
        raise FileFormatError(mp, f"expected a positive number, got {fs!r}",
                              field="sample_rate_hz")
    return float(fs)


def _sensor_names(man: Mapping[str, Any], mp: str) -> list[str]:
    names = man.get("sensor_names")
    if not isinstance(names, list) or not names or not all(isinstance(x, str) for x in names):
        raise FileFormatError(mp, "expected a non-empty list of strings", field="sensor_names")
    columns = man.get("columns", ["t", *names])
    if columns != ["t", *names]:
        raise FileFormatError(mp, f"expected ['t', *sensor_names], got {columns!r}",
                              field="columns")
    return names


def _imu_groups(man: Mapping[str, Any], mp: str, n: int) -> tuple[str, ...]:
    imu = man.get("imu", [])
    if not isinstance(imu, list) or not all(isinstance(x, str) for x in imu) \
            or len(imu) not in (0, n):
        raise FileFormatError(mp, f"expected a list of {n} strings (one IMU group per "
                                  f"sensor), got {imu!r}", field="imu")
    return tuple(imu)


def _file_beside(d: Path, mp: str, name: Any, field: str) -> Path:
    """The data file a manifest field names, in the folder ``d``."""
    if not isinstance(name, str) or not name.strip() or Path(name).name != name:
        raise FileFormatError(mp, f"expected a file name beside it, got {name!r}", field=field)
    path = d / name
    if not path.is_file():
        raise FileFormatError(str(path), f"cannot read (no such file); {Path(mp).name} "
                                         f"names it", field=field)
    return path


def _check_times(sp: str, t: np.ndarray) -> None:
    if t.size and not np.all(np.isfinite(t)):
        j = int(np.flatnonzero(~np.isfinite(t))[0])
        raise FileFormatError(sp, "non-finite time", line=j + 2, field="t")
    if t.size > 1 and np.any(np.diff(t) < 0):
        back = np.flatnonzero(np.diff(t) < 0)
        j = int(back[0]) + 1
        raise FileFormatError(sp, f"time goes backwards ({back.size} time stamp"
                              f"{'s' * (back.size != 1)} earlier than the one before, the first "
                              "here); sort the rows or re-ingest the log", line=j + 2, field="t")


def _aux_channel(ch: Any, mp: str, where: str) -> tuple[str, str, str]:
    """(kind, name, imu) of one entry of the manifest's ``aux.channels``."""
    if not isinstance(ch, Mapping) or not all(isinstance(ch.get(k), str)
                                              for k in ("kind", "name")):
        raise FileFormatError(mp, "expected an object with string 'kind' and 'name'",
                              field=where)
    Fields(ch, mp, where).finish(accept=("kind", "name", "unit", "imu"))
    if ch["kind"] not in AUX_KINDS:
        raise FileFormatError(mp, f"kind {ch['kind']!r} is not one of {AUX_KINDS}",
                              field=where)
    unit = ch.get("unit", AUX_UNITS[ch["kind"]])
    if unit != AUX_UNITS[ch["kind"]]:
        raise FileFormatError(mp, f"unit {unit!r}: {ch['kind']} channels are stored in "
                                  f"{AUX_UNITS[ch['kind']]!r}", field=where)
    imu = ch.get("imu", "")
    if not isinstance(imu, str):
        raise FileFormatError(mp, f"expected a string, got {imu!r}", field=where + ".imu")
    return ch["kind"], ch["name"], imu


def _aux_channels(d: Path, man: Mapping[str, Any], mp: str, t: np.ndarray
                  ) -> AuxChannels | None:
    """The manifest's optional ``aux`` block and its CSV, on the times ``t``."""
    block = man.get("aux")
    if block is None:
        return None
    if not isinstance(block, Mapping) or not isinstance(block.get("channels"), list) \
            or not block["channels"]:
        raise FileFormatError(mp, "expected {'file': ..., 'channels': [non-empty list]}",
                              field="aux")
    kinds, names, imus = zip(*(_aux_channel(ch, mp, f"aux.channels[{j}]")
                               for j, ch in enumerate(block["channels"])), strict=True)
    columns = ["t", *(f"{k}:{nm}" for k, nm in zip(kinds, names, strict=True))]
    if len(set(columns)) != len(columns):
        raise FileFormatError(mp, "a (kind, name) channel appears twice", field="aux")
    apath = _file_beside(d, mp, block.get("file", AUX_FILE), "aux.file")
    vals, missing = _load_samples(apath, len(columns), columns)
    if vals.shape[0] != t.shape[0] or not np.array_equal(vals[:, 0], t):
        bad = (min(vals.shape[0], t.shape[0]) if vals.shape[0] != t.shape[0] else
               int(np.flatnonzero(vals[:, 0] != t)[0]))
        raise FileFormatError(str(apath), f"times differ from the samples file ({vals.shape[0]}"
                                          f" rows, samples file {t.shape[0]})",
                              line=bad + 2, field="t")
    values = vals[:, 1:].copy()
    valid = ~missing[:, 1:]
    values[~valid] = np.nan
    return AuxChannels(tuple(kinds), tuple(names), tuple(imus), values, valid)


def load_flight_dir(directory: str | Path) -> Flight:
    """Read a flight directory written by :func:`save_flight_dir` (or by hand).

    Raises
    ------
    FileFormatError
        Naming the file, line and column (or field) of the first problem.
    """
    d = Path(directory)
    mpath = d / "manifest.json"
    man = read_json_object(mpath, FLIGHT_SCHEMA)
    mp = str(mpath)
    check_numbers(man, mp, FLIGHT_NUMBER_RULES)
    f = Fields(man, mp)
    f.accept("schema")
    fs = _positive_rate(man, mp)
    names = _sensor_names(man, mp)
    columns = ["t", *names]
    imu = _imu_groups(man, mp, len(names))
    kind = f.choice("kind", ("gyro", "accel"), "gyro")
    raw_unit = f.string("raw_unit", "raw")
    n_samples = f.integer("samples", None, lo=0)
    f.string("source", None, nonempty=False)
    f.free("meta", None)
    if isinstance(man.get("aux"), Mapping):
        Fields(man["aux"], mp, "aux").finish(accept=("file", "channels"))
    events = _events(man, mp)
    f.finish(accept=("sample_rate_hz", "sensor_names", "columns", "imu", "samples_file",
                     "aux", "events"))
    spath = _file_beside(d, mp, man.get("samples_file", "samples.csv"), "samples_file")
    vals, missing = _load_samples(spath, len(columns), columns)
    if n_samples is not None and n_samples != vals.shape[0]:
        raise FileFormatError(mp, f"says {n_samples!r} samples, {spath.name} has "
                                  f"{vals.shape[0]} (truncated or edited?)", field="samples")
    t = vals[:, 0].copy()
    raw = vals[:, 1:].copy()
    valid = ~missing[:, 1:]
    raw[~valid] = np.nan
    _check_times(str(spath), t)
    check_rate(fs, t, mp)
    said = time_base(t, raw, fs).text()
    if said:            # one line, every command that reads a flight folder
        logging.getLogger("rimu.flight").warning(f"{d}: {said}")
    aux = _aux_channels(d, man, mp, t)
    faults: tuple[Fault, ...] = ()
    truth: dict[str, Any] = {}
    rates = None
    if (d / "truth.json").exists():
        faults, truth, rates = read_truth_sidecar(d / "truth.json", samples=t.shape[0])
    return Flight(t=t, raw=raw, valid=valid, sample_rate_hz=fs,
                  sensor_names=tuple(names), raw_unit=raw_unit,
                  omega_true=rates, faults=faults, truth=truth, source=str(d), kind=kind,
                  imu=imu, aux=aux, events=events)


def _events(man: Mapping[str, Any], mp: str) -> tuple[LogEvent, ...]:
    """The manifest's optional ``events`` list."""
    ev = man.get("events", [])
    if not isinstance(ev, list):
        raise FileFormatError(mp, f"expected a list, got {type(ev).__name__}", field="events")
    return tuple(event_from_dict(d, mp, f"events[{j}]") for j, d in enumerate(ev))
