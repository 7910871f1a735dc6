"""Issue 19, field hardening second round: each class of defect as a regression test.

The promise (README): a refused command exits 2 with one line on stderr, no traceback, and
leaves nothing behind; warnings are one ``rimu: warning:`` line each. The commands run
in-process (``rimu.cli.main``) on small files made once per module.
"""

from __future__ import annotations

import ast
import csv
import json
import logging
import os
import shutil
import stat
import warnings
from pathlib import Path

import can
import numpy as np
import pytest

from fdi.calfile import CALIBRATION_SCHEMA
from replay.can_write import write_flight_log
from replay.flight import save_flight_dir, simulate_flight
from replay.live import StreamDecoder
from replay.logio import resolve_map
from rimu.cli import main
from rimu.outputs import atomic_file, atomic_write_text
from studies.ferraris_sim import imucal_like_truth, simulate_ferraris
from studies.synthetic import synthetic_calibration

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("hardening2")
    cal6 = synthetic_calibration("cone6", seed=2)
    cal6.save(d / "cal6.json")
    save_flight_dir(simulate_flight(cal6, 1.0, seed=1), d / "flight6")
    s = simulate_ferraris(imucal_like_truth(3), seed=3)
    part = np.full(s.gyro.shape[0], "", dtype=object)
    for k, idx in s.sections.items():
        part[idx] = k
    rows = ["part,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z"] + [
        f"{part[i]}," + ",".join(repr(float(v)) for v in (*s.gyro[i], *s.accel[i]))
        for i in range(s.gyro.shape[0])]
    (d / "fer.csv").write_text("\n".join(rows) + "\n")
    (d / "bin.csv").write_bytes(bytes(range(256)) * 8)
    (d / "existing.txt").write_text("keep me\n")
    (d / "x.BIN").write_bytes(b"\xa3\x95\x80")
    assert main(["simulate", "calibration", "--config", "tetrad", "--sequence",
                 "tetrad-paper", "--turns", "0.05", "--out", str(d / "sess")]) == 0
    assert main(["simulate", "flight", "--imus", "2", "--duration", "20",
                 "--out", str(d / "imus")]) == 0
    return {"d": d, "cal6": d / "cal6.json", "flight6": d / "flight6", "fer": d / "fer.csv",
            "bin": d / "bin.csv", "sess": d / "sess", "imus": d / "imus",
            "existing": d / "existing.txt", "bin_log": d / "x.BIN"}


def _tree(d: Path) -> dict[str, tuple[int, int]]:
    return {str(p.relative_to(d)): (p.stat().st_mtime_ns, p.stat().st_size)
            for p in d.rglob("*")}


def refused(capsys, d: Path, argv: list, needle: str) -> str:
    """Run argv: exit 2, one stderr line containing ``needle``, nothing written under d."""
    capsys.readouterr()
    before = _tree(d)
    rc = main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert rc == 2, (argv, err)
    assert len(err.strip().splitlines()) == 1, err
    assert "Traceback" not in err and needle in err, err
    assert _tree(d) == before, "a file was left behind or changed"
    return err


def _cal_args(f):
    return ["ferraris", f["fer"], "--sample-rate-hz", "100"]


