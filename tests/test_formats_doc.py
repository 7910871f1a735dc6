"""Every example of docs/formats.md loads with its loader (the page cannot rot silently).

An example is a fenced block right after a ``<!-- example: PATH -->`` line; the block is
written to ``tmp/PATH`` and the folder or file is read by rimu's loader.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from calibration.sequence import load_sequence
from calibration.session_io import load_session
from fdi.errors import FileFormatError
from fdi.geometry import load_configuration
from fdi.settings import load_thresholds
from replay.channel_map import check_against_calibration, load_channel_map
from replay.flight import load_flight_dir
from replay.scenario import load_scenario
from studies.synthetic import synthetic_calibration

DOC = Path(__file__).resolve().parents[1] / "docs" / "formats.md"
_BLOCK = re.compile(r"<!-- example: (?P<path>[^ ]+) -->\n```[a-z]*\n(?P<body>.*?)```",
                    re.DOTALL)


@pytest.fixture(scope="module")
def examples(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("formats")
    found = _BLOCK.findall(DOC.read_text(encoding="utf-8"))
    assert len(found) == 9, [p for p, _ in found]
    for rel, body in found:
        p = d / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(body, encoding="utf-8")
    return d


def test_configuration(examples):
    cfg = load_configuration(examples / "pentad.toml")
    assert cfg.name == "pentad" and cfg.n == 5 and cfg.sensor_names[3] == "d"
    assert len(cfg.groups) == 2
    np.testing.assert_allclose(np.linalg.norm(cfg.H, axis=1), 1.0)


def test_sequence(examples):
    seq = load_sequence(examples / "sequence.toml")
    assert len(seq.steps) == 3 and seq.table_rate_dps == 20.0
    assert len(seq.rate_steps()) == 2 and len(seq.position_steps()) == 1


def test_session_folder(examples):
    s = load_session(examples / "session")
    assert s.t.size == 20 and len(s.steps) == 2 and s.gyro_raw_unit == "mV"
    assert s.meta["operator"] == "bench 2"


def test_flight_folder(examples):
    f = load_flight_dir(examples / "flight")
    assert f.n == 4 and f.t.size == 5 and f.raw_unit == "mV"
    assert not f.valid[2, 1] and np.isnan(f.raw[2, 1])      # empty cell: no sample
    assert f.valid[4, 3] and np.isnan(f.raw[4, 3])          # nan: a value sent
    (ev,) = f.events
    assert ev.category == "crash" and ev.t_s == 0.02 and ev.t_end_s == float("inf")


def test_channel_map_and_scenario_against_a_tetrad_calibration(examples):
    cal = synthetic_calibration("tetrad", raw_unit="mV")
    cmap = load_channel_map(examples / "channel_map.toml")
    assert cmap.n == 4 and cmap.uses_sample_counter
    check_against_calibration(cmap, cal)
    from replay.effect_inputs import map_available

    assert [a.quantity for a in cmap.auxiliary] == ["temperature"] + ["specific_force"] * 3
    assert cmap.auxiliary[3].to_si == (9.80665, 0.0)
    assert map_available(cmap) == {"specific_force": [0, 1, 2, 3],
                                   "temperature": [0, 1, 2, 3]}
    faults, seed = load_scenario(examples / "scenario.toml", cal)
    assert seed == 7 and [f.kind for f in faults] == ["step", "ramp"]
    assert faults[0].sensor == 3 and faults[0].onset == 2.0


def test_thresholds(examples):
    thr = load_thresholds(examples / "thresholds.json")
    assert thr.scales == (1, 4, 16) and thr.n == 4 and thr.detector == "windows"


def test_a_typo_in_an_example_is_refused(examples, tmp_path):
    """The page promises unknown keys are refused: check it on its own example."""
    text = (examples / "channel_map.toml").read_text().replace("axis_nominal", "axis_nomnal")
    p = tmp_path / "typo.toml"
    p.write_text(text)
    with pytest.raises(FileFormatError, match=r"axis_nomnal.*did you mean 'axis_nominal'"):
        load_channel_map(p)
