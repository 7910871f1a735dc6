"""Benchmark: the run-time compensation of effect terms (fdi.effects) against the monitor.

A 10 min cone6 flight at 100 Hz (60 000 × 6 samples) with three compensated terms
(scale asymmetry, two g-sensitivities) and an accelerometer triad. Measured in the same
run: ``Monitor.run`` alone (the baseline), ``Compensator.block`` alone, and the
compensated monitor (``CompensatedMonitor.run``); and per sample, ``Monitor.step`` against
``CompensatedMonitor.step``. min/median/max over the repeats; ratios to the baseline of the
same run. Prints the figures and writes ``benchmarks/results/effects.json``.

Run: ``python benchmarks/bench_effects.py [--repeats 5]``
"""

from __future__ import annotations

import argparse
import sys

from _common import ROOT, header, print_results, timed, write_results

sys.path.insert(0, str(ROOT / "tests" / "fdi"))

from _effects_flight import effect_calibration, flight_with_effects

from fdi.effects import Compensator
from fdi.effects_monitor import CompensatedMonitor
from fdi.monitor import Monitor
from replay.effect_inputs import flight_effect_inputs


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--duration", type=float, default=600.0)
    ap.add_argument("--step-samples", type=int, default=2000)
    a = ap.parse_args()
    cal = effect_calibration()
    fl = flight_with_effects(cal, 1, duration_s=a.duration)
    force, _, avail = flight_effect_inputs(fl)
    comp = Compensator(cal, available=avail)
    res: dict = header("effects", samples=int(fl.t.size), sensors=int(fl.n),
                       terms_applied=len(comp.applied), repeats=a.repeats)
    res["monitor_run_s"] = timed(lambda: Monitor(cal).run(fl.t, fl.raw, fl.valid), a.repeats)
    res["compensator_block_s"] = timed(lambda: comp.block(fl.raw, force), a.repeats)
    res["compensated_run_s"] = timed(
        lambda: CompensatedMonitor(Monitor(cal), comp).run(fl.t, fl.raw, fl.valid,
                                                             force=force), a.repeats)
    k = min(a.step_samples, fl.t.size)

    def stepper(wrapped: bool):
        """A timed function stepping a monitor built beforehand (its set-up, which builds
        the set models, is not part of a step's cost)."""
        mons = iter([CompensatedMonitor(Monitor(cal), comp) if wrapped else Monitor(cal)
                     for _ in range(a.repeats + 1)])

        def run() -> None:
            mon = next(mons)
            for i in range(k):
                if wrapped:
                    mon.step(float(fl.t[i]), fl.raw[i], fl.valid[i], force=force[i])
                else:
                    mon.step(float(fl.t[i]), fl.raw[i], fl.valid[i])
        return run

    res["monitor_step_us"] = {q: v / k * 1e6 for q, v in
                              timed(stepper(False), a.repeats).items()}
    res["compensated_step_us"] = {q: v / k * 1e6 for q, v in
                                  timed(stepper(True), a.repeats).items()}
    base = res["monitor_run_s"]["median"]
    res["ratio_block_to_monitor_run"] = res["compensator_block_s"]["median"] / base
    res["ratio_compensated_to_monitor_run"] = res["compensated_run_s"]["median"] / base
    res["ratio_step"] = (res["compensated_step_us"]["median"]
                         / res["monitor_step_us"]["median"])
    print_results(res)
    write_results(res)


if __name__ == "__main__":
    main()
