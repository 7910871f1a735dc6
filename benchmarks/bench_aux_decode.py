"""Benchmark: decoding a CAN log's auxiliary channels (temperature, specific force) beside
the monitored sensors.

A cone6 flight (6 gyros at 100 Hz) with an accelerometer triad (three ``RIMU_ACCEL_ii``
frames per sample) and a temperature (``RIMU_TEMP_01`` every 10th sample), written once as
a candump log and read once into memory. Measured in the same run on the same frames:
``decode_frames`` with the plain map (the baseline: the auxiliary frames are counted as
unknown ids) and with the map carrying the four auxiliary channels (decoded, checked and
held onto the samples), and ``map_effect_inputs`` (held columns to per-sensor force and
temperature). min/median/max over the repeats; ratios to the baseline of the same run.
Prints the figures and writes ``benchmarks/results/aux_decode.json``.

Run: ``python benchmarks/bench_aux_decode.py [--repeats 5] [--duration 120]``
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
from pathlib import Path

import numpy as np
from _common import ROOT, header, print_results, timed, write_results

sys.path.insert(0, str(ROOT / "tests" / "fdi"))

from _effects_flight import effect_calibration, flight_with_effects

from replay.accounting import FrameAccounting
from replay.assemble import decode_frames
from replay.can_read import read_frames
from replay.can_write import write_flight_log
from replay.channel_map import default_channel_map
from replay.effect_inputs import map_effect_inputs
from replay.flight_data import AuxChannels
from replay.frames import load_dbc


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--duration", type=float, default=120.0)
    a = ap.parse_args()
    cal = effect_calibration()
    fl = flight_with_effects(cal, 1, duration_s=a.duration)
    T = 25.0 + 0.1 * fl.t
    aux = fl.aux
    fl = dataclasses.replace(fl, aux=AuxChannels(
        (*aux.kinds, "temperature"), (*aux.names, "board"), (*aux.imu, ""),
        np.column_stack([aux.values, T]), np.column_stack([aux.valid, np.isfinite(T)])))
    g = cal.gyro
    names = tuple(c.name for c in g.sensors)
    with tempfile.TemporaryDirectory() as d:
        log = Path(d) / "flight.log"
        chans = write_flight_log(fl, log)
        frames, _ = read_frames(log, progress=False)
    plain = default_channel_map(g.n, axes=g.H_nominal, names=names)
    with_aux = default_channel_map(g.n, axes=g.H_nominal, names=names, auxiliary=chans)
    db = load_dbc()
    fs = cal.sample_rate_hz

    def dec(cmap):
        return decode_frames(frames, db, cmap, FrameAccounting(), sample_rate_hz=fs)

    held = dec(with_aux).aux
    res: dict = header("aux_decode", samples=int(fl.t.size), sensors=int(fl.n),
                       frames=len(frames), aux_channels=len(chans), repeats=a.repeats)
    res["decode_plain_s"] = timed(lambda: dec(plain), a.repeats)
    res["decode_with_aux_s"] = timed(lambda: dec(with_aux), a.repeats)
    res["map_effect_inputs_s"] = timed(lambda: map_effect_inputs(with_aux, held), a.repeats)
    base = res["decode_plain_s"]["median"]
    res["ratio_decode_with_aux_to_plain"] = res["decode_with_aux_s"]["median"] / base
    res["ratio_inputs_to_plain_decode"] = res["map_effect_inputs_s"]["median"] / base
    print_results(res)
    write_results(res)


if __name__ == "__main__":
    main()
