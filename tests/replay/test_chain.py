"""One monitoring chain (replay.chain) and one timing model (replay.time_offsets), issue 17
items 4 and 5; files that cannot be mixed up (issue 19).

- the causal stream aligner gives the whole-flight alignment's samples bit for bit, for any
  piece sizes, with positive and negative offsets;
- a simulated two-IMU flight with a known lag, written as a CAN log and replayed in small
  pieces, gives the answers of ``monitor-file``'s chain on the same (decoded) samples
  exactly, and those of the flight folder itself (float64, not the log's float32) within a
  stated tolerance; with the offsets the monitor is in alarm far less of the time;
- ``rimu replay`` with a calibration of another set is refused in one line naming both files;
- thresholds made for another sample rate or calibration are refused, an old file without a
  fingerprint is accepted with one warning line.
"""

from __future__ import annotations

import dataclasses
import logging
import types
from dataclasses import replace

import numpy as np
import pytest

from calibration.inflight.calfile import calibration_from_fit
from calibration.inflight.fit import fit_inflight
from fdi.errors import ConfigError
from replay.can_write import write_flight_log
from replay.chain import ChainOptions, chain_for_flight, chain_for_map, report_log, run_flight
from replay.flight_data import concat_flights
from replay.imu_set import ImuSetSpec, simulate_imu_set
from replay.logio import LogStream, read_log, resolve_map
from replay.threshold_choice import check_made_for
from replay.time_offsets import StreamAligner, apply_time_offsets, imu_groups
from rimu.cli import main
from thresholds.compute import compute_thresholds

TAU_S = -0.010          # imu2 sees the motion 10 ms late (in-flight model y2(t) = y1(t + τ))


@pytest.fixture(scope="module")
def lagged():
    """A 20 s two-IMU flight at 50 Hz with a 10 ms lag and its in-flight calibration."""
    f = simulate_imu_set(ImuSetSpec(imus=2, duration_s=20, seed=1, time_offset_s=(0.0, TAU_S)))
    cal = calibration_from_fit(fit_inflight(f), f)
    return f, cal


def _split(f, sizes):
    """The flight in consecutive pieces of the given sizes (cycled)."""
    out, k, j = [], 0, 0
    N = f.t.shape[0]
    while k < N:
        m = sizes[j % len(sizes)]
        rows = slice(k, min(N, k + m))
        out.append(replace(f, t=f.t[rows], raw=f.raw[rows], valid=f.valid[rows],
                           omega_true=None if f.omega_true is None else f.omega_true[rows],
                           aux=None if f.aux is None else f.aux.slice(rows)))
        k += m
        j += 1
    return out


@pytest.mark.parametrize("tau", [TAU_S, 0.013])
@pytest.mark.parametrize("sizes", [(1,), (7, 1, 64), (5000,)])
def test_stream_aligner_equals_the_whole_flight_alignment(lagged, tau, sizes):
    f, cal = lagged
    imus = dict(cal.extra["inflight"]["imus"])
    imus["imu2"] = {**imus["imu2"], "time_offset_ms": 1e3 * tau}
    cal = replace(cal, extra={**cal.extra, "inflight": {**cal.extra["inflight"],
                                                        "imus": imus}})
    f = replace(f, valid=f.valid.copy())
    f.valid[100:103, 4] = False                       # a gap next to which nothing is made up
    whole, applied = apply_time_offsets(f, cal)
    assert applied == {"imu2": pytest.approx(1e3 * tau)}
    al = StreamAligner(cal, imu_groups(f.sensor_names, f.imu))
    assert al.delay_s == pytest.approx(max(-tau, 0.0))
    out = [al.push(p) for p in _split(f, sizes)] + [al.flush()]
    out = [p for p in out if p is not None]
    for name in ("t", "raw", "valid"):
        np.testing.assert_array_equal(np.concatenate([getattr(p, name) for p in out]),
                                      getattr(whole, name), err_msg=name)
    np.testing.assert_array_equal(np.concatenate([p.aux.values for p in out]),
                                  whole.aux.values)
    np.testing.assert_array_equal(np.concatenate([p.omega_true for p in out]),
                                  whole.omega_true)
    assert (~whole.valid[:, 3:]).sum() > 3            # the moved IMU lost samples at the edge
    np.testing.assert_array_equal(whole.raw[:, :3], f.raw[:, :3])   # the reference did not


