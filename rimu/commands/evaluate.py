"""``rimu evaluate --cal CAL --out DIR``: Monte Carlo (or corpus) evaluation of the monitor."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from fdi.errors import ConfigError
from rimu.argtypes import (
    DAY_S,
    MAX_RUNS,
    SEED_MAX,
    choice_or_url,
    nonnegative_int,
    positive_float,
    positive_int,
)

MAX_WORKERS = 256
SAMPLE_BUDGET = 100_000_000
"""Most simulated samples (runs × duration × rate, summed) evaluated without ``--yes``:
about 280 flight-hours at 100 Hz, some tens of minutes on one core."""
"""Most LocalCluster workers."""

HELP = ("evaluate the monitor on simulated flights (every fault kind, a sweep of sizes) or a "
        "corpus of flight folders: detection, delay, isolation, false alarms, ROC")


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("--cal", required=True, metavar="FILE", help="calibration file")
    p.add_argument("--thresholds", metavar="FILE",
                   help="rimu.thresholds/2 (or /1) or rimu.tuning/1 file (default: computed from "
                        "the calibration for --false-alarms-per-hour)")
    p.add_argument("--false-alarms-per-hour", type=positive_float(3.6e6), metavar="X",
                   help="budget for computed thresholds (default 1e-3)")
    p.add_argument("--runs", type=nonnegative_int(MAX_RUNS), default=200, metavar="N",
                   help="simulated flights (default 200)")
    p.add_argument("--sweep-runs", type=nonnegative_int(MAX_RUNS), default=220, metavar="N",
                   help="extra short runs measuring the detectable step per scale, compared "
                        "with rimu tune's prediction (default 220; 0: none)")
    p.add_argument("--seed", type=nonnegative_int(SEED_MAX), default=0,
                   help="campaign seed (default 0)")
    p.add_argument("--faults", metavar="KINDS",
                   help="comma-separated fault kinds (default: all of step, ramp, stuck, "
                        "noise, scale, spike, dropout)")
    p.add_argument("--duration", type=positive_float(DAY_S), default=60.0, metavar="S",
                   help="flight length (default 60 s; faults start half-way)")
    p.add_argument("--max-rate", type=positive_float(1e5), default=300.0, metavar="DPS",
                   help="largest body rate of the manoeuvres (default 300 deg/s)")
    p.add_argument("--kind", default="gyro", choices=("gyro", "accel"))
    p.add_argument("--corpus", metavar="DIR",
                   help="evaluate the flight folders (rimu.flight/1) under DIR instead")
    p.add_argument("--scheduler", default="serial", metavar="WHERE",
                   type=choice_or_url(("serial", "local")),
                   help="serial (default), local (a Dask LocalCluster on this machine) or "
                        "tcp://HOST:PORT (an existing Dask scheduler)")
    p.add_argument("--workers", type=positive_int(MAX_WORKERS), default=2,
                   help="LocalCluster workers (default 2)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--yes", action="store_true",
                   help=f"run a campaign beyond the budget of {SAMPLE_BUDGET:.0e} simulated "
                        "samples (refused up front without it)")
    p.add_argument("--baseline", metavar="NAMES",
                   help="also run the autopilots' own rules on the same samples of every "
                        "run (px4, px4-others, ardupilot, or all; the set must be IMUs of "
                        "three axes): their false alarms, detection, right blame and delay "
                        "beside rimu's in evaluation.json, summary.md and baselines.png")
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
    from fdi.errors import FileFormatError
    from fdi.fileio import read_json_object

    root = Path(d)
    if not root.is_dir():
        raise ConfigError(f"--corpus {d}: not a directory")
    dirs, other = [], []
    for m in sorted(root.rglob("manifest.json")):
        try:
            schema = str(read_json_object(m).get("schema", ""))
        except FileFormatError:
            schema = "?"
        (dirs if schema.startswith("rimu.flight/") else other).append((m.parent, schema))
    if other:
        where, schema = other[0]
        raise ConfigError(f"--corpus {d}: {where} is a {schema} folder, not a flight folder "
                          "(rimu.flight/1); a corpus holds flight folders only")
    if not dirs:
        raise ConfigError(f"--corpus {d}: no flight folder (manifest.json) under it")
    return [(k, str(p)) for k, (p, _) in enumerate(dirs)]


def _check_triads(cal: object, kind: str, where: str) -> None:
    """--baseline needs a set of IMUs of three axes (imu1.x …)."""
    from replay.time_offsets import imu_groups

    names = [c.name for c in cal.kind(kind).sensors]  # type: ignore[attr-defined]
    groups: dict[str, int] = {}
    for g in imu_groups(names):
        groups[g] = groups.get(g, 0) + 1
    if "" in groups or len(groups) < 2 or any(v != 3 for v in groups.values()):
        raise ConfigError(f"--baseline: {where} is not a set of two or more IMUs of three "
                          f"axes (sensors {', '.join(names[:6])}{' …' if len(names) > 6 else ''}"
                          "): the autopilot rules compare whole IMUs")


def _baseline_markdown(ev: dict) -> list[str]:
    """The baselines' table of summary.md."""
    b = ev.get("baselines")
    if not b:
        return []
    lines = ["Autopilot rules on the same samples (--baseline; docs/baselines.md):", ""]
    for nm, rule in b["rules"].items():
        lines += [f"- {nm}: false alarms {_false_alarm_text(rule['false_alarms'])}", ""]
        if rule["faults"]:
            lines += ["| fault | size | runs | P(detect) | P(right blame) | rimu P(isolate, "
                      "per IMU) | median delay s |", "|---|---|---|---|---|---|---|"]
            for f in rule["faults"]:
                d = "-" if f["delay_s_median"] is None else f"{f['delay_s_median']:.3g}"
                lines.append(f"| {f['fault']} | {f['size']:g} {f['unit']} | {f['runs']} | "
                             f"{f['pd']:.2f} | {f['p_blame_correct']:.2f} | "
                             f"{f['rimu_p_isolation_imu']:.2f} | {d} |")
            lines.append("")
    return lines


