"""``rimu repeat SESSION SESSION [...]``: run-to-run repeatability and stacking of sessions.

Calibrates each session as ``rimu calibrate`` does (with the adequacy check), compares
their parameters against the reported σ (turn-on to turn-on repeatability), and, when the
sessions share one sequence, calibrates their sample-by-sample mean (a repeating warm-up
stays, an independent wander drops by √N). See :mod:`calibration.repeat`,
:mod:`calibration.stack` and ``docs/diagnose.md`` ("Repeated sessions").
"""

from __future__ import annotations

import argparse
import json

from fdi.adequacy import SUSPECTED
from rimu.argtypes import probability

HELP = ("compare repeated calibration sessions (run-to-run repeatability) and stack them "
        "to find effects that repeat at every switch-on")


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("sessions", nargs="+", metavar="SESSION",
                   help="session directories (rimu.session/1), at least two, of one IMU")
    p.add_argument("--alpha", type=probability(), default=0.01, metavar="A",
                   help="family-wise level of the repeatability tests and of each adequacy "
                        "check (default 0.01)")
    p.add_argument("--json", action="store_true", help="print the result as JSON "
                   "(schema rimu.repeat/1)")
    p.add_argument("--out", metavar="DIR",
                   help="write each session's calibration, the stacked session and its "
                        "calibration into DIR")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--stack", dest="stack", action="store_true", default=None,
                   help="require stacking (fail when the sequences differ)")
    g.add_argument("--no-stack", dest="stack", action="store_false",
                   help="compare parameters only")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def _fmt(v: float) -> str:
    return f"{v:.3g}"


def run_sd_text(run_sd: float, lo: float, hi: float) -> str:
    """The run-to-run sd and its interval; an empty Q-profile interval (the scatter is
    below even the low quantile the reported sigma predict: both ends 0) is said, not
    printed as [0, 0], which would claim a run-to-run sd of exactly 0."""
    if hi <= 0.0:
        return "0 (scatter below the sigma: no interval)"
    return f"{_fmt(run_sd)} [{_fmt(lo)}, {_fmt(hi)}]"


def repeat_text(res) -> str:
    """The readable report of a :class:`calibration.repeat.RepeatResult`."""
    rep = res.repeatability
    n = rep.n_sessions
    lines = [f"{n} sessions:"]
    for k, (src, c) in enumerate(zip(res.sources, res.calibrations, strict=True), 1):
        lines.append(f"  {k}. {src}: {(c.adequacy or {}).get('verdict', '?')}")
    lines += ["", f"run-to-run repeatability (alpha {rep.alpha}, Holm over "
              f"{len(rep.parameters)} parameters; chi2 of the scatter about the weighted "
              f"mean against the reported sigma, {n - 1} dof; run-to-run sd beyond the "
              f"reported sigma with its {rep.ci_level:.0%} interval):",
              f"  {'sensor':<10s}{'parameter':<16s}{'mean':>12s}{'± sd':>10s} {'unit':<12s}"
              f"{'chi2':>8s}{'p':>10s}  {'run-to-run sd [CI]':<26s}verdict"]
    for p in rep.parameters:
        lo, hi = p.run_sd_ci
        mean = "-" if p.parameter == "scale_factor" else _fmt(p.mean)
        lines.append(f"  {p.kind + ' ' + p.sensor_name:<10s}{p.parameter:<16s}{mean:>12s}"
                     f"{_fmt(p.mean_sd):>10s} {p.unit:<12s}{p.chi2:8.2f}{p.p_value:10.2g}  "
                     f"{run_sd_text(p.run_sd, lo, hi):<26s}"
                     f"{p.verdict}")
    fl = rep.flagged()
    if fl:
        lines.append(f"  {len(fl)} of {len(rep.parameters)} scatter beyond their sigma: the "
                     "single-session sigma are too small for use from one switch-on to the "
                     "next (a bias wander slower than the record, or turn-on repeatability); "
                     "for run-to-run use take sqrt(sd^2 + run-to-run sd^2)")
    else:
        lines.append(f"  all {len(rep.parameters)} parameters repeatable within their sigma")
    sus = [str(k) for k, c in enumerate(res.calibrations, 1)
           if (c.adequacy or {}).get("verdict") == SUSPECTED]
    if sus:
        lines.append(f"  note: session{'s' if len(sus) > 1 else ''} {', '.join(sus)} "
                     "had effects suspected: their sigma are the white-noise sigma (the "
                     "Gauss-Markov widening is withheld), so under a bias wander their "
                     "biases can scatter beyond them; the stack below says what repeats")
    lines.append("")
    if res.stack is None:
        lines.append(f"stacking skipped: {res.stack_skipped}" +
                     ("" if res.stack_skipped == "not asked for" else
                      " (stacking needs identical sequences: same configuration, steps, "
                      "sample times and table motion)"))
    else:
        from calibration.diagnose.adequacy_text import format_adequacy

        lines.append(f"stack of {res.stack.n_sessions} sessions (sample-by-sample mean: an "
                     "effect that repeats at the same time after switch-on keeps its size, "
                     f"independent noise drops by sqrt({res.stack.n_sessions})):")
        lines.extend("  " + ln for ln in format_adequacy(res.stack.calibration))
        if (res.stack.adequacy or {}).get("verdict") == SUSPECTED:
            lines.append("  the effects repeat at every switch-on: size them with rimu "
                         "diagnose on the stacked session (--out DIR writes it and its "
                         "calibration)")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    from calibration.repeat import repeat_sessions
    from calibration.session_io import load_session, save_session
    from fdi.errors import ConfigError
    from rimu.outputs import atomic_dir, distinct_inputs, input_path, output_dir

    if len(args.sessions) < 2:
        raise ConfigError(f"rimu repeat: give at least two sessions to compare, got one "
                          f"({args.sessions[0]})")
    for s in args.sessions:
        input_path(s, "SESSION", kind="dir")
    distinct_inputs(args.sessions, "SESSION")     # a session with itself repeats trivially
    out = output_dir(args.out, "--out", inputs=args.sessions) if args.out else None
    sessions = [load_session(s) for s in args.sessions]
    res = repeat_sessions(sessions, alpha=args.alpha, stack=args.stack,
                          progress=not args.no_progress)
    if out is not None:
        written = []
        with atomic_dir(out) as tmp:        # every file or none
            for k, c in enumerate(res.calibrations, 1):
                c.save(tmp / f"calibration_{k}.json")
                written.append(out / f"calibration_{k}.json")
            if res.stack is not None:
                save_session(res.stack.session, tmp / "stacked")
                written.append(out / "stacked")
                res.stack.calibration.save(tmp / "stacked_calibration.json")
                written.append(out / "stacked_calibration.json")
            (tmp / "repeat.json").write_text(json.dumps(res.to_dict(), indent=1,
                                                        allow_nan=False, default=float),
                                             encoding="utf-8")
            written.append(out / "repeat.json")
    if args.json:
        print(json.dumps(res.to_dict(), indent=1, allow_nan=False, default=float))
    else:
        print(repeat_text(res))
        for p in written if out is not None else []:
            print(f"wrote {p}")
    return 0