def _stream_report(path, cal, *, offsets=True, chunk=997):
    db, cmap = resolve_map(cal)
    st = LogStream(path, cal, db, cmap, progress=False, chunk_frames=chunk)
    ch = chain_for_map(cal, cmap, ChainOptions(time_offsets=offsets))
    results = []
    feed = ch.feed

    def keep(piece, **kw):
        r = feed(piece, **kw)
        if r is not None:
            results.append(r)
        return r

    ch.feed = keep
    fin = ch.finish
    ch.finish = lambda **kw: results.append(fin(**kw)) or results[-1]
    rep = report_log(ch, st, st.header)
    return [r for r in results if r is not None], rep, ch


def _in_alarm(results):
    st = np.concatenate([r.statistics for r in results])
    th = np.concatenate([r.thresholds for r in results])
    return float(np.mean(np.any(st > th, axis=1)))


def test_replay_applies_the_offsets_as_monitor_file_does(lagged, tmp_path):
    f, cal = lagged
    log = tmp_path / "lagged.log"
    write_flight_log(f, log)
    pieces, rep, ch = _stream_report(log, cal)
    assert len(pieces) > 3 and rep["time_offsets_applied_ms"] == {"imu2": pytest.approx(-10.0,
                                                                                      abs=0.5)}
    assert ch.delay_s == pytest.approx(-1e-3 * rep["time_offsets_applied_ms"]["imu2"])
    # monitor-file's chain on the same samples (the log decoded whole): identical answers
    decoded, _ = read_log(log, cal, progress=False)
    whole, ref = run_flight(chain_for_flight(decoded, cal), decoded)
    got = {k: np.concatenate([getattr(r, k) for r in pieces])
           for k in ("t", "omega", "statistics", "healthy", "protection_level")}
    for k, v in got.items():
        np.testing.assert_array_equal(v, getattr(whole, k), err_msg=k)
    assert rep["events"] == ref["events"]
    # ... and on the flight folder's float64 samples (the log carries float32): the same
    # events at the same samples (log times within 1 µs), statistics within 1 % (the raw
    # values' float32 rounding is amplified in the small parity residual: 0.15 % seen)
    folder, ref64 = run_flight(chain_for_flight(f, cal), f)
    assert [(e["sensor"], e["type"]) for e in ref64["events"]] == \
        [(e["sensor"], e["type"]) for e in rep["events"]]
    np.testing.assert_allclose([e["t"] for e in rep["events"]],
                               [e["t"] for e in ref64["events"]], atol=1e-6)
    ok = np.isfinite(folder.statistics) & np.isfinite(got["statistics"])
    np.testing.assert_allclose(got["statistics"][ok], folder.statistics[ok], rtol=1e-2,
                               atol=1e-6)
    # without the offsets the 10 ms lag keeps the monitor in alarm most of the time
    plain, _, _ = _stream_report(log, cal, offsets=False)
    moved_frac, plain_frac = _in_alarm(pieces), _in_alarm(plain)
    assert moved_frac < 0.1 * plain_frac, (moved_frac, plain_frac)


def _other_set(cal):
    """The calibration with every sensor expecting raw outputs in LSB (another set)."""
    s = cal.kind("gyro")
    return replace(cal, sets={"gyro": replace(s, sensors=tuple(
        replace(c, raw_unit="LSB") for c in s.sensors))})


