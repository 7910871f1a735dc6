"""``rimu evaluate --cal CAL --out DIR``: Monte Carlo (or corpus) evaluation of the monitor."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from fdi.calfile import load_calibration
from fdi.errors import ConfigError

HELP = ("evaluate the monitor on simulated flights (every fault kind, a sweep of sizes) or a "
        "corpus of flight folders: detection, delay, isolation, false alarms, ROC")


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("--cal", required=True, metavar="FILE", help="calibration file")
    p.add_argument("--thresholds", metavar="FILE",
                   help="rimu.thresholds/2 (or /1) or rimu.tuning/1 file (default: computed from "
                        "the calibration for --false-alarms-per-hour)")
    p.add_argument("--false-alarms-per-hour", type=float, metavar="X",
                   help="budget for computed thresholds (default 1e-3)")
    p.add_argument("--runs", type=int, default=200, metavar="N",
                   help="simulated flights (default 200)")
    p.add_argument("--sweep-runs", type=int, default=220, metavar="N",
                   help="extra short runs measuring the detectable step per scale, compared "
                        "with rimu tune's prediction (default 220; 0: none)")
    p.add_argument("--seed", type=int, default=0, help="campaign seed (default 0)")
    p.add_argument("--faults", metavar="KINDS",
                   help="comma-separated fault kinds (default: all of step, ramp, stuck, "
                        "noise, scale, spike, dropout)")
    p.add_argument("--duration", type=float, default=60.0, metavar="S",
                   help="flight length (default 60 s; faults start half-way)")
    p.add_argument("--max-rate", type=float, default=300.0, metavar="DPS",
                   help="largest body rate of the manoeuvres (default 300 deg/s)")
    p.add_argument("--kind", default="gyro", choices=("gyro", "accel"))
    p.add_argument("--corpus", metavar="DIR",
                   help="evaluate the flight folders (rimu.flight/1) under DIR instead")
    p.add_argument("--scheduler", default="serial", metavar="WHERE",
                   help="serial (default), local (a Dask LocalCluster on this machine) or "
                        "tcp://HOST:PORT (an existing Dask scheduler)")
    p.add_argument("--workers", type=int, default=2, help="LocalCluster workers (default 2)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")


def _kinds(text: str | None) -> tuple[str, ...]:
    from replay.faults import FAULT_KINDS

    if not text:
        return FAULT_KINDS
    out = tuple(k.strip().lower() for k in text.split(",") if k.strip())
    for k in out:
        if k not in FAULT_KINDS:
            raise ConfigError(f"unknown fault kind {k!r}; expected one of "
                              f"{', '.join(FAULT_KINDS)}")
    return out


def _corpus_items(d: str) -> list[tuple[int, str]]:
    root = Path(d)
    if not root.is_dir():
        raise ConfigError(f"--corpus {d}: not a directory")
    dirs = sorted(p.parent for p in root.rglob("manifest.json"))
    if not dirs:
        raise ConfigError(f"--corpus {d}: no flight folder (manifest.json) under it")
    return [(k, str(p)) for k, p in enumerate(dirs)]


def markdown(ev: dict, how: dict) -> str:
    """A short Markdown summary of ``evaluation.json``."""
    fa = ev["false_alarms"]
    lo, hi = fa["ci95_per_hour"]
    lines = ["# rimu evaluation", "",
             f"- thresholds: {how.get('source')} ({ev['thresholds']['false_alarms_per_hour']:g} "
             f"false alarms/h target), scales {ev['thresholds']['scales']}",
             f"- runs: {ev['runs']}",
             f"- false alarms: {fa['count']} in {fa['exposure_h']:.2f} h = "
             f"{fa['per_hour']:.3g}/h (95 % {lo:.3g} to {hi:.3g})", ""]
    if ev["faults"]:
        lines += ["| fault | size | runs | P(detect) [95 %] | P(isolate) | median delay s |",
                  "|---|---|---|---|---|---|"]
        for f in ev["faults"]:
            d = "-" if f["delay_s_median"] is None else f"{f['delay_s_median']:.3g}"
            lines.append(f"| {f['fault']} | {f['size']:g} {f['unit']} | {f['runs']} | "
                         f"{f['pd']:.2f} [{f['pd_ci95'][0]:.2f}, {f['pd_ci95'][1]:.2f}] | "
                         f"{f['p_isolation']:.2f} | {d} |")
        lines.append("")
    if "detectable_sizes" in ev:
        lines += ["Detectable step (99 %, one full window, at rest), in σ:", "",
                  "| scale | measured [95 %] | rimu tune | ratio |", "|---|---|---|---|"]
        for r in ev["detectable_sizes"]["per_scale"]:
            m = r["measured_sigma"]
            lines.append(f"| {r['scale']} | {m:.3g} [{r['ci95_sigma'][0]:.3g}, "
                         f"{r['ci95_sigma'][1]:.3g}] | {r.get('predicted_sigma', float('nan')):.3g}"
                         f" | {r.get('ratio') or float('nan'):.3f} |")
        lines.append("")
    lines += ["Plots: roc.png, delay_vs_size.png, isolation_confusion.png"
              + (", detectable_sizes.png" if "detectable_sizes" in ev else ""), ""]
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    from fdi.fileio import to_jsonable
    from thresholds.evaluate import (
        corpus_task,
        design,
        execute,
        simulation_task,
        summarise,
    )
    from thresholds.plots import plot_all
    from thresholds.select import select
    from thresholds.tune import detectable_sizes

    if args.runs < 0 or args.sweep_runs < 0:
        raise ConfigError("--runs and --sweep-runs must be >= 0")
    if not (args.scheduler in ("serial", "local") or "://" in args.scheduler):
        raise ConfigError(f"unknown scheduler {args.scheduler!r}; expected serial, local or "
                          f"tcp://HOST:PORT")
    kinds = _kinds(args.faults)
    cal = load_calibration(args.cal)
    choice = select(cal, kind=args.kind, thresholds_file=args.thresholds,
                    false_alarms_per_hour=args.false_alarms_per_hour,
                    calibration_file=args.cal)
    thr = choice.thresholds
    if args.corpus:
        items = _corpus_items(args.corpus)
        task = corpus_task(cal, thr, args.kind)
    else:
        n_sweep = args.sweep_runs if cal.kind(args.kind).n >= 4 else 0   # no parity: no sweep
        items = design(cal, thr, runs=args.runs, seed=args.seed, faults=kinds,
                       sweep_runs=n_sweep, kind=args.kind, duration_s=args.duration,
                       onset_s=args.duration / 2, max_rate_dps=args.max_rate)
        task = simulation_task(cal, thr, args.kind)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    results = execute(task, items, scheduler=args.scheduler, progress=not args.no_progress,
                      workers=args.workers)
    wall = time.perf_counter() - t0
    sweep = any(getattr(x, "fault", "") == "sweep" for x in items)
    pred = detectable_sizes(cal, thr, kind=args.kind) if sweep else ()
    ev = summarise(results, thr, n_sensors=cal.kind(args.kind).n, predicted=pred)
    ev["source"] = "corpus" if args.corpus else "simulation"
    ev["threshold_choice"] = choice.to_dict()
    ev["campaign"] = {"seed": args.seed, "faults": list(kinds), "duration_s": args.duration,
                      "max_rate_dps": args.max_rate, "corpus": args.corpus}
    ev["timing"] = {"wall_s": wall, "scheduler": args.scheduler}
    (out / "evaluation.json").write_text(json.dumps(to_jsonable(ev), indent=1) + "\n",
                                         encoding="utf-8")
    plot_all(ev, out)
    (out / "summary.md").write_text(markdown(ev, choice.to_dict()), encoding="utf-8")
    fa = ev["false_alarms"]
    print(f"{len(results)} runs in {wall:.1f} s ({args.scheduler}); false alarms "
          f"{fa['count']} in {fa['exposure_h']:.2f} h = {fa['per_hour']:.3g}/h")
    for f in ev["faults"]:
        print(f"  {f['fault']:8s} {f['size']:8.3g} {f['unit']:8s} Pd {f['pd']:.2f} "
              f"isolated {f['p_isolation']:.2f} runs {f['runs']}")
    print(f"wrote {out / 'evaluation.json'}, summary.md and plots")
    return 0
