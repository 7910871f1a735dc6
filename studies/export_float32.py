"""How far the float32 C module is from the float64 monitor on the real flights
(docs/export-c.md, "float32"): erle flights 41 and 83 of ../shared/data through the chain
of ``rimu monitor-file`` (in-flight calibration, time offsets, envelope), the monitor's
own inputs fed to the float32 module; largest relative difference of the thresholds and
protection levels, of ω̂ relative to the largest rate, of the statistics relative to the
larger of statistic and threshold, and whether the events are the same.

Run: ``python studies/export_float32.py`` (prints one line per flight and a JSON line).
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

from fdi.detector import default_thresholds
from fdi.export import generate_c, write_c
from fdi.export.host import CMonitor, compile_module

FLIGHTS = {"41": "pxf_copter_22-12-2014_41.BIN", "83": "pxf_copter_31-3-2015_83.BIN"}


def measure(path: Path) -> dict:
    from replay.chain import ChainOptions, chain_for_flight
    from studies.field import inflight_calibration, load_erle

    flight = load_erle(path)
    cal = inflight_calibration(flight)
    th = default_thresholds(cal)
    chain = chain_for_flight(flight, cal, ChainOptions(thresholds=th, report=False))
    calls = []
    run = chain.monitor.run

    def recorded(t, raw, valid=None, **kw):
        res = run(t, raw, valid, **kw)
        calls.append((np.array(t), np.array(raw), None if valid is None else np.array(valid),
                      dict(kw), res))
        return res

    chain.monitor.run = recorded
    chain.feed_whole(flight)
    with tempfile.TemporaryDirectory() as d:
        write_c(generate_c(cal, th, precision="float32", harness=True), d)
        mon = CMonitor.load(d, compile_module(d), [s.name for s in cal.gyro.sensors])
        worst = {"thresholds": 0.0, "protection_level": 0.0, "omega": 0.0,
                 "statistics": 0.0}
        same_events = True
        for t, raw, valid, kw, res in calls:
            c = mon.run(t, raw, valid, force=kw.get("force"),
                        temperature=kw.get("temperature"), envelope=kw.get("envelope"))
            for name in worst:
                a = np.asarray(getattr(res, name), float)
                b = np.asarray(getattr(c, name), float)
                ok = np.isfinite(a) & np.isfinite(b)
                if not ok.any():
                    continue
                if name == "omega":
                    e = np.max(np.abs(b[ok] - a[ok])) / np.max(np.abs(a[ok]))
                elif name == "statistics":
                    den = np.maximum(np.asarray(res.thresholds, float)[ok], a[ok])
                    e = np.max(np.abs(b[ok] - a[ok]) / den)
                else:
                    e = np.max(np.abs(b[ok] - a[ok]) / np.abs(a[ok]))
                worst[name] = max(worst[name], float(e))
            pe = [(e.t, e.sensor, e.type, e.reason) for e in res.events]
            ce = [(e.t, e.sensor, e.type, e.reason) for e in c.events]
            same_events &= pe == ce
    return {"samples": int(sum(len(c[0]) for c in calls)), "same_events": same_events,
            **{f"max_rel_{k}": v for k, v in worst.items()}}


def main() -> int:
    root = Path(os.environ.get("RIMU_SHARED_DATA", Path(__file__).resolve().parents[1] /
                               ".." / "shared" / "data")) / "erle_pxf_dual_imu"
    out = {}
    for name, f in FLIGHTS.items():
        if not (root / f).exists():
            print(f"{root / f} not found", file=sys.stderr)
            continue
        out[name] = m = measure(root / f)
        print(f"flight {name}: {m['samples']} samples, same events {m['same_events']}; "
              f"thresholds {m['max_rel_thresholds']:.3g}, protection level "
              f"{m['max_rel_protection_level']:.3g}, omega {m['max_rel_omega']:.3g}, "
              f"statistics {m['max_rel_statistics']:.3g}")
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
