"""rerun recordings: written headless, verified and read back with rerun's own CLI."""

import re
import subprocess
import sys
from collections import defaultdict

import numpy as np
import pytest
from test_logio import CAL

from fdi.monitor import Monitor
from replay.faults import parse_fault
from replay.flight import simulate_flight
from replay.rerun_log import ENTITIES, record


def _rerun(*args):
    return subprocess.run([sys.executable, "-m", "rerun", *args], capture_output=True,
                          text=True, timeout=120)


def _entity_rows(path):
    out = _rerun("rrd", "print", str(path)).stdout
    rows: dict = defaultdict(int)
    rows["text"] = out
    for m in re.finditer(r"with (\d+) rows \([^)]*\) - (/\S+) - data columns: \[([^\]]*)\]",
                         out):
        rows[(m.group(2), m.group(3))] += int(m.group(1))
    return rows


@pytest.fixture(scope="module")
def run():
    f = simulate_flight(CAL, 4.0, seed=12, faults=(parse_fault("step:4:60sigma:2", CAL),))
    mon = Monitor(CAL)
    return f, mon, mon.run(f.t, f.raw, f.valid)


def test_recording_written_verified_and_holds_the_entities(tmp_path, run):
    f, mon, res = run
    assert any(e.type == "isolated" for e in res.events)
    p = tmp_path / "r.rrd"
    tim = record(res, f, CAL, path=p, thresholds=mon.thresholds)
    assert tim["rows"] == f.t.size and p.stat().st_size > 0
    v = _rerun("rrd", "verify", str(p))
    assert v.returncode == 0, v.stderr
    rows = _entity_rows(p)
    N = f.t.size
    for ent in [e for e in ENTITIES if e != "events"] + ["omega/truth", "omega/error"]:
        assert rows[(f"/{ent}", "Scalars:scalars")] == N, ent
    for w in mon.thresholds.scales:
        assert rows[(f"/detector/scale_{w}", "Scalars:scalars")] == N, f"scale {w}"
    n_text = sum(r for k, r in rows.items() if k[0] == "/events" and "TextLog" in k[1])
    assert n_text == len(res.events)
    # the blueprint is in the file
    assert "ViewportBlueprint" in rows["text"] and "ContainerBlueprint" in rows["text"]


def test_recording_without_truth_or_events(tmp_path):
    f = simulate_flight(CAL, 1.0, seed=13)
    f = type(f)(**{**f.__dict__, "omega_true": None})
    res = Monitor(CAL).run(f.t, f.raw, f.valid)
    p = tmp_path / "q.rrd"
    record(res, f, CAL, path=p)
    rows = _entity_rows(p)
    assert ("/omega/truth", "Scalars:scalars") not in rows
    assert rows[("/omega/estimate", "Scalars:scalars")] == f.t.size
    assert np.isfinite(res.omega).all()