# ------------------------------------------------------------ (a) tracebacks and hangs ----
@pytest.mark.parametrize("argv,needle", [
    (["calibrate", "{fer_args}", "--gravity", "nan"], "--gravity"),
    (["calibrate", "{fer_args}", "--position-sd-deg", "-1"], "--position-sd-deg"),
    (["calibrate", "{fer_args}", "--latitude-deg", "inf"], "--latitude-deg"),
    (["calibrate", "{fer_args}", "--sample-rate-hz", "0"], "--sample-rate-hz"),
    (["calibrate", "{fer_args}", "--sample-rate-hz", "1e-300"], "--sample-rate-hz"),  # fuzz
    (["calibrate", "{fer_args}", "--rotation-deg", "0"], "--rotation-deg"),    # fuzz: singular
    (["tune", "--cal", "{cal6}", "--false-alarms-per-hour", "1", "--seed", "-1"], "--seed"),
    (["tune", "--cal", "{cal6}", "--false-alarms-per-hour", "1", "--simulate-hours", "nan"],
     "--simulate-hours"),
    (["tune", "--cal", "{cal6}", "--false-alarms-per-hour", "1", "--simulate-hours", "inf"],
     "--simulate-hours"),
    (["tune", "--cal", "{cal6}", "--false-alarms-per-hour", "inf"], "--false-alarms-per-hour"),
    (["evaluate", "--cal", "{cal6}", "--max-rate", "nan"], "--max-rate"),
    (["evaluate", "--cal", "{cal6}", "--runs", "1000000000000"], "--runs"),   # was a hang
    (["evaluate", "--cal", "{cal6}", "--scheduler", "local", "--workers", "0"],
     "--workers"),                                                            # was a hang
    (["evaluate", "--cal", "{cal6}", "--scheduler", "elsewhere"], "--scheduler"),
    (["evaluate", "--cal", "{cal6}", "--duration", "-1"], "--duration"),
    (["simulate", "flight", "--imus", "2", "--duration", "2", "--time-offset-ms", "1e308,0"],
     "--time-offset-ms"),
    (["simulate", "flight", "--imus", "2", "--duration", "2", "--vibration", "nan:1"],
     "--vibration"),
    (["demo", "--duration", "5"], "--duration"),      # its faults start at 20 s and 35 s
])
def test_bad_option_values_refused_while_parsing(files, capsys, argv, needle):
    out = files["d"] / "out_never"
    args = []
    for a in argv:
        if a == "{fer_args}":
            args += _cal_args(files)
        else:
            args.append(a.format(**files))
    err = refused(capsys, files["d"], [*args, "--out", out], needle)
    assert err.startswith("rimu: error: argument "), err
    assert not out.exists()


def test_binary_ferraris_file_is_one_line(files, capsys):
    refused(capsys, files["d"], ["calibrate", "ferraris", files["bin"], "--sample-rate-hz",
                                 "100", "--out", files["d"] / "c.json"], "not UTF-8")


def test_ferraris_file_with_1e308_is_one_line(files, tmp_path, capsys):
    """Found by the fuzz harness: a raw value of 1e308 made the fit raise LinAlgError."""
    lines = files["fer"].read_text().splitlines()
    cells = lines[40].split(",")
    cells[2] = "1e308"
    lines[40] = ",".join(cells)
    (tmp_path / "f.csv").write_text("\n".join(lines) + "\n")
    refused(capsys, tmp_path, ["calibrate", "ferraris", tmp_path / "f.csv",
                               "--sample-rate-hz", "100", "--out", tmp_path / "c.json"],
            "beyond any sensor")


def test_tune_scales_nan_and_inf(files, capsys):
    for v in ("nan", "inf", "1e12"):
        refused(capsys, files["d"], ["tune", "--cal", files["cal6"], "--false-alarms-per-hour",
                                     "1", "--scales", v, "--out", files["d"] / "t.json"],
                "scale")


def test_diagnose_flight_with_huge_samples(files, tmp_path, capsys):
    """Rows of 1e308 in a flight folder are left out (counted), not a traceback."""
    big = tmp_path / "big"
    shutil.copytree(files["imus"], big)
    rows = list(csv.reader((big / "samples.csv").open()))
    rows[1 + 900][1:] = ["1e308"] * (len(rows[1]) - 1)        # t = 18 s of 20 s
    with (big / "samples.csv").open("w", newline="") as f:
        csv.writer(f).writerows(rows)
    cal = tmp_path / "c.json"
    assert main(["calibrate", "in-flight", str(files["imus"]), "--out", str(cal)]) == 0
    capsys.readouterr()
    assert main(["diagnose", str(big), "--cal", str(cal)]) == 0
    out, err = capsys.readouterr()
    import re

    used = int(re.search(r"\((\d+) of 1000 samples", out).group(1))
    assert 100 < used < 1000, out
    assert all(x.startswith("rimu: warning: ") for x in err.splitlines()), err


