"""Effect terms compensated from a CAN stream's auxiliary channels (``[[auxiliary]]`` in the
channel map): a simulated flight whose gyros carry g-sensitivity (sensors 2 and 4), a scale
asymmetry (sensor 1) and a temperature coefficient (sensor 5) is written as a CAN log with
accelerometer frames (every sample) and temperature frames (every 10th sample), and replayed
with the calibration holding the true terms and their σ.

With the auxiliary channels the per-sensor parity residual mean is within 3 σ of 0 and the
alarms within the false-alarm bound; without them (the default map) the g-sensitivity and
temperature terms are listed as not applied, naming what the map lacks, and the bias shows.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from _effects_flight import effect_calibration, flight_with_effects, residual_z
from scipy.stats import poisson

from fdi.calfile import EffectTerm
from fdi.effects import Compensator
from fdi.effects_monitor import CompensatedMonitor
from fdi.monitor import Monitor
from fdi.units import DPH
from replay.can_write import write_flight_log
from replay.channel_map import default_channel_map, load_channel_map, write_channel_map
from replay.effect_inputs import map_available, map_effect_inputs, map_reasons
from replay.flight_data import AuxChannels
from replay.logio import read_log

DUR = 30.0
K_T = 20.0                    # deg/h per degC on sensor 5: up to 600 deg/h, 1.7 σ per sample
T_REF = 25.0


def _calibration():
    cal = effect_calibration()
    term = EffectTerm("temperature", "gyro", 4, K_T, 0.1, "deg/h per degC", ("temperature",),
                      {"reference_degC": T_REF})
    return dataclasses.replace(cal, effects=(*cal.effects, term))


def _flight(cal, seed):
    """The effects flight plus a board temperature warming from 25 to 55 °C, whose effect
    the gyro 5 output carries."""
    fl = flight_with_effects(cal, seed, duration_s=DUR)
    t = fl.t - fl.t[0]
    T = T_REF + 30.0 * (1 - np.exp(-t / 10.0))
    Tm = T + 0.05 * np.random.default_rng([seed, 8]).standard_normal(T.size)
    raw = fl.raw.copy()
    raw[:, 4] += K_T * DPH * (T - T_REF) / cal.gyro.scale_factors[4]
    a = fl.aux
    aux = AuxChannels((*a.kinds, "temperature"), (*a.names, "board"), (*a.imu, ""),
                      np.column_stack([a.values, Tm]), np.column_stack([a.valid,
                                                                        np.ones(T.size, bool)]))
    return dataclasses.replace(fl, raw=raw, aux=aux)


def _maps(cal, aux):
    g = cal.gyro
    names = tuple(c.name for c in g.sensors)
    return (default_channel_map(g.n, axes=g.H_nominal, names=names, auxiliary=aux),
            default_channel_map(g.n, axes=g.H_nominal, names=names))


def _allowed(cal):
    return int(poisson.isf(1e-3, Monitor(cal).thresholds.false_alarms_per_hour * DUR / 3600))


def _replay(cal, log, cmap):
    """Replay ``log`` with ``cmap``; the compensated monitor's result, its compensator and
    the per-sensor residual z of the compensated outputs."""
    flight, frames = read_log(log, cal, channel_map=cmap, progress=False)
    n_aux = 3 * len(flight.t) + len(flight.t) // 10           # accelerometer, temperature
    assert frames["balanced"] and frames["lost_samples"] == 0, frames
    assert frames["rejected"] == ({} if cmap.auxiliary else {"unknown_id": n_aux}), frames
    force, temp = map_effect_inputs(cmap, None if flight.aux is None else flight.aux.values)
    comp = Compensator(cal, available=map_available(cmap), lacking=map_reasons(cmap))
    res = CompensatedMonitor(Monitor(cal), comp).run(flight.t, flight.raw, flight.valid,
                                                     force=force, temperature=temp)
    g = cal.gyro
    c = Compensator(cal, available=map_available(cmap)).block(flight.raw, force, temp)
    return res, comp, residual_z(cal, flight.raw * g.scale_factors - g.biases - c)


@pytest.fixture(scope="module")
def cal():
    return _calibration()


@pytest.mark.parametrize("seed", [1, 2])
def test_can_replay_with_aux_channels_compensates_without_them_not(cal, tmp_path, seed):
    fl = _flight(cal, seed)
    log = tmp_path / "flight.log"
    aux = write_flight_log(fl, log)
    assert [(a.quantity, a.message) for a in aux] == [
        ("specific_force", "RIMU_ACCEL_01"), ("specific_force", "RIMU_ACCEL_02"),
        ("specific_force", "RIMU_ACCEL_03"), ("temperature", "RIMU_TEMP_01")]
    with_aux, plain = _maps(cal, aux)
    allowed = _allowed(cal)

    on, comp, z_on = _replay(cal, log, with_aux)
    assert [(a.term.name, a.term.sensor) for a in comp.applied] == [
        ("scale_asymmetry", 0), ("g_sensitivity", 1), ("g_sensitivity", 3),
        ("temperature", 4)] and comp.skipped == ()
    # the first sample's accelerometer and temperature frames leave after it: no input there
    assert comp.missing == {("g_sensitivity", 1): 1, ("g_sensitivity", 3): 1,
                            ("temperature", 4): 1}
    assert np.all(np.abs(z_on) < 3), z_on
    assert sum(e.type == "detected" for e in on.events) <= allowed
    assert on.healthy.all()

    off, comp0, z_off = _replay(cal, log, plain)
    assert [(a.term.name, a.term.sensor) for a in comp0.applied] == [("scale_asymmetry", 0)]
    skipped = {(s.term.name, s.term.sensor): s.reason for s in comp0.skipped}
    assert set(skipped) == {("g_sensitivity", 1), ("g_sensitivity", 3), ("temperature", 4)}
    assert skipped[("g_sensitivity", 1)] == (
        "needs specific force: the default channel map (give --map with [[auxiliary]] "
        "channels) names no specific-force (accelerometer) channel for this sensor")
    assert skipped[("temperature", 4)].startswith("needs temperature: the default channel map")
    assert np.max(np.abs(z_off)) > 10, z_off
    assert sum(e.type == "detected" for e in off.events) > allowed


def test_replay_command_with_an_aux_map(cal, tmp_path, capsys):
    """``rimu replay --map`` with the auxiliary channels: the terms are applied, the report
    records the auxiliary frames; the same log without the map lists them as not applied."""
    from rimu.cli import main

    fl = _flight(cal, 3)
    log = tmp_path / "flight.log"
    aux = write_flight_log(fl, log)
    with_aux, _ = _maps(cal, aux)
    write_channel_map(with_aux, tmp_path / "map.toml")
    assert len(load_channel_map(tmp_path / "map.toml").auxiliary) == 4
    cal.save(tmp_path / "cal.json")
    assert main(["replay", str(log), "--cal", str(tmp_path / "cal.json"), "--map",
                 str(tmp_path / "map.toml"), "--no-progress", "--report",
                 str(tmp_path / "on.json")]) == 0
    lines = capsys.readouterr().out.splitlines()
    first = lines[0]
    n = len(fl.t)
    assert (f"auxiliary channels (values received): accel:imu.x {n}, accel:imu.y {n}, "
            f"accel:imu.z {n}, temperature:board {n // 10}; frames used {3 * n + n // 10}, "
            "rejected none, lost 0") in lines
    assert first == ("compensating: scale_asymmetry on x1 (from rate sign), g_sensitivity on "
                     "y1 (from specific force), g_sensitivity on x2 (from specific force), "
                     "temperature on y2 (from temperature)"), first
    rep = json.loads((tmp_path / "on.json").read_text())
    assert sum(e["type"] == "detected" for e in rep["events"]) <= _allowed(cal)
    frames = rep["auxiliary"]["frames"]
    assert frames["used"] == frames["read"] == 3 * n + n // 10 and frames["lost_frames"] == 0
    assert [c["values_received"] for c in rep["auxiliary"]["channels"]] == [[n]] * 3 + [[n // 10]]
    assert rep["frames"]["balanced"] and rep["frames"]["used"] == rep["frames"]["read"]
    assert {m["name"]: m["samples"] for m in rep["effects"]["samples_without_input"]} == {
        "g_sensitivity": 1, "temperature": 1}
    assert main(["replay", str(log), "--cal", str(tmp_path / "cal.json"), "--no-progress",
                 "--report", str(tmp_path / "off.json")]) == 0
    out = capsys.readouterr().out
    assert "not applied: g_sensitivity on y1 (needs specific force: the default channel map" \
        in out.splitlines()[0]
    off = json.loads((tmp_path / "off.json").read_text())
    assert [a["name"] for a in off["effects"]["not_applied"]] == [
        "g_sensitivity", "g_sensitivity", "temperature"]
    assert off["frames"]["rejected"] == {"unknown_id": 3 * n + n // 10}


@pytest.mark.slow
def test_can_aux_compensation_is_honest_over_seeds(cal, tmp_path):
    """12 flights through CAN logs: the compensated residual z has an RMS near 1 and
    per-sensor means within 3 σ of 0 (the held inputs' one-frame lag adds no visible bias)."""
    zs = []
    for seed in range(200, 212):
        log = tmp_path / f"f{seed}.log"
        aux = write_flight_log(_flight(cal, seed), log)
        zs.append(_replay(cal, log, _maps(cal, aux)[0])[2])
    z = np.array(zs)
    rms = float(np.sqrt(np.mean(z ** 2)))
    print(f"RMS of z over {len(z)} seeds x 6 sensors: {rms:.3f}; means "
          f"{np.round(z.mean(axis=0), 3)}")
    assert 0.6 < rms < 1.5, rms
    assert np.all(np.abs(z.mean(axis=0)) < 3 / np.sqrt(len(z))), z.mean(axis=0)


class _ListBus:
    """A bus that hands out a log's frames, then nothing (run_live stops on idle)."""

    def __init__(self, msgs):
        self._it = iter(msgs)

    def recv(self, timeout=None):
        return next(self._it, None)


def test_live_monitor_and_realtime_replay_get_the_same_inputs(cal, tmp_path):
    """``rimu monitor`` (run_live, sample by sample) and ``rimu replay --realtime`` (Pacer)
    feed the compensated monitor the held inputs of each sample: the same answers as the
    block path."""
    import can

    from replay.live import Pacer, StreamDecoder, run_live
    from replay.logio import resolve_map

    fl = _flight(cal, 4)
    fl = dataclasses.replace(fl, t=fl.t[:300], raw=fl.raw[:300], valid=fl.valid[:300],
                             omega_true=fl.omega_true[:300], aux=fl.aux.slice(slice(0, 300)))
    log = tmp_path / "short.log"
    cmap = _maps(cal, write_flight_log(fl, log))[0]
    flight, _ = read_log(log, cal, channel_map=cmap, progress=False)
    force, temp = map_effect_inputs(cmap, flight.aux.values)
    avail = map_available(cmap)
    blk = CompensatedMonitor(Monitor(cal), Compensator(cal, available=avail)).run(
        flight.t, flight.raw, flight.valid, force=force, temperature=temp)
    db, _ = resolve_map(cal, channel_map=cmap)
    with can.LogReader(str(log)) as r:
        msgs = list(r)
    live, frames = run_live(_ListBus(msgs), StreamDecoder(db, cmap, cal.sample_rate_hz),
                            CompensatedMonitor(Monitor(cal), Compensator(cal, available=avail)),
                            idle_timeout_s=0.2, poll_s=0.01)
    assert frames["balanced"] and len(live.t) == len(flight.t)
    np.testing.assert_allclose(live.t, flight.t, atol=1e-9)
    np.testing.assert_allclose(live.omega, blk.omega, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(live.statistics, blk.statistics, rtol=1e-9, atol=1e-12)
    k = slice(0, 40)                                      # Pacer sleeps at the recorded pace
    mon = CompensatedMonitor(Monitor(cal), Compensator(cal, available=avail))
    paced = Pacer().run(mon, flight.t[k], flight.raw[k], flight.valid[k], force=force[k],
                        temperature=temp[k])
    np.testing.assert_allclose(paced.omega, blk.omega[k], rtol=1e-12, atol=1e-15)
    # without the inputs the answers differ (the terms matter at this size)
    bare = CompensatedMonitor(Monitor(cal), Compensator(cal)).run(flight.t, flight.raw,
                                                                 flight.valid)
    assert np.max(np.abs(bare.omega - blk.omega)) > 1e-4


@pytest.mark.slow
def test_monitor_command_on_a_virtual_bus_with_an_aux_map(cal, tmp_path, capsys):
    """``rimu monitor --map`` with auxiliary channels on a live (virtual) bus: the terms are
    applied and the report carries the auxiliary frames (about 8 s: the log is played at its
    recorded pace)."""
    import threading
    import time
    import uuid

    import can

    from rimu.cli import main

    fl = _flight(cal, 6)
    k = slice(0, 100)
    fl = dataclasses.replace(fl, t=fl.t[k], raw=fl.raw[k], valid=fl.valid[k],
                             omega_true=fl.omega_true[k], aux=fl.aux.slice(k))
    log = tmp_path / "live.blf"
    write_channel_map(_maps(cal, write_flight_log(fl, log))[0], tmp_path / "map.toml")
    cal.save(tmp_path / "cal.json")
    channel = f"rimu-aux-{uuid.uuid4().hex}"

    def play():
        time.sleep(2.0)                                    # the monitor opens its bus first
        with can.Bus(interface="virtual", channel=channel, ignore_config=True,
                     preserve_timestamps=True) as tx, can.LogReader(str(log)) as r:
            for m in can.MessageSync(r, timestamps=True):
                tx.send(m)

    th = threading.Thread(target=play, daemon=True)
    th.start()
    rc = main(["monitor", "--interface", "virtual", "--channel", channel, "--cal",
               str(tmp_path / "cal.json"), "--map", str(tmp_path / "map.toml"),
               "--idle-timeout", "4", "--report", str(tmp_path / "r.json")])
    th.join(5)
    assert rc == 0
    assert "temperature on y2 (from temperature)" in capsys.readouterr().out.splitlines()[0]
    rep = json.loads((tmp_path / "r.json").read_text())
    assert rep["frames"]["balanced"] and rep["frames"]["rejected"] == {}
    assert rep["auxiliary"]["frames"]["used"] == 3 * 100 + 10
    assert [a["name"] for a in rep["effects"]["applied"]] == [
        "scale_asymmetry", "g_sensitivity", "g_sensitivity", "temperature"]
