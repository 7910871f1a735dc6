"""Mutated files for every loader: a valid object or a RimuError that names the file.

The pristine files come from rimu's own writers (``rimu simulate calibration``,
``rimu calibrate``, ``rimu simulate flight``, :meth:`Thresholds.save`, the shipped sequence
and channel-map files). Hypothesis (bounded by ``max_examples``) applies byte damage
(truncation, flips, inserted garbage, BOM, empty, binary), line damage (deleted, duplicated,
swapped lines), structural JSON damage (deleted keys, values of the wrong type or length),
TOML value damage and CSV cell/column/header damage. Structural errors (a valid JSON/TOML
document with a wrong field) must also name the field.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import re
import shutil
import tempfile
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from calibration.sequence import load_sequence
from calibration.session_io import load_session
from calibration.truth import load_truth
from fdi.calfile import load_calibration
from fdi.detector import default_thresholds
from fdi.errors import FileFormatError, RimuError
from fdi.geometry import cone6, load_configuration
from fdi.settings import load_thresholds
from replay.channel_map import load_channel_map
from replay.flight import load_flight_dir
from replay.scenario import load_scenario
from rimu.cli import main

ROOT = Path(__file__).resolve().parents[1]
# RIMU_FUZZ_EXAMPLES=2000 for a long hunt; the default keeps each test around a second
FUZZ = settings(max_examples=int(os.environ.get("RIMU_FUZZ_EXAMPLES", "40")), deadline=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                       HealthCheck.function_scoped_fixture])

SCENARIO = """schema = "rimu.scenario/1"
seed = 3

[[faults]]
sensor = 3
kind = "step"
size = "15sigma"
onset = 1.0
duration = 0.5

[[faults]]
spec = "ramp:2:0.05sigma/s:0.5"

[[faults]]
sensor = 4
kind = "stuck"
onset = 2.0

[[faults]]
sensor = 1
kind = "noise"
size = "3x"
onset = 0.0
"""


def _cli(*argv: str) -> None:
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        code = main(list(argv))
    if code != 0:
        raise RuntimeError(f"rimu {' '.join(argv)} exited {code}")


@pytest.fixture(scope="module")
def pristine(tmp_path_factory) -> Path:
    """Valid files written by rimu's own writers."""
    d = tmp_path_factory.mktemp("pristine")
    _cli("simulate", "calibration", "--config", "tetrad", "--preset", "tetrad-paper",
         "--table-rate-dps", "90", "--out", str(d / "sess"), "--seed", "2")
    _cli("calibrate", "turntable", str(d / "sess"), "--out", str(d / "cal.json"))
    _cli("simulate", "flight", "--cal", str(d / "cal.json"), "--duration", "2",
         "--out", str(d / "flight"), "--seed", "1", "--fault", "step:2:15sigma:1")
    cal = load_calibration(d / "cal.json")
    default_thresholds(cal).save(d / "thresholds.json")
    shutil.copy(ROOT / "calibration" / "sequences" / "tetrad_paper.toml", d / "seq.toml")
    shutil.copy(ROOT / "replay" / "dbc" / "j1939_ari_acc_3imu.toml", d / "map.toml")
    shutil.copy(ROOT / "replay" / "dbc" / "j1939_ari.dbc", d / "j1939_ari.dbc")
    (d / "scenario.toml").write_text(SCENARIO)
    rows = cone6().H[:5]
    (d / "config.toml").write_text("name = 'five'\n" + "".join(
        f"[[sensors]]\nname = 's{i}'\naxis = {[float(v) for v in r]!r}\ngroup = {i // 3}\n"
        for i, r in enumerate(rows)))
    return d


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("work")


def _fresh(pristine: Path, work: Path) -> Path:
    """A clean copy of every pristine file in a new directory under ``work``."""
    d = Path(tempfile.mkdtemp(dir=work))
    shutil.copytree(pristine, d, dirs_exist_ok=True)
    return d