def markdown(ev: dict, how: dict) -> str:
    """A short Markdown summary of ``evaluation.json``."""
    fa = ev["false_alarms"]
    lines = ["# rimu evaluation", "",
             f"- thresholds: {how.get('source')} ({ev['thresholds']['false_alarms_per_hour']:g} "
             f"false alarms/h target), scales {ev['thresholds']['scales']}",
             f"- runs: {ev['runs']}" + (
                 f" ({ev['runs'] - ev['detectable_sizes']['runs']} flights + "
                 f"{ev['detectable_sizes']['runs']} sweep runs of the detectable step, "
                 "--sweep-runs)" if "detectable_sizes" in ev else ""),
             f"- false alarms: {_false_alarm_text(fa)}", ""]
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
            m, lo, hi = (float("nan") if x is None else x
                         for x in (r["measured_sigma"], *r["ci95_sigma"]))
            meas = (f"{m:.3g} [{lo:.3g}, {hi:.3g}]" if m == m else
                    f"between {lo:.3g} and {hi:.3g} (no overlap of misses and hits: no fit)"
                    if lo == lo else "-")
            lines.append(f"| {r['scale']} | {meas} | {r.get('predicted_sigma', float('nan')):.3g}"
                         f" | {r.get('ratio') or float('nan'):.3f} |")
        lines.append("")
    lines += _baseline_markdown(ev)
    lines += ["Plots: roc.png, delay_vs_size.png, isolation_confusion.png"
              + (", detectable_sizes.png" if "detectable_sizes" in ev else "")
              + (", baselines.png" if "baselines" in ev else ""), ""]
    return "\n".join(lines)


def _check_budget(items: list, rate_hz: float, args: argparse.Namespace) -> None:
    """Say what will run; refuse a campaign beyond :data:`SAMPLE_BUDGET` unless ``--yes``."""
    from fdi.errors import ConfigError

    n_flights = sum(x.fault != "sweep" for x in items)
    samples = sum(x.duration_s for x in items) * float(rate_hz)
    hours = sum(x.duration_s for x in items) / 3600.0
    plan = (f"{n_flights} flight(s) of {args.duration:g} s"
            + (f" + {len(items) - n_flights} short sweep run(s) (--sweep-runs)"
               if len(items) > n_flights else "")
            + f": {hours:.3g} simulated hours, {samples:.3g} samples at {rate_hz:g} Hz")
    if samples > SAMPLE_BUDGET and not args.yes:
        raise ConfigError(f"evaluate: {plan}, beyond the budget of {SAMPLE_BUDGET:.0e} samples: "
                          "give fewer --runs or a shorter --duration, or --yes to run it")
    print(f"evaluate: {plan}", flush=True)


