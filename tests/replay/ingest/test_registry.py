"""The log-format registry: built-in formats and third parties' through the
``rimu.log_readers`` entry points; the CLI's ``--format`` list is the registry's."""

from __future__ import annotations

import argparse
import logging
import textwrap
from importlib import metadata

import numpy as np
import pytest

from fdi.errors import ConfigError
from replay.ingest import registry
from replay.ingest.readers import detect_format, read_any

PLUGIN = textwrap.dedent('''
    """A toy log format: a text file 'TOYLOG' then rows t gx gy gz (rad/s)."""
    from pathlib import Path

    import numpy as np

    from replay.ingest import ImuStream, LogFormat, LogRead


    def sniff(path):
        try:
            with open(path, "rb") as fh:
                return fh.read(6) == b"TOYLOG"
        except OSError:
            return False


    def read(path, *, salvage=False, map_path=None):
        rows = np.loadtxt(path, skiprows=1, ndmin=2)
        s = ImuStream("imu1", rows[:, 0], rows[:, 1:4], source="toy")
        return LogRead(str(path), "toy", (s,), meta={"map": map_path, "salvage": salvage})


    NOT_A_FORMAT = {"name": "bad"}
    FORMAT = LogFormat("toy", read, (".toy",), sniff, options=("map_path",),
                       description="toy text log")
    ''')


def _ep(name: str, value: str) -> metadata.EntryPoint:
    return metadata.EntryPoint(name=name, value=value, group=registry.ENTRY_POINT_GROUP)


@pytest.fixture
def plugins(monkeypatch, tmp_path):
    """Install ``rimu_toy_plugin`` and make the metadata list the given entry points; the
    registry is reset before and after."""
    (tmp_path / "rimu_toy_plugin.py").write_text(PLUGIN, encoding="utf-8")
    monkeypatch.syspath_prepend(str(tmp_path))

    def install(*eps: metadata.EntryPoint) -> None:
        real = metadata.entry_points

        def fake(**kw):
            if kw.get("group") == registry.ENTRY_POINT_GROUP:
                return metadata.EntryPoints(eps)
            return real(**kw)

        monkeypatch.setattr(registry.metadata, "entry_points", fake)
        monkeypatch.setattr(registry, "_FORMATS", {f.name: f for f in registry.BUILTIN})
        monkeypatch.setattr(registry, "_LOADED", False)

    monkeypatch.setattr(registry, "_FORMATS", {f.name: f for f in registry.BUILTIN})
    monkeypatch.setattr(registry, "_LOADED", False)
    return install


def _toy_log(path, n=50):
    t = np.arange(n) / 100.0
    rows = np.column_stack([t, 0.01 * np.ones(n), -0.02 * np.ones(n), np.zeros(n)])
    rows[10, 3] = 100.0                    # rad/s: beyond twice any gyro's range
    path.write_text("TOYLOG\n" + "\n".join(" ".join(f"{v:.6f}" for v in r) for r in rows))
    return path


def test_builtin_formats_are_the_registry():
    assert registry.FORMATS == ("auto", "ardupilot", "px4", "mat", "csv", "rda")
    assert [f.name for f in registry.BUILTIN] == list(registry.FORMATS[1:])
    suffix = {s: f.name for f in registry.BUILTIN for s in f.suffixes}
    assert suffix == {".bin": "ardupilot", ".ulg": "px4", ".mat": "mat", ".csv": "csv",
                      ".rda": "rda", ".rdata": "rda"}
    assert [f.name for f in registry.BUILTIN if f.sniffer] == ["ardupilot", "px4"]
    assert {f.name for f in registry.BUILTIN if "map_path" in f.options} == \
        {"mat", "csv", "rda"}


def test_extras_named_by_the_registry_are_those_of_rimu_optional():
    from rimu.optional import EXTRAS

    assert {f.extra for f in registry.BUILTIN if f.extra} <= {e for e, _ in EXTRAS.values()}