def _load(loader, path: Path, *, field: str | None = None):
    """Run a loader; only a RimuError naming the file (and ``field``) may escape."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")              # collinear-axes warnings are fine
        try:
            return loader()
        except RimuError as exc:
            msg = str(exc)
            assert path.name in msg, f"error does not name {path.name}: {msg}"
            assert "\n" not in msg.strip(), f"error is not one line: {msg!r}"
            if field is not None:
                assert field in msg, f"error does not name field {field!r}: {msg}"
            return exc


# ---------------------------------------------------------------- mutation strategies
GARBAGE = [b"\x00\xff\xfe", b"\xef\xbb\xbf", b"nan", b"\n\n", b",,,,", b"]]}{", b"\"",
           b"1e999", b"-", b"\xc3\x28", b"\t", b"=", b"#"]


@st.composite
def byte_damage(draw, data: bytes) -> bytes:
    kind = draw(st.sampled_from(["truncate", "flip", "insert", "bom", "empty", "binary",
                                 "del_line", "dup_line", "swap_lines", "garbage_line",
                                 "crlf"]))
    n = len(data)
    if kind == "truncate":
        return data[:draw(st.integers(0, max(n - 1, 0)))]
    if kind == "flip":
        out = bytearray(data)
        for _ in range(draw(st.integers(1, 4))):
            k = draw(st.integers(0, n - 1))
            out[k] ^= draw(st.integers(1, 255))
        return bytes(out)
    if kind == "insert":
        k = draw(st.integers(0, n))
        return data[:k] + draw(st.sampled_from(GARBAGE)) + data[k:]
    if kind == "bom":
        return b"\xef\xbb\xbf" + data
    if kind == "empty":
        return b""
    if kind == "binary":
        return draw(st.binary(min_size=1, max_size=200))
    if kind == "crlf":
        return data.replace(b"\n", b"\r\n")
    lines = data.split(b"\n")
    i = draw(st.integers(0, len(lines) - 1))
    if kind == "del_line":
        del lines[i]
    elif kind == "dup_line":
        lines.insert(i, lines[i])
    elif kind == "swap_lines":
        j = draw(st.integers(0, len(lines) - 1))
        lines[i], lines[j] = lines[j], lines[i]
    else:
        lines.insert(i, draw(st.sampled_from(GARBAGE)))
    return b"\n".join(lines)


WRONG = [None, "x", "", -1, 0, 1e308, -1e308, True, [], {}, [1, 2], [[1, 2, 3]], [None],
         ["a", "b"], {"a": 1}, 3.5, 10**30]


def _paths(doc, prefix=()):
    """Every (path) into a JSON document: keys and list indices."""
    yield prefix
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from _paths(v, (*prefix, k))
    elif isinstance(doc, list) and doc and not all(isinstance(x, int | float) for x in doc):
        for k, v in enumerate(doc):
            yield from _paths(v, (*prefix, k))
    elif isinstance(doc, list) and doc:
        yield (*prefix, 0)
        yield (*prefix, len(doc) - 1)


@st.composite
def json_damage(draw, doc) -> tuple[object, str | None]:
    """(mutated document, the name of the damaged key or None)."""
    paths = [p for p in _paths(doc) if p]
    path = draw(st.sampled_from(paths))
    doc = json.loads(json.dumps(doc))
    parent = doc
    for k in path[:-1]:
        parent = parent[k]
    last = path[-1]
    op = draw(st.sampled_from(["delete", "replace", "nan", "shorten", "extend"]))
    if op == "delete":
        del parent[last]
    elif op == "replace":
        parent[last] = draw(st.sampled_from(WRONG))
    elif op == "nan":
        parent[last] = draw(st.sampled_from([float("nan"), float("inf"), -float("inf")]))
    elif op == "shorten" and isinstance(parent[last], list) and parent[last]:
        parent[last] = parent[last][:-1]
    elif op == "extend" and isinstance(parent[last], list):
        parent[last] = parent[last] + [parent[last][-1] if parent[last] else 1.0]
    else:
        parent[last] = None
    key = next((k for k in reversed(path) if isinstance(k, str)), None)
    return doc, key


TOML_VALUES = ['"x"', '""', "-1", "0", "1e308", "nan", "inf", "-inf", "[]", "[1, 2]",
               "{}", "true", "[[1, 2, 3]]", '["a"]', "1.5", "999999999999999999999",
               "0x7FFF_FFFF_FFFF_FFFF"]
_KEYLINE = re.compile(r"^(\s*)([A-Za-z_][A-Za-z0-9_]*)(\s*=\s*)(.*)$")


@st.composite
def toml_damage(draw, text: str) -> tuple[str, str | None]:
    """(mutated text, key whose value was damaged or None). Keeps the text valid TOML
    (one key per line) so that the loader's field checks are exercised."""
    lines = text.split("\n")
    keyed = [i for i, ln in enumerate(lines) if _KEYLINE.match(ln)]
    op = draw(st.sampled_from(["value", "value", "delete", "rename", "dup_table"]))
    i = draw(st.sampled_from(keyed))
    m = _KEYLINE.match(lines[i])
    key = m.group(2)
    if op == "value":
        lines[i] = m.group(1) + key + m.group(3) + draw(st.sampled_from(TOML_VALUES))
    elif op == "delete":
        del lines[i]
    elif op == "rename":
        lines[i] = m.group(1) + key + "_typo" + m.group(3) + m.group(4)
    else:
        tables = [j for j, ln in enumerate(lines) if ln.startswith("[[")]
        if not tables:
            return "\n".join(lines), None
        j = draw(st.sampled_from(tables))
        lines.insert(j, lines[j])                   # an empty table of the array
        key = None
    return "\n".join(lines), key


