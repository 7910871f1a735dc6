"""replay.plots: a monitoring run's picture, in bounded memory, with no display; and the
rerun recording's parity entity finite on every path (block, stepwise, paced)."""

import numpy as np
import pytest
from test_logio import CAL

from fdi.monitor import Monitor
from replay.faults import parse_fault
from replay.flight import simulate_flight
from replay.plots import RunTrace, plot_run, spans
from replay.report import RunningReport


@pytest.fixture(scope="module")
def run():
    f = simulate_flight(CAL, 6.0, seed=5, faults=(parse_fault("step:4:60sigma:2", CAL),
                                                  parse_fault("ramp:2:2sigma/s:3", CAL)))
    mon = Monitor(CAL)
    return f, mon, mon.run(f.t, f.raw, f.valid, parity=True)


def _piece(res, a, b):
    from fdi.answer import BlockResult

    return BlockResult(t=res.t[a:b], omega=res.omega[a:b], omega_sd=res.omega_sd[a:b],
                       healthy=res.healthy[a:b], statistics=res.statistics[a:b],
                       thresholds=res.thresholds[a:b],
                       protection_level=res.protection_level[a:b],
                       capability=res.capability[a:b], events=[],
                       unverified=None if res.unverified is None else res.unverified[a:b],
                       envelope=None if res.envelope is None else res.envelope[a:b])


@pytest.mark.parametrize("max_bins", [8, 64])
def test_trace_in_pieces_equals_trace_at_once_and_stays_bounded(run, max_bins):
    _, _, res = run
    N = res.t.size
    whole = RunTrace(max_bins=max_bins)
    whole.update(res)
    rng = np.random.default_rng(1)
    cuts = np.sort(rng.choice(np.arange(1, N), size=40, replace=False))
    parts = RunTrace(max_bins=max_bins)
    for a, b in zip(np.r_[0, cuts], np.r_[cuts, N], strict=True):
        parts.update(_piece(res, a, b))
    bw, bp = whole.bins(), parts.bins()
    assert whole.per_bin == parts.per_bin and whole.per_bin >= N / max_bins
    assert bw["t0"].size <= max_bins
    for k in ("t0", "t1", "mean", "min", "max", "unverified", "ratio"):
        np.testing.assert_allclose(bp[k], bw[k], rtol=1e-12, equal_nan=True, err_msg=k)
    # nothing lost by binning: extremes, first and last time, unverified time
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = res.statistics / res.thresholds
    np.testing.assert_allclose(np.nanmax(bw["ratio"], axis=0), np.nanmax(ratio, axis=0))
    np.testing.assert_allclose(bw["max"].max(axis=0), np.nanmax(res.omega, axis=0) * 180 / np.pi)
    assert bw["t0"][0] == res.t[0] and bw["t1"][-1] == res.t[-1]
    unv = np.asarray(res.unverified, bool).any(axis=1)
    assert unv.any(), "the scenario has unverified samples"
    for a, z in spans(res.t, res.t, unv):
        inside = (bw["t1"] >= a) & (bw["t0"] <= z)
        assert bw["unverified"].any(axis=1)[inside].all()


def test_picture_of_a_run_without_a_display(run, tmp_path, monkeypatch):
    f, _, res = run
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    acc = RunningReport()
    acc.update(res, f.omega_true)
    rep = acc.build(f, CAL)
    assert any(e["type"] == "isolated" for e in rep["events"]) and rep["faults"]
    p = plot_run(acc.trace, tmp_path / "run.png", report=rep)
    import matplotlib.image

    img = matplotlib.image.imread(p)
    assert img.shape[0] > 500 and img.shape[1] > 800
    # the unverified spans are shaded (gold over white: high red and green, low blue)
    rgb = img[..., :3]
    gold = (rgb[..., 0] > 0.95) & (rgb[..., 1] > 0.85) & (rgb[..., 2] < 0.75)
    assert gold.sum() > 2000


def _parity_rows(path):
    import rerun.chunk

    rows = []
    for ch in rerun.chunk.RrdReader(path).stream():
        if str(ch.entity_path) == "/parity" and not ch.is_static:
            rb = ch.to_record_batch()
            rows += rb.column("Scalars:scalars").to_pylist()
    return np.array([r for r in rows if r is not None], float)


def test_recording_parity_finite_on_the_block_path(run, tmp_path):
    from replay.rerun_log import record

    f, mon, res = run
    record(res, f, CAL, path=tmp_path / "a.rrd", thresholds=mon.thresholds)
    par = _parity_rows(tmp_path / "a.rrd")
    assert par.shape[0] == f.t.size
    before = f.t < 2.0                           # every sensor in: all components finite
    assert np.isfinite(par[before]).all()
    assert np.isfinite(par).any(axis=1).mean() > 0.99


@pytest.mark.parametrize("how", ["block", "realtime"])
def test_replay_rrd_parity_finite(tmp_path, how):
    """``rimu replay --rrd`` (chain block path; ``--realtime``: paced, sample by sample)."""
    from replay.can_write import write_flight_log
    from rimu.cli import main

    f = simulate_flight(CAL, 1.5, seed=25)
    log = tmp_path / "a.trc"
    write_flight_log(f, log)
    rrd = tmp_path / "a.rrd"
    extra = ["--realtime"] if how == "realtime" else []
    cal = tmp_path / "cal.json"
    CAL.save(cal)
    assert main(["replay", str(log), "--cal", str(cal), "--rrd", str(rrd),
                 "--no-progress", "--report", str(tmp_path / "r.json"), *extra]) == 0
    par = _parity_rows(rrd)
    assert par.shape[0] >= f.t.size - 2 and np.isfinite(par).all()
    assert (tmp_path / "r.png").stat().st_size > 10_000