# --------------------------------------------------- (b) conflicting options ------------
@pytest.mark.parametrize("argv,needle", [
    # each procedure takes only its own options (rimu calibrate PROCEDURE, issue 29)
    (["calibrate", "in-flight", "{imus}", "--ferraris", "{fer}"],
     "unrecognized arguments: --ferraris"),
    (["calibrate", "turntable", "{sess}", "--in-flight", "{imus}"],
     "unrecognized arguments: --in-flight"),
    (["calibrate", "turntable", "{sess}", "--reference", "imu1"],
     "unrecognized arguments: --reference"),
    (["calibrate", "static", "{imus}", "--in-flight", "{imus}"],
     "unrecognized arguments: --in-flight"),
    (["calibrate", "in-flight", "{imus}", "--effects", "warmup"],
     "unrecognized arguments: --effects"),
    (["calibrate", "ferraris", "{fer}", "--sample-rate-hz", "100", "--no-denoise"],
     "unrecognized arguments: --no-denoise"),
    (["calibrate", "turntable", "{sess}", "--sample-rate-hz", "100"],
     "unrecognized arguments: --sample-rate-hz"),
    (["simulate", "flight", "--imus", "2", "--duration", "2", "--cal", "{cal6}"], "--cal"),
    (["simulate", "flight", "--imus", "2", "--duration", "2", "--fault", "step:1:5sigma:1"],
     "--fault"),
    (["simulate", "flight", "--cal", "{cal6}", "--duration", "2", "--time-offset-ms", "0,5"],
     "--imus only"),
    (["simulate", "flight", "--imus", "2", "--duration", "2", "--time-offset-ms", "1,2,3"],
     "2 values"),
])
def test_conflicting_options_refused(files, capsys, argv, needle):
    out = files["d"] / "never"
    refused(capsys, files["d"], [a.format(**files) for a in argv] + ["--out", out], needle)
    assert not out.exists()


@pytest.mark.parametrize("name", ["x.blf", "x.trc"])
def test_imus_to_a_can_log_name_refused(files, capsys, name):
    refused(capsys, files["d"], ["simulate", "flight", "--imus", "2", "--duration", "2",
                                 "--out", files["d"] / name], "flight folder")


def test_flight_to_a_log_kind_rimu_cannot_write_refused(files, capsys):
    refused(capsys, files["d"], ["simulate", "flight", "--cal", files["cal6"], "--duration",
                                 "1", "--out", files["d"] / "x.trc"], "not .trc")


# ------------------------------------------ (b) output replacing input, wrong inputs ----
def test_output_replacing_input(files, tmp_path, capsys):
    fer = tmp_path / "fer.csv"
    fer.write_bytes(files["fer"].read_bytes())
    cal = tmp_path / "cal.json"
    cal.write_bytes(files["cal6"].read_bytes())
    for argv in (["calibrate", "ferraris", fer, "--sample-rate-hz", "100", "--out", fer],
                 ["tune", "--cal", cal, "--false-alarms-per-hour", "1", "--out", cal],
                 ["diagnose", files["sess"], "--cal", cal, "--out", cal],
                 ["simulate", "flight", "--cal", cal, "--duration", "1", "--out", cal]):
        refused(capsys, tmp_path, argv, "input of this command")


def test_session_is_not_a_corpus(files, capsys):
    refused(capsys, files["d"], ["evaluate", "--cal", files["cal6"], "--corpus", files["sess"],
                                 "--no-progress", "--out", files["d"] / "ev"],
            "not a flight folder")


def test_repeat_of_a_session_with_itself(files, capsys):
    refused(capsys, files["d"], ["repeat", files["sess"], str(files["sess"]) + "/"],
            "given twice")


def test_flight_written_over_a_session_folder_refused(files, capsys):
    refused(capsys, files["d"], ["simulate", "flight", "--imus", "2", "--duration", "2",
                                 "--out", files["sess"]], "rimu.session/1")


# --------------------------------------- (b) outputs checked first, partial outputs ----
def _boom(*a, **k):
    raise AssertionError("the work ran before the output was checked")


def test_outputs_checked_before_the_work(files, monkeypatch, capsys):
    from importlib import import_module

    for mod, name in (("thresholds.tune", "tune"), ("calibration.ferraris", "ferraris_calibrate"),
                      ("thresholds.evaluate", "execute"), ("replay.ingest", "read_any"),
                      ("calibration.inflight.diagnose", "diagnose_flight")):
        monkeypatch.setattr(import_module(mod), name, _boom)
    d = files["d"]
    missing = d / "no_such_dir" / "x.json"
    for argv, needle in (
            (["tune", "--cal", files["cal6"], "--false-alarms-per-hour", "1", "--out",
              missing], "does not exist"),
            (["calibrate", *_cal_args(files), "--out", missing], "does not exist"),
            (["evaluate", "--cal", files["cal6"], "--runs", "2", "--out", files["existing"]],
             "is a file"),
            (["ingest", files["fer"], "--out", files["existing"]], "is a file"),
            (["diagnose", files["imus"], "--cal", files["cal6"], "--report",
              files["existing"]], "is a file")):
        refused(capsys, d, argv, needle)