CELLS = ["abc", "", "nan", "inf", "-inf", "1e999", "1,5", "0x10", " ", "\x00", "é", "NaN",
         "--1", "1e-999"]


@st.composite
def csv_damage(draw, text: str) -> str:
    lines = text.split("\n")
    nonempty = [i for i, ln in enumerate(lines) if ln]
    op = draw(st.sampled_from(["cell", "drop_cell", "extra_cell", "header_rename",
                               "header_drop", "header_dup", "truncate_mid", "blank_line",
                               "drop_header"]))
    if op.startswith("header") or op == "drop_header":
        cols = lines[0].split(",")
        k = draw(st.integers(0, len(cols) - 1))
        if op == "header_rename":
            cols[k] = draw(st.sampled_from(["", "x", cols[k] + " ", cols[k].upper()]))
        elif op == "header_drop":
            del cols[k]
        elif op == "header_dup":
            cols.insert(k, cols[k])
        else:
            return "\n".join(lines[1:])
        lines[0] = ",".join(cols)
        return "\n".join(lines)
    i = draw(st.sampled_from(nonempty[1:] or nonempty))
    cells = lines[i].split(",")
    if op == "cell":
        cells[draw(st.integers(0, len(cells) - 1))] = draw(st.sampled_from(CELLS))
    elif op == "drop_cell":
        del cells[draw(st.integers(0, len(cells) - 1))]
    elif op == "extra_cell":
        cells.append(draw(st.sampled_from(["1.0", "", "x"])))
    elif op == "truncate_mid":
        s = ",".join(cells)
        return "\n".join([*lines[:i], s[:draw(st.integers(0, len(s)))]])
    else:
        lines.insert(i, "")
        return "\n".join(lines)
    lines[i] = ",".join(cells)
    return "\n".join(lines)


# ---------------------------------------------------------------- JSON files
JSON_FILES = {
    "calibration": ("cal.json", lambda d: load_calibration(d / "cal.json")),
    "thresholds": ("thresholds.json", lambda d: load_thresholds(d / "thresholds.json")),
    "truth": ("sess/truth.json", lambda d: load_truth(d / "sess" / "truth.json")),
    "session_manifest": ("sess/manifest.json", lambda d: load_session(d / "sess")),
    "flight_manifest": ("flight/manifest.json", lambda d: load_flight_dir(d / "flight")),
    "flight_truth": ("flight/truth.json", lambda d: load_flight_dir(d / "flight")),
}


@pytest.mark.parametrize("which", sorted(JSON_FILES))
@FUZZ
@given(data=st.data())
def test_json_file_with_byte_damage(pristine, work, which, data):
    rel, loader = JSON_FILES[which]
    d = _fresh(pristine, work)
    p = d / rel
    p.write_bytes(data.draw(byte_damage(p.read_bytes()), label="bytes"))
    _load(lambda: loader(d), p)


@pytest.mark.parametrize("which", sorted(JSON_FILES))
@FUZZ
@given(data=st.data())
def test_json_file_with_structural_damage(pristine, work, which, data):
    rel, loader = JSON_FILES[which]
    d = _fresh(pristine, work)
    p = d / rel
    doc, key = data.draw(json_damage(json.loads(p.read_text())), label="doc")
    p.write_text(json.dumps(doc, indent=1))
    res = _load(lambda: loader(d), p)
    if isinstance(res, FileFormatError) and key is not None and res.line is None:
        # a structural error names a field (not necessarily the damaged one: a deleted
        # key can surface as a consistency check elsewhere)
        assert res.field is not None or res.step is not None, str(res)


# ---------------------------------------------------------------- TOML files
TOML_FILES = {
    "sequence": ("seq.toml", lambda d: load_sequence(d / "seq.toml")),
    "configuration": ("config.toml", lambda d: load_configuration(d / "config.toml")),
    "channel_map": ("map.toml", lambda d: load_channel_map(d / "map.toml")),
    "scenario": ("scenario.toml",
                 lambda d: load_scenario(d / "scenario.toml", load_calibration(d / "cal.json"))),
}


