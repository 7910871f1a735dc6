"""Installs that fit the job: the core (``pip install rimu``) calibrates, monitors and
replays; the optional packages come with extras, and a command that reaches a missing one
says which extra in one line (exit 2). Missing packages are simulated by hiding them
(``sys.modules[name] = None`` in a fresh process), not by uninstalling."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from rimu.optional import EXTRAS

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("fdi", "calibration", "thresholds", "replay", "rimu")
CONF = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
_HIDE = """
import sys
for m in sys.argv[1].split(","):
    if m:
        sys.modules[m] = None
from rimu.cli import main
raise SystemExit(main(sys.argv[2:]))
"""


def _rimu(hide: tuple[str, ...], *args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-c", _HIDE, ",".join(hide), *args], cwd=cwd,
                          env=env, capture_output=True, text=True, timeout=600)


def _name(requirement: str) -> str:
    return re.split(r"[<>=!~\[; ]", requirement, maxsplit=1)[0].lower()


def test_extras_of_pyproject_are_the_optional_packages():
    """Every package of :data:`rimu.optional.EXTRAS` is in the extra it names and not in
    the core; ``all`` and ``dev`` bring every extra."""
    core = {_name(r) for r in CONF["project"]["dependencies"]}
    extras = CONF["project"]["optional-dependencies"]
    for module, (extra, dist) in EXTRAS.items():
        assert dist.lower() not in core, f"{dist} is optional ({extra}) but in the core"
        assert dist.lower() in {_name(r) for r in extras[extra]}, (module, extra)
    named = {extra for extra, _ in EXTRAS.values()}
    assert set(extras) == named | {"all", "dev"}
    assert any(r.startswith("rimu[") and all(e in r for e in named) for r in extras["all"])
    assert any(r.startswith("rimu[all]") for r in extras["dev"])


def _one_line_naming(p: subprocess.CompletedProcess, extra: str, dist: str) -> None:
    lines = p.stderr.strip().splitlines()
    assert p.returncode == 2, p.stderr[-2000:]
    assert len(lines) == 1 and "Traceback" not in p.stderr, p.stderr[-2000:]
    assert lines[0].startswith("rimu: error: ") and dist in lines[0]
    assert f'pip install "rimu[{extra}]"' in lines[0]


_RDA_MAP = ('schema = "rimu.ingest-map/1"\n[time]\nrate_hz = 100.0\n[[imus]]\n'
            'gyro = ["Gyro. X", "Gyro. Y", "Gyro. Z"]\ngyro_unit = "deg/s"\n')


@pytest.mark.parametrize(("suffix", "dist"), [(".BIN", "pymavlink"), (".ulg", "pyulog"),
                                              (".rda", "rdata")])
def test_ingest_names_the_logs_extra(tmp_path, suffix, dist):
    log = tmp_path / f"flight{suffix}"
    log.write_bytes(b"\x00" * 64)
    extra = []
    if suffix == ".rda":                     # R data carry no units: the map comes first
        (tmp_path / "m.toml").write_text(_RDA_MAP, encoding="utf-8")
        extra = ["--map", str(tmp_path / "m.toml")]
    p = _rimu((dist,), "ingest", str(log), *extra, "--out", str(tmp_path / "out"),
              cwd=tmp_path)
    _one_line_naming(p, "logs", dist)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("args", [
    ("evaluate", "--cal", "cal.json", "--runs", "2", "--out", "ev"),
    ("diagnose", "session", "--cal", "cal.json", "--report", "rep"),
    ("characterise", "flight", "--report", "rep"),
    ("calibrate", "turntable", "session", "--out", "cal2.json", "--plot", "rep"),
    ("calibrate", "in-flight", "flight", "--out", "cal2.json", "--report", "rep"),
    ("monitor-file", "flight", "--cal", "cal.json", "--baseline", "px4",
     "--baseline-plot", "b.png"),
], ids=lambda a: " ".join(a[:2]))
def test_figures_name_the_plots_extra_before_any_work(tmp_path, args):
    """A command that would draw figures at the end of its work is refused before it
    starts: nothing is written."""
    p = _rimu(("matplotlib",), *args, cwd=tmp_path)
    _one_line_naming(p, "plots", "matplotlib")
    assert list(tmp_path.iterdir()) == []


def test_a_dask_scheduler_names_the_fleet_extra(tmp_path):
    p = _rimu(("distributed", "dask"), "evaluate", "--cal", "cal.json", "--runs", "2",
              "--scheduler", "local", "--out", "ev", cwd=tmp_path)
    _one_line_naming(p, "fleet", "distributed")


def test_every_command_module_loads_without_the_extras(tmp_path):
    """``rimu --help`` builds every command's parser (imports every command module) with
    all optional packages hidden."""
    p = _rimu(tuple(EXTRAS), "--help", cwd=tmp_path)
    assert p.returncode == 0 and "usage: rimu" in p.stdout, p.stderr[-2000:]
    assert "export" in p.stdout and "ingest" in p.stdout and "evaluate" in p.stdout


@pytest.mark.slow
def test_demo_runs_on_the_core(tmp_path):
    """``rimu demo`` with every optional package hidden: the core path (calibrate,
    thresholds, simulate, CAN log, replay, rerun recording) needs no extra."""
    p = _rimu(tuple(EXTRAS), "demo", "--out", str(tmp_path / "d"), "--duration", "40",
              cwd=tmp_path)
    assert p.returncode == 0, p.stderr[-3000:]
    written = {f.name for f in (tmp_path / "d").iterdir()}
    assert {"cal.json", "thresholds.json", "flight.blf", "report.json",
            "replay.rrd"} <= written