def test_entry_point_reader_is_found_and_reads(plugins, tmp_path):
    plugins(_ep("toy", "rimu_toy_plugin:FORMAT"))
    assert registry.format_names() == (*registry.FORMATS, "toy")
    assert [f.name for f in registry.log_formats()][-1] == "toy"
    log = _toy_log(tmp_path / "flight.dat")           # no suffix: found by its sniffer
    assert detect_format(log) == "toy"
    (tmp_path / "b.toy").write_text("no header")      # no header: found by its suffix
    assert detect_format(tmp_path / "b.toy") == "toy"
    read = read_any(log, map_path=tmp_path / "m.toml")
    assert read.format == "toy" and read.streams[0].size == 50
    assert read.meta["map"] == tmp_path / "m.toml" and read.meta["salvage"] is False
    np.testing.assert_allclose(read.streams[0].gyro[:, 1], -0.02)
    # the same checks as a built-in reader: the implausible sample is marked
    assert read.meta["implausible"]["imu1"]["gyro"]["samples"] == 1
    assert np.isnan(read.streams[0].gyro[10, 2])


def test_entry_point_reader_is_a_cli_choice(plugins, tmp_path):
    from rimu.commands import ingest, inspect

    plugins(_ep("toy", "rimu_toy_plugin:FORMAT"))
    for mod in (ingest, inspect):
        p = argparse.ArgumentParser()
        mod.configure(p)
        action = next(a for a in p._actions if a.dest == "format")
        assert tuple(action.choices) == registry.format_names()
        assert "toy" in action.choices and "toy" in action.help


def test_cli_format_list_equals_the_registry():
    from rimu.commands import ingest, inspect

    for mod in (ingest, inspect):
        p = argparse.ArgumentParser()
        mod.configure(p)
        action = next(a for a in p._actions if a.dest == "format")
        assert tuple(action.choices) == registry.format_names()
        for f in registry.log_formats():
            assert f.name in action.help
            for s in f.suffixes:
                assert s in action.help


@pytest.mark.parametrize("value, why", [
    ("rimu_toy_plugin:nothing_here", "cannot load"),
    ("rimu_toy_plugin:NOT_A_FORMAT", "a dict, not a replay.ingest.LogFormat"),
])
def test_broken_entry_point_is_skipped_with_its_name(plugins, caplog, value, why):
    plugins(_ep("bad", value), _ep("toy", "rimu_toy_plugin:FORMAT"))
    with caplog.at_level(logging.WARNING, logger="rimu"):
        names = [f.name for f in registry.log_formats()]
    assert names == [*registry.FORMATS[1:], "toy"]
    assert "'bad'" in caplog.text and why in caplog.text


def test_entry_point_named_otherwise_or_like_a_builtin_is_skipped(plugins, caplog):
    plugins(_ep("other", "rimu_toy_plugin:FORMAT"), _ep("csv", "rimu_toy_plugin:FORMAT"))
    with caplog.at_level(logging.WARNING, logger="rimu"):
        names = [f.name for f in registry.log_formats()]
    assert names == list(registry.FORMATS[1:])
    assert "not 'other'" in caplog.text
    assert registry.get_format("csv") is registry.BUILTIN[3]


def test_register_format_in_process(plugins, tmp_path):
    plugins()
    import rimu_toy_plugin

    registry.register_format(rimu_toy_plugin.FORMAT)
    assert read_any(_toy_log(tmp_path / "x.toy"), "toy").format == "toy"
    with pytest.raises(ConfigError, match="built-in"):
        registry.register_format(registry.LogFormat("csv", rimu_toy_plugin.read))
    with pytest.raises(ConfigError, match="expected a LogFormat"):
        registry.register_format("toy")


def test_unknown_and_undetectable_formats_are_refused(tmp_path):
    log = tmp_path / "x.xyz"
    log.write_bytes(b"nothing")
    with pytest.raises(ConfigError, match=r"unknown format 'mcap'; expected one of auto, "
                                          r"ardupilot, px4, mat, csv, rda"):
        read_any(log, "mcap")
    with pytest.raises(ConfigError, match=r"cannot tell the log format \(suffix '.xyz'\); "
                                          r"give --format one of ardupilot, px4, mat, csv, rda"):
        read_any(log)
    log.write_bytes(b"\xa3\x95\x80")                     # a DataFlash header wins the suffix
    with pytest.raises(ConfigError, match=r"--map is for mat, csv and rda logs, not ardupilot"):
        read_any(log, map_path=tmp_path / "m.toml")


def test_bad_entries_are_refused():
    with pytest.raises(ConfigError, match="not 'auto'"):
        registry.LogFormat("auto", "m:f")
    with pytest.raises(ConfigError, match="unknown option"):
        registry.LogFormat("x", "m:f", options=("topic",))
    with pytest.raises(ConfigError, match="lower case"):
        registry.LogFormat("x", "m:f", suffixes=("BIN",))