def test_replay_refuses_a_log_of_another_set_naming_both_files(lagged, tmp_path, capsys):
    f, cal = lagged
    log = tmp_path / "lagged.log"
    write_flight_log(f, log)
    other = tmp_path / "other.json"
    _other_set(cal).save(other)
    rc = main(["replay", str(log), "--cal", str(other), "--no-progress"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1
    assert str(log) in err[0] and str(other) in err[0] and "'LSB'" in err[0]


def test_thresholds_of_another_rate_or_calibration_are_refused(lagged, tmp_path, caplog):
    f, cal = lagged
    thr = compute_thresholds(cal)
    check_made_for(types.SimpleNamespace(sample_rate_hz=thr.sample_rate_hz,
                                         calibration_fingerprint="abc"),
                   types.SimpleNamespace(sample_rate_hz=cal.sample_rate_hz,
                                         configuration="x", fingerprint=lambda: "abc"),
                   "t.json", "c.json")            # made for this one: accepted
    with pytest.raises(ConfigError, match=r"t\.json: .*fingerprint abc.*c\.json has def"):
        check_made_for(types.SimpleNamespace(sample_rate_hz=thr.sample_rate_hz,
                                             calibration_fingerprint="abc"),
                       types.SimpleNamespace(sample_rate_hz=cal.sample_rate_hz,
                                             configuration="x", fingerprint=lambda: "def"),
                       "t.json", "c.json")
    with pytest.raises(ConfigError, match=r"t\.json: thresholds made for 100 Hz, the "
                                          r"calibration c\.json is at 50 Hz"):
        check_made_for(replace(thr, sample_rate_hz=100.0), cal, "t.json", "c.json")
    check_made_for(thr, cal, "t.json", "c.json")       # /2 made for this calibration
    old = replace(thr, calibration_fingerprint="")      # as a /1 file loads
    with caplog.at_level(logging.WARNING, logger="rimu"):
        check_made_for(old, cal, "t.json", "c.json")   # /1: no fingerprint, warned
    assert [r.getMessage() for r in caplog.records if "fingerprint" in r.getMessage()]
    # through monitor-file: one line naming both files, exit 2, no report
    folder = tmp_path / "f"
    from replay.flight_io import save_flight_dir
    save_flight_dir(f, folder)
    cp, tp, rp = tmp_path / "cal.json", tmp_path / "thr100.json", tmp_path / "r.json"
    cal.save(cp)
    replace(thr, sample_rate_hz=100.0).save(tp)
    rc = main(["monitor-file", str(folder), "--cal", str(cp), "--thresholds", str(tp),
               "--report", str(rp)])
    assert rc == 2 and not rp.exists()


def test_one_chain_per_command():
    """The commands parse, call the chain and print: none builds a monitor itself."""
    from pathlib import Path

    root = Path(__file__).resolve().parents[2] / "rimu" / "commands"
    for name in ("replay.py", "monitor.py", "monitor_file.py"):
        text = (root / name).read_text(encoding="utf-8")
        assert "Monitor(" not in text and "CompensatedMonitor" not in text, name
        assert "apply_time_offsets" not in text, name
    assert dataclasses.is_dataclass(ChainOptions)


def test_each_block_carries_what_the_envelope_needs(lagged):
    """Per block the chain has the time, the calibrated rates and each IMU's accelerometer
    triad (the operating envelope's inputs), on the moved samples."""
    f, cal = lagged
    ch = chain_for_flight(f, cal)
    held = ch.aligner.push(f)
    assert held.t.shape[0] == f.t.shape[0] - 1          # 10 ms at 50 Hz: the last one waits
    piece = concat_flights([held, ch.aligner.flush()])
    blk = ch.block(piece)
    s = cal.kind("gyro")
    B = piece.t.shape[0]
    assert blk.t.shape == (B,) and blk.rates.shape == (B, 6)
    ok = piece.valid
    np.testing.assert_allclose(blk.rates[ok], (piece.raw * s.scale_factors - s.biases)[ok])
    assert np.isnan(blk.rates[~ok]).all() and (~ok).any()       # the moved IMU's edge
    assert blk.accel_imus == ("imu1", "imu2") and blk.accel.shape == (B, 2, 3)
    # calibrated rates of both IMUs agree with the true rate along the axes (≈ 1 °/s noise)
    err = blk.rates[ok[:, 0], 0] - (f.omega_true[:B][ok[:, 0]] @ s.H[0])
    assert np.sqrt(np.mean(err ** 2)) < np.radians(2.0)


def test_a_maps_auxiliary_channels_move_with_their_imu(lagged, tmp_path):
    """write_flight_log's accelerometer channels (each applied to one IMU's sensors) move
    with that IMU; the replay with them gives the same statistics as without the map's
    auxiliary channels (the gyro samples do not depend on them here: no effect terms)."""
    from replay.channel_map import default_channel_map

    f, cal = lagged
    log = tmp_path / "aux.log"
    aux = write_flight_log(f, log)
    s = cal.kind("gyro")
    cmap = default_channel_map(s.n, axes=s.H_nominal, names=tuple(c.name for c in s.sensors),
                               auxiliary=aux)
    ch = chain_for_map(cal, cmap)
    from replay.chain import moved_aux
    assert moved_aux(ch) == ["accel:imu2.x", "accel:imu2.y", "accel:imu2.z"]
    db, _ = resolve_map(cal)
    rep = report_log(ch, LogStream(log, cal, db, cmap, progress=False), f)
    assert rep["time_offsets_aux_moved"] == ["accel:imu2.x", "accel:imu2.y", "accel:imu2.z"]
    assert rep["frames"]["rejected"].get("unknown_id", 0) == 0
    _, plain, _ = _stream_report(log, cal)
    assert [e["t"] for e in rep["events"]] == [e["t"] for e in plain["events"]]


def test_an_envelope_tracker_in_the_chain_gives_its_codes_to_the_monitor(lagged):
    """The chain's per-block seam: an EnvelopeTracker given to the chain sees the moved
    samples' calibrated rates and accelerometer triads, and its codes reach the answers
    (the codes flight_envelope gives on the moved flight, each the union with the next
    sample's: IMU2 is read 10 ms ahead, replay.envelope_lead)."""
    from fdi.envelope import SHOCK, EnvelopeTracker
    from replay.envelope import flight_envelope
    from replay.envelope_lead import dilate_back

    f, cal = lagged
    vals = f.aux.values.copy()
    acc = [j for j, k in enumerate(f.aux.kinds) if k == "accel"]
    vals[300:306, acc] = 300.0                                 # a shock of ~50 g
    f = replace(f, aux=replace(f.aux, values=vals))
    moved, _ = apply_time_offsets(f, cal)
    want = flight_envelope(moved, cal)
    assert (want & SHOCK).any()
    tr = EnvelopeTracker(H=cal.gyro.H, groups=list(f.imu_groups().values()),
                         validated_rate=cal.gyro.validated_rate,
                         validated_specific_force=cal.gyro.validated_specific_force,
                         validated_jolt=cal.gyro.validated_jolt)
    ch = chain_for_flight(f, cal, ChainOptions(envelope=tr))
    assert ch._hold is not None and ch._hold.lead == 1
    res, rep = run_flight(ch, f)
    np.testing.assert_array_equal(res.envelope, dilate_back(want, 1))
    assert any(e["type"] == "envelope" for e in rep["events"])


def test_the_chain_decides_the_envelope_by_default_and_reports_it(lagged):
    """Without options the chain marks a shock (the codes flight_envelope gives on the
    moved flight, each the union with the next sample's: replay.envelope_lead), the report
    counts the excursion with its reason and the share of samples out, and names what the
    set can isolate; --no-envelope (envelope=False) marks nothing."""
    from fdi.envelope import SHOCK
    from replay.envelope import flight_envelope
    from replay.envelope_lead import dilate_back

    f, cal = lagged
    vals = f.aux.values.copy()
    acc = [j for j, k in enumerate(f.aux.kinds) if k == "accel"]
    vals[300:306, acc] = 300.0
    f = replace(f, aux=replace(f.aux, values=vals))
    moved, _ = apply_time_offsets(f, cal)
    want = dilate_back(flight_envelope(moved, cal), 1)
    res, rep = run_flight(chain_for_flight(f, cal), f)
    np.testing.assert_array_equal(res.envelope, want)
    s = rep["summary"]
    assert len(s["envelope_periods"]) == 1 and "shock" in s["envelope_periods"][0]["reasons"]
    assert s["envelope_out_fraction"] == pytest.approx(np.count_nonzero(want) / want.size)
    assert s["envelope_periods"][0]["samples"] == np.count_nonzero(want & SHOCK)
    cap = rep["isolation_capability"]
    assert cap["capability"] == "detect" and cap["unit"] == "deg/s"
    assert {tuple(sorted(p["names"])) for p in cap["pairs"][:3]} == {
        ("imu1.x", "imu2.x"), ("imu1.y", "imu2.y"), ("imu1.z", "imu2.z")}
    off, rep_off = run_flight(chain_for_flight(f, cal, ChainOptions(envelope=False)), f)
    assert not off.envelope.any() and rep_off["summary"]["envelope_periods"] == []


def test_report_follows_an_excursion_across_pieces():
    """An excursion that spans two pieces is one period in the running report."""
    from fdi.answer import BlockResult
    from replay.report import RunningReport

    def piece(t, env):
        N = len(t)
        return BlockResult(t=np.asarray(t, float), omega=np.zeros((N, 3)),
                           omega_sd=np.zeros((N, 3)), healthy=np.ones((N, 6), bool),
                           statistics=np.zeros((N, 1)), thresholds=np.ones((N, 1)),
                           protection_level=np.ones(N), capability=np.array(["detect"] * N,
                                                                            dtype=object),
                           envelope=np.asarray(env), unverified=np.zeros((N, 3), bool))

    rr = RunningReport()
    rr.update(piece([0, 1, 2, 3], [0, 0, 1, 1]))
    rr.update(piece([4, 5, 6], [4, 0, 0]))
    rr.update(piece([7, 8], [0, 2]))
    ps = rr._periods()
    assert [(p["t0_s"], p["t1_s"], p["samples"], p["reasons"]) for p in ps] == [
        (2.0, 4.0, 3, ["shock", "tumble"]), (8.0, 8.0, 1, ["saturation"])]
    assert rr.n_out == 4