def _false_alarm_text(fa: dict) -> str:
    """``N in X h = r/h (95 % lo to hi)`` of rimu's or a rule's false alarms, or no rate
    where there was no flight time."""
    lo, hi = fa["ci95_per_hour"]
    rate = (f"{fa['per_hour']:.3g}/h (95 % {lo:.3g} to {hi:.3g})" if fa["exposure_h"] > 0
            else _rate_text(fa))
    return f"{fa['count']} in {fa['exposure_h']:.2f} h = {rate}"


def _rate_text(fa: dict) -> str:
    return (f"{fa['per_hour']:.3g}/h" if fa["exposure_h"] > 0 else
            "no rate (no flight time: --runs 0)")


def run(args: argparse.Namespace) -> int:
    from fdi.calfile import load_calibration
    from fdi.fileio import to_jsonable
    from replay.baselines import parse_baselines
    from replay.threshold_choice import select
    from rimu.outputs import atomic_dir, input_path, output_dir
    from thresholds.evaluate import (
        corpus_task,
        design,
        execute,
        simulation_task,
        summarise,
    )
    from thresholds.plots import plot_all
    from thresholds.tune import detectable_sizes

    kinds = _kinds(args.faults)
    baselines = parse_baselines(args.baseline)
    input_path(args.cal, "--cal")
    if args.thresholds:
        input_path(args.thresholds, "--thresholds")
    out = output_dir(args.out, "--out", inputs=(args.corpus, args.cal, args.thresholds))
    cal = load_calibration(args.cal)
    choice = select(cal, kind=args.kind, thresholds_file=args.thresholds,
                    false_alarms_per_hour=args.false_alarms_per_hour,
                    calibration_file=args.cal)
    thr = choice.thresholds
    if baselines:
        _check_triads(cal, args.kind, args.cal)
    if args.corpus:
        items = _corpus_items(args.corpus)
        task = corpus_task(cal, thr, args.kind, baselines)
    else:
        n_sweep = args.sweep_runs if cal.kind(args.kind).n >= 4 else 0   # no parity: no sweep
        items = design(cal, thr, runs=args.runs, seed=args.seed, faults=kinds,
                       sweep_runs=n_sweep, kind=args.kind, duration_s=args.duration,
                       onset_s=args.duration / 2, max_rate_dps=args.max_rate)
        task = simulation_task(cal, thr, args.kind, baselines)
        _check_budget(items, cal.sample_rate_hz, args)
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
    with atomic_dir(out) as tmp:        # all files or none
        (tmp / "evaluation.json").write_text(json.dumps(to_jsonable(ev), indent=1) + "\n",
                                             encoding="utf-8")
        plot_all(ev, tmp)
        if "baselines" in ev:
            from thresholds.plots import plot_baselines

            plot_baselines(ev, tmp / "baselines.png")
        (tmp / "summary.md").write_text(markdown(ev, choice.to_dict()), encoding="utf-8")
    fa = ev["false_alarms"]
    n_flights = sum(getattr(x, "fault", "") != "sweep" for x in items)
    what = (f" ({n_flights} flights + {len(items) - n_flights} sweep runs of the detectable "
            "step, --sweep-runs)" if len(items) > n_flights else "")
    print(f"{len(results)} runs{what} in {wall:.1f} s ({args.scheduler}); false alarms "
          f"{fa['count']} in {fa['exposure_h']:.2f} h = {_rate_text(fa)}")
    for f in ev["faults"]:
        print(f"  {f['fault']:8s} {f['size']:8.3g} {f['unit']:8s} Pd {f['pd']:.2f} "
              f"isolated {f['p_isolation']:.2f} runs {f['runs']}")
    for nm, rule in ev.get("baselines", {}).get("rules", {}).items():
        fa = rule["false_alarms"]
        print(f"  baseline {nm}: false alarms {fa['count']} in {fa['exposure_h']:.2f} h")
        for f in rule["faults"]:
            print(f"    {f['fault']:8s} {f['size']:8.3g} {f['unit']:8s} Pd {f['pd']:.2f} "
                  f"right blame {f['p_blame_correct']:.2f} (rimu per IMU "
                  f"{f['rimu_p_isolation_imu']:.2f})")
    print(f"wrote {out / 'evaluation.json'}, summary.md and plots")
    return 0