@pytest.mark.parametrize("which", sorted(TOML_FILES))
@FUZZ
@given(data=st.data())
def test_toml_file_with_byte_damage(pristine, work, which, data):
    rel, loader = TOML_FILES[which]
    d = _fresh(pristine, work)
    p = d / rel
    p.write_bytes(data.draw(byte_damage(p.read_bytes()), label="bytes"))
    _load(lambda: loader(d), p)


@pytest.mark.parametrize("which", sorted(TOML_FILES))
@FUZZ
@given(data=st.data())
def test_toml_file_with_value_damage(pristine, work, which, data):
    rel, loader = TOML_FILES[which]
    d = _fresh(pristine, work)
    p = d / rel
    text, _key = data.draw(toml_damage(p.read_text()), label="text")
    p.write_text(text)
    _load(lambda: loader(d), p)


# ---------------------------------------------------------------- CSV sample files
CSV_FILES = {
    "session": ("sess/samples.csv", lambda d: load_session(d / "sess")),
    "flight": ("flight/samples.csv", lambda d: load_flight_dir(d / "flight")),
}


@pytest.mark.parametrize("which", sorted(CSV_FILES))
@FUZZ
@given(data=st.data())
def test_samples_csv_with_cell_damage(pristine, work, which, data):
    rel, loader = CSV_FILES[which]
    d = _fresh(pristine, work)
    p = d / rel
    p.write_text(data.draw(csv_damage(p.read_text()), label="csv"))
    res = _load(lambda: loader(d), p)
    if isinstance(res, RimuError):
        assert re.search(r":\d+|line|row|column|field|header", str(res)), str(res)


@pytest.mark.parametrize("which", sorted(CSV_FILES))
@FUZZ
@given(data=st.data())
def test_samples_csv_with_byte_damage(pristine, work, which, data):
    rel, loader = CSV_FILES[which]
    d = _fresh(pristine, work)
    p = d / rel
    p.write_bytes(data.draw(byte_damage(p.read_bytes()), label="bytes"))
    _load(lambda: loader(d), p)


@FUZZ
@given(data=st.data())
def test_flight_truth_rates_with_byte_damage(pristine, work, data):
    d = _fresh(pristine, work)
    p = d / "flight" / "truth_rates.npy"
    if not p.exists():
        pytest.skip("no truth_rates.npy in this flight format")
    p.write_bytes(data.draw(byte_damage(p.read_bytes()), label="bytes"))
    _load(lambda: load_flight_dir(d / "flight"), p)


def test_missing_files_name_the_file(pristine, work):
    d = _fresh(pristine, work)
    for rel, loader in {**JSON_FILES, **TOML_FILES, **CSV_FILES}.values():
        e = _fresh(pristine, work)
        (e / rel).unlink()
        res = _load(lambda e=e, loader=loader: loader(e), e / rel)
        if rel != "flight/truth.json":              # a flight without truth is valid
            assert isinstance(res, RimuError), rel
    # a directory where a file should be
    (d / "cal.json").unlink()
    (d / "cal.json").mkdir()
    assert isinstance(_load(lambda: load_calibration(d / "cal.json"), d / "cal.json"),
                      RimuError)


def test_pristine_files_load(pristine):
    """The fuzzing starts from files every loader accepts."""
    for rel, loader in {**JSON_FILES, **TOML_FILES, **CSV_FILES}.values():
        res = _load(lambda loader=loader: loader(pristine), pristine / rel)
        assert not isinstance(res, RimuError), f"{rel}: {res}"
    assert np.isfinite(load_calibration(pristine / "cal.json").gyro.H).all()


def test_writer_refuses_a_scale_factor_the_loader_would_refuse(tmp_path):
    """Regression: a session with one -1e300 raw sample calibrated to a zero scale factor and
    ``Calibration.save`` died in the unit conversion (ZeroDivisionError, a traceback from
    ``rimu calibrate``); the writer now raises a one-line ConfigError."""
    from dataclasses import replace

    from fdi.calfile import Calibration, SensorSet
    from fdi.errors import ConfigError
    from studies.synthetic import synthetic_calibration

    cal = synthetic_calibration("tetrad", seed=1)
    s = cal.gyro
    for bad in (0.0, float("inf"), float("nan")):
        sens = (replace(s.sensors[0], scale_factor=bad, scale_factor_unit="mV/(deg/s)"),
                *s.sensors[1:])
        c2 = Calibration(cal.configuration, {"gyro": SensorSet("gyro", sens,
                                                                s.noise_covariance)},
                         cal.sample_rate_hz)
        with pytest.raises(ConfigError, match="scale factor"):
            c2.save(tmp_path / "c.json")