def test_diagnose_out_then_bad_report_leaves_nothing(files, capsys):
    out = files["d"] / "refit.json"
    refused(capsys, files["d"], ["diagnose", files["sess"], "--cal", files["cal6"], "--out",
                                 out, "--report", files["existing"]], "--report")
    assert not out.exists()


def test_tune_and_ingest_write_atomically(files, tmp_path, monkeypatch, capsys):
    from importlib import import_module

    import replay.flight_io

    def half(self, path):
        Path(path).write_text("{")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(import_module("thresholds.tune").Tuning, "save", half)
    refused(capsys, tmp_path, ["tune", "--cal", files["cal6"], "--false-alarms-per-hour", "1",
                               "--simulate-hours", "0", "--out", tmp_path / "t.json"],
            "No space left")

    def half_dir(flight, directory):
        Path(directory).mkdir(parents=True, exist_ok=True)
        (Path(directory) / "manifest.json").write_text("{")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(replay.flight_io, "save_flight_dir", half_dir)
    log = tmp_path / "in" / "log.csv"
    log.parent.mkdir()
    _csv_log(log, rate_hz=200.0)
    refused(capsys, tmp_path, ["ingest", log, "--out", tmp_path / "fl"], "No space left")


def test_written_files_have_normal_modes(tmp_path):
    mask = os.umask(0o022)
    try:
        atomic_write_text(tmp_path / "a.txt", "x")
        with atomic_file(tmp_path / "b.bin") as t:
            t.write_bytes(b"x")
    finally:
        os.umask(mask)
    for name in ("a.txt", "b.bin"):
        assert stat.S_IMODE((tmp_path / name).stat().st_mode) == 0o644


# ---------------------------------------------------------------- (b) ingest ------------
def _csv_log(path: Path, *, rate_hz: float, value: str | None = None,
             time_col: str = "time_s", scale: float = 1.0, n: int = 400) -> None:
    rng = np.random.default_rng(0)
    lines = [f"{time_col},imu1_gyr_x_rps,imu1_gyr_y_rps,imu1_gyr_z_rps"]
    for i in range(n):
        g = rng.normal(0, 0.01, 3)
        vals = [value] * 3 if value is not None and i % 4 == 0 else [repr(float(x)) for x in g]
        lines.append(f"{scale * i / rate_hz!r}," + ",".join(vals))
    path.write_text("\n".join(lines) + "\n")


def test_ingest_refuses_rates_beyond_any_gyro(tmp_path, capsys):
    log = tmp_path / "big.csv"
    _csv_log(log, rate_hz=200.0, value="1e308")
    refused(capsys, tmp_path, ["ingest", log, "--out", tmp_path / "f"], "beyond any gyro")
    assert main(["ingest", str(log), "--salvage", "--out", str(tmp_path / "f")]) == 0
    rep = json.loads((tmp_path / "f" / "ingest_report.json").read_text())
    assert rep["imus"][0]["dropped"]["rate beyond any gyro's range"] == 100


def test_ingest_refuses_seconds_read_as_milliseconds(tmp_path, capsys):
    log = tmp_path / "ms.csv"
    _csv_log(log, rate_hz=200.0, time_col="time_ms")     # seconds in a time_ms column
    refused(capsys, tmp_path, ["ingest", log, "--out", tmp_path / "f"], "faster than any IMU")
    _csv_log(log, rate_hz=200.0, time_col="time_s", scale=1000.0)    # milliseconds as s
    refused(capsys, tmp_path, ["ingest", log, "--out", tmp_path / "f"], "slower than any IMU")


def test_rda_without_map_refused_before_parsing(tmp_path, capsys, monkeypatch):
    import replay.ingest.tabular as tab

    monkeypatch.setattr(tab, "read_rda_table", _boom)
    log = tmp_path / "x.rda"
    log.write_bytes(b"RDX2\n")
    refused(capsys, tmp_path, ["ingest", log, "--format", "rda", "--out", tmp_path / "f"],
            "--map")


