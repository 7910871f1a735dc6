"""``rimu diagnose SESSION --cal CAL``: find the effect the model lacks, refit, before/after.

See :mod:`calibration.diagnose` and ``docs/diagnose.md``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from rimu.argtypes import probability

HELP = ("find unmodelled effects in a calibration session or a flight folder, refit, "
        "report before and after")


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("session", metavar="DIR",
                   help="session directory (rimu.session/1) or flight folder (rimu.flight/1, "
                        "e.g. from rimu ingest)")
    p.add_argument("--cal", required=True, metavar="FILE",
                   help="calibration of this session (rimu calibrate turntable SESSION --out FILE)")
    p.add_argument("--alpha", type=probability(), default=0.01, metavar="A",
                   help="family-wise false-claim level of the tests (default 0.01)")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.add_argument("--report", metavar="DIR",
                   help="write a Markdown page with PNG plots into DIR")
    p.add_argument("--truth", metavar="TRUTH",
                   help="truth sidecar (DIR/truth.json): parameter errors in sigma before "
                        "and after the refit")
    p.add_argument("--sensor-class", choices=("fog", "mems"), default=None,
                   help="sensor class whose physical bounds label the effects found on a session "
                        "(default: from the calibration's gyro noise, docs/diagnose.md)")
    p.add_argument("--out", metavar="FILE",
                   help="write the refit calibration (rimu.calibration/3, with effects)")


def _p(e: dict) -> str:
    if e["p_value"] > 0 or e.get("log10_p_value") is None:
        return f"{e['p_value']:.2g}"
    return f"1e{e['log10_p_value']:.0f}"


def _fmt_list(xs: list, f: str = "{:.3g}") -> str:
    return " ".join(f.format(x) for x in xs)


def _unexplained_line(u: dict) -> str:
    """One line of unexplained structure: sensor, test, p-value, where it sits."""
    where = []
    if u.get("steps"):
        where.append("steps " + ", ".join(map(str, u["steps"])))
    if u.get("band_hz"):
        where.append(f"band {u['band_hz'][0]:.3g}-{u['band_hz'][1]:.3g} Hz")
    if u.get("time_s") is not None:
        where.append(f"near t = {u['time_s']:.1f} s")
    if u.get("segments"):                        # line_stationarity: amplitude per segment
        where.append("amplitude per segment " + " ".join(
            f"{g['amplitude']:.3g}±{g['amplitude_sd']:.2g}" for g in u["segments"])
            + f" {u.get('unit', '')}".rstrip())
    part = f"; partial fits not claimed: {', '.join(u['partial_fits'])}" \
        if u.get("partial_fits") else ""
    return (f"  {u['kind']} {u['sensor']} ({u['sensor_name']}): {u['test']} "
            f"p {u['p_value']:.2g}; " + ", ".join(where) + part)


def text(d) -> str:
    """Readable summary of a :class:`calibration.diagnose.Diagnosis`."""
    lines = [f"diagnosis at alpha {d.alpha:g} (Holm/Bonferroni over candidates x sensors)"]
    coloured = [k for k, v in getattr(d, "noise_null", {}).items() if v != "white"]
    if coloured:
        lines.append(f"tests against white + Gauss-Markov noise for the {', '.join(coloured)} "
                     "set (its residual reads as coloured; parameters profiled out)")
    if d.effects:
        lines.append("effects found:")
        for e in d.effects:
            lines.extend(_effect_lines(e))
    else:
        lines.append("effects found: none")
    if d.unexplained:
        lines.append("unexplained structure (no candidate explains it):")
        lines.extend(_unexplained_line(u) for u in d.unexplained_detail)
    else:
        lines.append("unexplained structure: none")
    a = d.calibration.adequacy or {}
    if a:
        from calibration.diagnose.adequacy_text import holdout_lines, limit_lines

        lines.append(f"verdict of the refit calibration: {d.verdict}")
        lines.extend(holdout_lines(a))
        lines.extend(limit_lines(a))
    nt = sorted({(n["name"], n["kind"], n["reason"]) for n in d.not_testable})
    for name, kind, why in nt:
        lines.append(f"not testable: {name} ({kind}): {why}")
    for label, e in (("before", d.error_before), ("after ", d.error_after)):
        lines.extend(_error_lines(label, e))
    return "\n".join(lines)


def _effect_lines(e: dict) -> list[str]:
    """One claimed effect: its estimate, p and parameters, its bound note and what it
    could be absorbing.

    Parameters
    ----------
    e : dict
        One of :attr:`calibration.diagnose.Diagnosis.effects`.

    Returns
    -------
    list of str
    """
    alias = f"  (strongly correlated on this sequence with {', '.join(e['aliases'])})" \
        if e["aliases"] else ""
    par = ", ".join(f"{k} {v:.4g}" for k, v in e["params"].items()
                    if isinstance(v, float))
    lines = [f"  {e['name']:<18s} {e['kind']} {e['sensors'][0]}: "
             f"{e['estimate']:+.4g} ± {e['estimate_sd']:.2g} {e['unit']}"
             f"   p {_p(e)}" + (f"   [{par}]" if par else "") + alias]
    if e.get("bound_note"):
        lines.append(f"    {'':<18s} {e['bound_note']}")
    if e.get("could_absorb"):
        lines.append(f"    {'':<18s} could instead be absorbing (outside the "
                     f"library): {e['could_absorb']}")
    return lines


def _error_lines(label: str, e: dict) -> list[str]:
    """Residual rms, step-mean χ²/dof and parity rms per kind, and the truth errors, before
    or after the refit.

    Parameters
    ----------
    label : str
        ``"before"`` or ``"after "``.
    e : dict
        :attr:`calibration.diagnose.Diagnosis.error_before` or ``error_after``.

    Returns
    -------
    list of str
    """
    lines = []
    for kind in e["residual_rms"]:
        u = e["unit"][kind]
        lines.append(f"{label} {kind}: residual rms [{u}] {_fmt_list(e['residual_rms'][kind])}"
                     f"; step-mean chi2/dof {_fmt_list(e['step_chi2_dof'][kind], '{:.2f}')}"
                     + (f"; parity rms [{u}] {_fmt_list(e['parity_rms'][kind])}"
                        if kind in e["parity_rms"] else ""))
    if "truth" in e:
        t = e["truth"]
        lines.append(f"{label} truth: max |error/sd| {t['max_abs_z']:.2f}, "
                     f"{t['n_beyond_3']} beyond 3 sigma, rms error/sd {t['rms_z']:.2f}")
    return lines


def _is_flight(path: str) -> bool:
    """True when ``path`` holds a ``rimu.flight/1`` manifest (else it is read as a session)."""
    from fdi.errors import FileFormatError
    from fdi.fileio import read_json_object

    try:
        doc = read_json_object(Path(path) / "manifest.json")
    except FileFormatError:
        return False
    return isinstance(doc, dict) and str(doc.get("schema", "")).startswith("rimu.flight/")


def _check_paths(args: argparse.Namespace):
    """Inputs exist, outputs writable and none of them an input: before any work."""
    from rimu.outputs import input_path, output_dir, output_file

    input_path(args.session, "DIR", kind="dir")
    input_path(args.cal, "--cal")
    if args.truth:
        input_path(args.truth, "--truth")
    ins = (args.session, args.cal, args.truth)
    out = output_file(args.out, "--out", inputs=ins) if args.out else None
    rep = output_dir(args.report, "--report", inputs=ins) if args.report else None
    if out is not None and rep is not None and (out.resolve() == rep.resolve()):
        from fdi.errors import ConfigError

        raise ConfigError(f"--out {out} and --report {rep}: the same path")
    return out, rep


def run(args: argparse.Namespace) -> int:
    out, rep = _check_paths(args)
    if _is_flight(args.session):
        from rimu.commands.diagnose_flight import run_flight

        if args.truth or args.out:
            from fdi.errors import ConfigError

            raise ConfigError(f"{args.session}: --truth and --out apply to turntable sessions, "
                              "not to flight folders")
        return run_flight(args.session, args.cal, alpha=args.alpha, as_json=args.json,
                          report_dir=args.report)
    from calibration.diagnose import diagnose
    from calibration.session_io import load_session
    from fdi.calfile import load_calibration
    from fdi.progress import current
    from rimu.outputs import atomic_dir, atomic_file

    current().stage("reading the session")
    session = load_session(args.session)
    cal = load_calibration(args.cal)
    truth = None
    if args.truth:
        from calibration.truth import load_truth

        truth = load_truth(args.truth)
    current().stage("diagnosing (residual, effects, refit)")
    d = diagnose(session, cal, alpha=args.alpha, truth=truth, cal_path=str(args.cal),
                 sensor_class=args.sensor_class)
    page = None
    if rep is not None:             # the page and its plots: all or none
        from calibration.diagnose.report import write_report

        with atomic_dir(rep) as tmp:
            page = rep / write_report(session, cal, d, tmp).relative_to(tmp)
    if out is not None:
        with atomic_file(out) as tmp:
            d.calibration.save(tmp)
    if args.json:
        from fdi.fileio import to_jsonable

        print(json.dumps(to_jsonable(d.to_json()), indent=1))
    else:
        print(text(d))
        if args.out:
            print(f"wrote {args.out}")
    if page is not None and not args.json:
        print(f"wrote {page}")
    return 0
