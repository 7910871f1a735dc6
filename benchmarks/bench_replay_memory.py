"""Replay memory: peak resident memory of ``rimu replay`` on a 10 min and a 2 h log.

The logs are simulated cone6 flights at 100 Hz through the shipped DBC, written once as BLF
into a temporary directory (the 2 h log has 4.3 million frames). Each run is a fresh
interpreter whose own peak (``VmHWM`` of ``/proc/self/status``) is read at its end:

- ``stream``: ``rimu replay LOG --cal CAL --report R`` (read, decode, monitor and report
  piece by piece: :class:`replay.logio.LogStream`);
- ``whole``: the whole-log path the replay used before: ``read_log`` (every frame in memory),
  ``Monitor.run`` over all samples, ``build_report`` — the baseline, measured in the same run
  (it builds the CLI's parser first, so that both pay the same imports).

Target (issue 10): peak of the 2 h stream replay ≤ 1.3× the 10 min one; wall time of the
stream replay not worse than the whole-log one. CPU time (user + system of the child, from
``wait4``) and wall time, min/median/max over ``--repeat`` runs; wall time swings with the
load of the shared machine, CPU time much less.

Usage: ``python benchmarks/bench_replay_memory.py [--repeat 3] [--long-min 120]``.
Writes ``benchmarks/results/replay_memory.json``.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _common import ROOT, header, spread, write_results

from replay.can_write import write_flight_log
from replay.flight import simulate_flight
from studies.synthetic import synthetic_calibration

_HWM = ("hwm = [x for x in open('/proc/self/status') if x.startswith('VmHWM')][0]\n"
        "print('VmHWM', hwm.split()[1], file=sys.stderr)\n")
STREAM = "import sys\nfrom rimu.cli import main\nrc = main(sys.argv[1:])\n" + _HWM
WHOLE = ("import sys\nfrom rimu.cli import build_parser\nbuild_parser()\n"
         "from fdi.calfile import load_calibration\nfrom fdi.monitor import Monitor\n"
         "from replay.logio import read_log\nfrom replay.report import build_report\n"
         "cal = load_calibration(sys.argv[2])\n"
         "f, fr = read_log(sys.argv[1], cal, progress=False)\n"
         "res = Monitor(cal).run(f.t, f.raw, f.valid)\n"
         "rep = build_report(res, f, cal, frames=fr)\n" + _HWM)


def run(code: str, argv: list[str]) -> tuple[float, float, int]:
    """(wall seconds, CPU seconds, peak kB) of one fresh interpreter."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    t0 = time.perf_counter()
    with tempfile.TemporaryFile("w+") as err:
        p = subprocess.Popen([sys.executable, "-c", code, *argv], cwd=ROOT, env=env,
                             text=True, stdout=subprocess.DEVNULL, stderr=err)
        _, status, usage = os.wait4(p.pid, 0)
        wall = time.perf_counter() - t0
        err.seek(0)
        text = err.read()
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(text)
    return wall, usage.ru_utime + usage.ru_stime, int(text.rsplit("VmHWM", 1)[1].split()[0])


def stats(x: list[float]) -> dict[str, float]:
    return spread(x)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--short-min", type=float, default=10.0)
    ap.add_argument("--long-min", type=float, default=120.0)
    args = ap.parse_args()
    if not Path("/proc/self/status").is_file():
        raise SystemExit("needs Linux /proc to read the peak resident memory")
    cal = synthetic_calibration("cone6", seed=4, raw_unit="mV")
    out: dict = header("replay_memory", repeat=args.repeat, logs={})
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        cp = d / "cal.json"
        cal.save(cp)
        for name, minutes in (("short", args.short_min), ("long", args.long_min)):
            log = d / f"{name}.blf"
            t0 = time.perf_counter()
            write_flight_log(simulate_flight(cal, 60.0 * minutes, seed=1), log)
            print(f"{name}: {minutes:g} min log written in {time.perf_counter() - t0:.0f} s "
                  f"({log.stat().st_size / 2**20:.0f} MiB)", flush=True)
            rec: dict = {"minutes": minutes, "bytes": log.stat().st_size}
            for mode, code, argv in (
                    ("stream", STREAM, ["replay", str(log), "--cal", str(cp), "--no-progress",
                                        "--report", str(d / "r.json")]),
                    ("whole", WHOLE, [str(log), str(cp)])):
                walls, cpus, peaks = [], [], []
                for _ in range(args.repeat):
                    w, c, k = run(code, argv)
                    walls.append(w)
                    cpus.append(c)
                    peaks.append(k / 1024.0)
                rec[mode] = {"wall_s": stats(walls), "cpu_s": stats(cpus),
                             "peak_mib": stats(peaks)}
                print(f"  {mode:6s}  peak {stats(peaks)['median']:7.1f} MiB   cpu "
                      f"{stats(cpus)['min']:6.2f} / {stats(cpus)['median']:6.2f} / "
                      f"{stats(cpus)['max']:6.2f} s   wall {stats(walls)['median']:6.1f} s "
                      "(min/median/max)", flush=True)
            out["logs"][name] = rec
    s, lg = out["logs"]["short"], out["logs"]["long"]
    ratio = lg["stream"]["peak_mib"]["max"] / s["stream"]["peak_mib"]["min"]
    out["ratio_peak_long_over_short_stream"] = ratio
    out["ratio_peak_long_over_short_whole"] = (lg["whole"]["peak_mib"]["median"]
                                               / s["whole"]["peak_mib"]["median"])
    out["ratio_wall_stream_over_whole_long"] = (lg["stream"]["wall_s"]["median"]
                                                / lg["whole"]["wall_s"]["median"])
    out["ratio_cpu_stream_over_whole"] = {k: out["logs"][k]["stream"]["cpu_s"]["median"]
                                          / out["logs"][k]["whole"]["cpu_s"]["median"]
                                          for k in ("short", "long")}
    print(f"peak long/short: stream {ratio:.2f} (target <= 1.3), whole-log "
          f"{out['ratio_peak_long_over_short_whole']:.2f}; wall stream/whole on the long log "
          f"{out['ratio_wall_stream_over_whole_long']:.2f}; CPU stream/whole "
          + ", ".join(f"{k} {v:.2f}" for k, v in out["ratio_cpu_stream_over_whole"].items()))
    write_results(out)
    return 0 if ratio <= 1.3 else 1


if __name__ == "__main__":
    sys.exit(main())