def test_inflight_counts_nonfinite_rows(files, tmp_path, capsys):
    fl = tmp_path / "nan"
    shutil.copytree(files["imus"], fl)
    rows = list(csv.reader((fl / "samples.csv").open()))
    for r in rows[1:51]:
        r[4] = "nan"
    with (fl / "samples.csv").open("w", newline="") as f:
        csv.writer(f).writerows(rows)
    capsys.readouterr()
    assert main(["calibrate", "in-flight", str(fl), "--out", str(tmp_path / "c.json")]) == 0
    out = capsys.readouterr().out
    doc = json.loads((tmp_path / "c.json").read_text())["extra"]["inflight"]
    assert doc["samples_nonfinite"] == 50
    assert "50 samples with a non-finite rate" in out
    assert f"({doc['samples_used']} of {doc['samples']} samples used)" in out
    assert doc["samples_used"] <= doc["samples"] - 50


# -------------------------------------------------------------- (c) warnings ------------
def test_python_warnings_are_one_rimu_line(files, monkeypatch, capsys):
    import rimu.commands.parity as parity

    def noisy(args):
        warnings.warn("sensors 1 and 2 are collinear\n  (second line)", stacklevel=1)
        with np.errstate(over="warn"):
            np.float64(1e308) * 10
            np.float64(1e308) * 20              # the same text again: not repeated
        return 0

    monkeypatch.setattr(parity, "run", noisy)
    capsys.readouterr()
    assert main(["parity", "cone6"]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2, err
    assert all(x.startswith("rimu: warning: ") for x in err), err
    assert ".py:" not in "".join(err) and "collinear" in err[0] and "overflow" in err[1]


def test_damaged_text_log_warns_on_stderr(tmp_path, capsys):
    cal = synthetic_calibration("cone6", seed=5)
    cal.save(tmp_path / "cal.json")
    f = simulate_flight(cal, 0.5, seed=2)
    write_flight_log(f, tmp_path / "f.log")
    lines = (tmp_path / "f.log").read_text().splitlines()
    lines.insert(10, "this is not a frame")
    (tmp_path / "f.log").write_text("\n".join(lines) + "\n")
    capsys.readouterr()
    assert main(["replay", str(tmp_path / "f.log"), "--cal", str(tmp_path / "cal.json"),
                 "--no-progress"]) == 0
    err = capsys.readouterr().err
    assert "rimu: warning:" in err and "1 unreadable line" in err, err


# ---------------------------------------------------------- (d) what a user reads -------
def test_hints_for_the_natural_wrong_command(files, capsys):
    refused(capsys, files["d"], ["monitor-file", files["bin_log"], "--cal", files["cal6"]],
            "rimu ingest")
    refused(capsys, files["d"], ["calibrate", "turntable",
                                 files["imus"], "--out", files["d"] / "c.json"],
            "rimu calibrate in-flight")


def test_calibration_schema_error_names_the_written_version(files, capsys):
    refused(capsys, files["d"], ["monitor-file", files["flight6"], "--cal",
                                 files["flight6"] / "manifest.json"],
            f"expected '{CALIBRATION_SCHEMA}'")


def test_report_names_sensors_and_carries_units(files, tmp_path, capsys):
    capsys.readouterr()
    assert main(["monitor-file", str(files["flight6"]), "--cal", str(files["cal6"]),
                 "--report", str(tmp_path / "r.json")]) == 0
    rep = json.loads((tmp_path / "r.json").read_text())
    assert rep["units"]["magnitude"] == "rad/s" and rep["units"]["t"] == "s"
    from replay.report import format_report

    rep["events"] = [{"t": 1.0, "sensor": 3, "type": "isolated", "reason": "parity scale 1",
                      "statistic": 40.0, "threshold": 30.0}]
    assert f"sensor 3 ({rep['sensor_names'][2]})" in format_report(rep)


def _doc_commands() -> list[str]:
    """Every concrete ``rimu ...`` line in the code blocks of the docs (not synopses)."""
    out = []
    for p in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        fenced = False
        for line in p.read_text(encoding="utf-8").splitlines():
            if line.strip().startswith("```"):
                fenced = not fenced
                continue
            s = line.strip()
            if fenced and s.startswith("rimu ") and not any(c in s for c in "[<{|\\") \
                    and "..." not in s:
                out.append(s.split("#")[0].split(">")[0].strip())
    from rimu.cli import COMMANDS

    return [c for c in out if c.split()[1] in (*COMMANDS, "simulate")]


def test_every_command_line_of_the_docs_parses(capsys):
    from rimu.cli import build_parser

    cmds = _doc_commands()
    assert any(c.startswith("rimu diagnose e41") for c in cmds)
    bad = []
    for c in cmds:
        try:
            build_parser().parse_args(c.split()[1:])
        except SystemExit as exc:
            if exc.code:
                bad.append((c, capsys.readouterr().err.strip()))
    assert not bad, bad


# ----------------------------------------------------- (f) circle and the late frame ----
def _imports(path: Path) -> set[str]:
    mods = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.module:
            mods.add(node.module)
            mods.update(f"{node.module}.{a.name}" for a in node.names)
        elif isinstance(node, ast.Import):
            mods.update(a.name for a in node.names)
    return mods


def test_no_import_circle_in_the_command_layer():
    """No two command modules import each other, even inside functions."""
    d = ROOT / "rimu" / "commands"
    names = {p.stem: p for p in d.glob("*.py") if p.stem != "__init__"}
    graph = {n: {m.rsplit(".", 1)[-1] for m in _imports(p)
                 if m.startswith("rimu.commands.") and m.rsplit(".", 1)[-1] in names}
             for n, p in names.items()}

    def reach(a: str, seen: set[str]) -> set[str]:
        for b in graph[a] - seen:
            seen.add(b)
            reach(b, seen)
        return seen

    circles = sorted(a for a in graph if a in reach(a, set()))
    assert not circles, {a: graph[a] for a in circles}


def test_live_assembly_rejects_a_frame_of_an_emitted_sample(tmp_path):
    """A frame for a sample already handed over is counted ``late``, not used, and leaves
    that sample as it was emitted (its slot invalid)."""
    cal = synthetic_calibration("cone6", seed=5)
    f = simulate_flight(cal, 0.5, seed=2)
    write_flight_log(f, tmp_path / "f.log")
    msgs = list(can.LogReader(str(tmp_path / "f.log")))
    slot = msgs[0].arbitration_id
    idx = [i for i, m in enumerate(msgs) if m.arbitration_id == slot]
    late, gone, cut = idx[5], set(idx[5:14]), idx[13]   # slot 1 silent for samples 5..13
    db, cmap = resolve_map(cal)
    dec = StreamDecoder(db, cmap, cal.sample_rate_hz)
    out = []
    for i, m in enumerate(msgs[:cut]):
        if i not in gone:
            out += dec.feed(m)
    assert len(out) > 6                                  # sample 5 already handed over
    emitted5 = (out[5][1].copy(), out[5][2].copy())
    assert dec.feed(msgs[late]) == []
    for i, m in enumerate(msgs[cut:], cut):
        if i not in gone:
            out += dec.feed(m)
    out += dec.flush()
    acct = dec.acct.to_dict()
    assert acct["rejected"] == {"late": 1}
    assert acct["used"] == acct["read"] - 1 and acct["balanced"]
    assert len(out) == f.t.size
    assert not out[5][2][0] and not emitted5[1][0]
    np.testing.assert_array_equal(out[5][1], emitted5[0])


def test_logging_handler_is_installed_once():
    from rimu.cli import _log_to_stderr

    _log_to_stderr()
    _log_to_stderr()
    assert sum(getattr(h, "_rimu", False) for h in logging.getLogger("rimu").handlers) == 1


# ------------------------------------------------------------------ (g) start-up --------
def test_help_and_version_import_no_numerical_library():
    """``rimu --version`` and every ``rimu COMMAND --help`` build their parser without
    numpy, scipy or numba (the measured cost is in benchmarks/bench_startup.py)."""
    import subprocess
    import sys

    code = ("import sys\nfrom rimu.cli import COMMANDS, SIMULATE, main\n"
            "cmds = [[c] for c in COMMANDS] + [['simulate', c] for c in SIMULATE]\n"
            "main(['--version'])\n"
            "for c in cmds:\n    main([*c, '--help'])\n"
            "print(sorted(m for m in ('numpy', 'scipy', 'numba', 'fdi.monitor') "
            "if m in sys.modules))\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       env={**os.environ, "PYTHONPATH": str(ROOT)}, check=True)
    assert r.stdout.strip().splitlines()[-1] == "[]", r.stdout[-500:]


def test_choice_lists_kept_beside_the_parsers_agree_with_the_library():
    from calibration.calibrate import BIAS_METHODS, NOISE_MODELS
    from calibration.diagnose.library import candidates
    from calibration.inflight.fit import MODELS
    from replay.ingest.readers import FORMATS
    from rimu.commands import calibrate_effects, calibrate_inflight, calibrate_turntable, ingest

    assert calibrate_turntable.BIAS_METHODS == BIAS_METHODS
    assert calibrate_turntable.NOISE_MODELS == NOISE_MODELS
    assert calibrate_inflight.MODELS == MODELS and ingest.FORMATS == FORMATS
    assert calibrate_effects.EFFECT_NAMES == tuple(c.name for c in candidates())


def test_lazy_packages_export_what_they_list():
    import importlib

    import thresholds

    for pkg in ("fdi", "calibration", "replay", "thresholds"):
        m = importlib.import_module(pkg)
        assert set(m.__all__) == set(m._EXPORTS)      # order: ruff RUF022 checks it
        for name in m.__all__:
            assert getattr(m, name) is getattr(importlib.import_module(m._EXPORTS[name]), name)
    importlib.import_module("thresholds.tune")
    assert callable(thresholds.tune) and thresholds.tune.__name__ == "tune"   # not the module


@pytest.mark.slow
def test_first_kernel_compile_is_announced(tmp_path):
    """In a fresh process with an empty numba cache, the compile is announced once on
    stderr before it happens; a later process loading the cache, and a command that stops
    before running the monitor, say nothing."""
    import subprocess
    import sys

    from rimu import kernel_notice

    src = tmp_path / "src"                  # a copy without fdi/__pycache__: a fresh install
    for pkg in ("fdi", "rimu", "replay", "calibration", "thresholds"):
        shutil.copytree(ROOT / pkg, src / pkg, ignore=shutil.ignore_patterns("__pycache__"))
    cal = synthetic_calibration("tetrad", seed=1)
    cal.save(tmp_path / "cal.json")
    save_flight_dir(simulate_flight(cal, 0.2, seed=1), tmp_path / "fl")
    env = {**os.environ, "PYTHONPATH": str(src), "NUMBA_CACHE_DIR": str(tmp_path / "nb"),
           "HOME": str(tmp_path)}
    run = ["monitor-file", str(tmp_path / "fl"), "--cal", str(tmp_path / "cal.json")]

    def rimu(*argv):
        return subprocess.run([sys.executable, "-m", "rimu", *argv], capture_output=True,
                              text=True, env=env, cwd=tmp_path, timeout=600)

    (tmp_path / "bad.json").write_text("{")
    r = rimu(*run, "--thresholds", str(tmp_path / "bad.json"))  # stops before the monitor runs
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    r = rimu(*run)
    assert r.returncode == 0, r.stderr
    assert r.stderr.count(kernel_notice.MESSAGE) == 1, r.stderr
    r = rimu(*run)
    assert r.returncode == 0 and kernel_notice.MESSAGE not in r.stderr, r.stderr


def test_roc_detection_counts_a_passage_after_an_earlier_false_alarm():
    """A run whose statistic passed before the onset and again after it is a false alarm
    and a detection: lowering the thresholds never lowers the ROC's P(detect)."""
    import math

    from thresholds.campaign import ROC_MULTIPLIERS, RunResult, RunSpec
    from thresholds.evaluate import _roc_point

    k = len(ROC_MULTIPLIERS)
    spec = RunSpec(0, 1, "step", 1.0, 5.0, 1, 30.0, 60.0, 300.0)
    early = RunResult(spec, 10.0, True, True, 0.1, 1, tuple([10.0] * k),
                      roc_detect=tuple([30.1] * k))
    clean = RunResult(spec, 30.0, False, True, 0.1, 1, tuple([30.1] * k),
                      roc_detect=tuple([30.1] * k))
    miss = RunResult(spec, 30.0, False, False, math.nan, 0, tuple([math.inf] * k),
                     roc_detect=tuple([math.inf] * k))
    pts = [_roc_point([early, clean, miss], j) for j in range(k)]
    assert all(p["pd_step_ramp"] == 2 / 3 for p in pts)
    assert all(p["false_alarms"] == 1 for p in pts)


def test_detectable_size_of_separated_runs_is_a_bracket_not_a_point():
    """Every miss below every hit: no probit maximum; the runs' bracket is reported, not a
    degenerate '3.06 [3.06, 3.06]'."""
    import math

    from thresholds.evaluate import _probit_b99

    sizes = np.repeat([2.0, 2.5, 3.0, 3.5, 4.0], 4)
    hits = (sizes >= 3.0).astype(float)
    b, lo, hi = _probit_b99(sizes, hits)
    assert math.isnan(b) and (lo, hi) == (2.5, 3.0)
    rng = np.random.default_rng(1)
    sizes = np.repeat(np.linspace(1.0, 5.0, 9), 20)
    hits = (rng.normal(sizes, 0.6) > 3.0).astype(float)
    b, lo, hi = _probit_b99(sizes, hits)
    assert lo < b < hi and hi - lo > 0.05


def test_tune_names_the_worst_sensor_and_writes_a_normal_file(files, tmp_path, capsys):
    import re

    capsys.readouterr()
    out = tmp_path / "t.json"
    assert main(["tune", "--cal", str(files["cal6"]), "--false-alarms-per-hour", "1",
                 "--simulate-hours", "0", "--no-progress", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    from fdi.calfile import load_calibration

    names = [c.name for c in load_calibration(files["cal6"]).gyro.sensors]
    m = re.search(r"worst sensor (\d+) \((\S+)\)", text)
    assert m and names[int(m.group(1)) - 1] == m.group(2), text
    assert stat.S_IMODE(out.stat().st_mode) == 0o666 & ~_umask()


def _umask() -> int:
    m = os.umask(0)
    os.umask(m)
    return m


def test_evaluate_states_the_sweep_runs(files, tmp_path, capsys):
    """--runs 2 with the default sweep runs more than 2: the output says how many and why."""
    capsys.readouterr()
    assert main(["evaluate", "--cal", str(files["cal6"]), "--runs", "2", "--sweep-runs", "4",
                 "--duration", "2", "--no-progress", "--out", str(tmp_path / "ev")]) == 0
    out = capsys.readouterr().out
    assert "6 runs (2 flights + 4 sweep runs" in out, out
    assert "(2 flights + 4 sweep runs" in (tmp_path / "ev" / "summary.md").read_text()


def test_evaluate_and_diagnose_leave_nothing_when_a_late_write_fails(files, tmp_path,
                                                                     monkeypatch, capsys):
    """A failure while the outputs are written (the plots, the report page) leaves neither
    the folder nor the files written before it."""
    from importlib import import_module

    def broken(*a, **k):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(import_module("thresholds.plots"), "plot_all", broken)
    refused(capsys, tmp_path, ["evaluate", "--cal", files["cal6"], "--runs", "1",
                               "--sweep-runs", "0", "--duration", "2", "--no-progress",
                               "--out", tmp_path / "ev"], "No space left")
    cal = tmp_path / "in" / "cal.json"
    cal.parent.mkdir()
    assert main(["calibrate", "turntable", str(files["sess"]), "--out", str(cal)]) == 0
    monkeypatch.setattr(import_module("calibration.diagnose.report"), "write_report", broken)
    refused(capsys, tmp_path, ["diagnose", files["sess"], "--cal", cal, "--out",
                               tmp_path / "refit.json", "--report", tmp_path / "rep"],
            "No space left")


def test_loading_a_calibration_does_not_import_scipy_stats():
    """Loading a calibration (and ingest's envelope summary) needs no scipy.stats (0.35 s of
    start-up: ingest of flight 41 rose to 2.5x a bare pymavlink pass with it)."""
    import subprocess
    import sys

    code = ("import sys\nimport fdi.calfile, replay.envelope\n"
            "print('scipy.stats' in sys.modules)\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       env={**os.environ, "PYTHONPATH": str(ROOT)}, check=True)
    assert r.stdout.strip() == "False", r.stdout