def test_thresholds_with_a_huge_window_are_refused(pristine, work):
    """Regression: ``scales = [..., 1e308]`` passed the loader (finite, integral) and the
    monitor then tried to allocate a ring of 1e308 window sums."""
    d = _fresh(pristine, work)
    p = d / "thresholds.json"
    doc = json.loads(p.read_text())
    doc["scales"][-1] = 1e308
    p.write_text(json.dumps(doc))
    res = _load(lambda: load_thresholds(p), p, field="scales")
    assert isinstance(res, FileFormatError) and "1e+308" in str(res), res


@pytest.mark.parametrize("edit, field", [
    (lambda d: d["noise_covariance"]["gyro"][0].__setitem__(0, -1.0), "noise_covariance.gyro"),
    (lambda d: d["noise_covariance"]["gyro"][1].__setitem__(1, 1e308), "noise_covariance.gyro"),
    (lambda d: d["noise_covariance"]["gyro"][0].__setitem__(2, 1e-3), "noise_covariance.gyro"),
    (lambda d: d["sensors"]["gyro"][0].__setitem__("bias_sd", 1e308), "bias_sd"),
    (lambda d: d["sensors"]["gyro"][0].__setitem__("bias_sd", -1.0), "bias_sd"),
])
def test_calibration_the_monitor_cannot_use_is_refused_by_the_loader(pristine, work, edit,
                                                                        field):
    """Regression: these loaded, then ``Monitor(cal)`` died in numpy (LinAlgError: not
    positive definite / singular / eigenvalues did not converge) -- a traceback from
    ``rimu monitor-file`` and ``rimu replay``."""
    d = _fresh(pristine, work)
    p = d / "cal.json"
    doc = json.loads(p.read_text())
    edit(doc)
    p.write_text(json.dumps(doc))
    res = _load(lambda: load_calibration(p), p, field=field)
    assert isinstance(res, FileFormatError), res


def test_monitor_runs_with_an_infinite_input_error_covariance(pristine):
    """Regression: an input_error_cov entry of 1e308 made a kernel constant inf, and the
    generated kernel source failed with NameError: name 'inf' is not defined (out of
    Monitor.run; Monitor.step reported an internal error)."""
    from fdi.monitor import Monitor

    doc = json.loads((pristine / "cal.json").read_text())
    doc["sensors"]["gyro"][0]["input_error_cov"][0][0] = 1e308
    from fdi.calfile import calibration_from_dict

    cal = calibration_from_dict(doc, "cal.json")
    n = cal.gyro.n
    raw = np.tile(np.linspace(1.0, 2.0, n), (20, 1)) + np.arange(20)[:, None] * 1e-3
    mon = Monitor(cal)
    res = mon.run(np.arange(20) / 100.0, raw)
    a = Monitor(cal).step(0.0, raw[0])
    assert not any("internal error" in e.reason for e in a.events), a.events
    assert len(res) == 20


def _numeric_paths(doc, prefix=()):
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from _numeric_paths(v, (*prefix, k))
    elif isinstance(doc, list):
        for k, v in enumerate(doc):
            yield from _numeric_paths(v, (*prefix, k))
    elif isinstance(doc, int | float) and not isinstance(doc, bool):
        yield prefix


@FUZZ
@given(data=st.data())
def test_any_calibration_the_loader_accepts_runs_the_monitor(pristine, work, data):
    """Extreme numbers in any numeric field: refused by the loader, or the monitor runs."""
    from fdi.monitor import Monitor

    p0 = pristine / "cal.json"
    doc = json.loads(p0.read_text())
    for _ in range(data.draw(st.integers(1, 3), label="edits")):
        path = data.draw(st.sampled_from(list(_numeric_paths(doc))), label="path")
        parent = doc
        for k in path[:-1]:
            parent = parent[k]
        parent[path[-1]] = data.draw(st.sampled_from([0, -1, 1e308, -1e308, 1e-308, 1e300,
                                                      5e-324, 1e30, -1e-30]), label="value")
    d = _fresh(pristine, work)
    p = d / "cal.json"
    p.write_text(json.dumps(doc))
    cal = _load(lambda: load_calibration(p), p)
    if isinstance(cal, RimuError):
        return
    try:
        mon = Monitor(cal)
    except RimuError:
        return
    n = cal.gyro.n
    raw = np.tile(np.linspace(1.0, 2.0, n), (30, 1)) + np.arange(30)[:, None] * 1e-3
    res = mon.run(np.arange(30) / 100.0, raw)
    assert len(res) == 30
    a = Monitor(cal).step(0.0, raw[0])
    assert not any("internal error" in e.reason for e in a.events), a.events
