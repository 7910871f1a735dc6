"""``rimu calibrate in-flight DIR [DIR ...] --out CAL``: calibrate an IMU set against itself
in flight.

One of the procedures of :mod:`rimu.commands.calibrate`; fits every IMU of the flight
folder to the reference IMU (:mod:`calibration.inflight.fit`), writes the
``rimu.calibration/3`` file (:mod:`calibration.inflight.calfile`) and prints a summary.
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from fdi.calfile import Calibration

__all__ = ["HELP", "MODELS", "configure", "covered_range_text", "parse_window", "run",
           "summary_text"]

HELP = ("an IMU set against itself in flight (one or several flight folders): alignment, "
        "scale, bias and time offsets from the recorded motion")

MODELS = ("auto", "full", "rotation")
"""``--model`` (:data:`calibration.inflight.fit.MODELS`; kept here so that ``--help`` does
not import the fit; a test checks they agree)."""


def configure(p: argparse.ArgumentParser) -> None:
    """The options of ``rimu calibrate in-flight``."""
    p.add_argument("in_flight", metavar="DIR", nargs="+",
                   help="calibrate the IMUs of a flight folder (rimu.flight/1) against one of "
                        "them: alignment, bias and time offset from the recorded motion; what "
                        "the motion does not excite is held at the prior (--prior-*) and the "
                        "output says so. Several folders (one IMU set, several power-ups): "
                        "mounting, misalignment and scale fitted jointly, bias and time "
                        "offset per flight, their run-to-run spread written "
                        "(bias_turn_on_sd)")
    p.add_argument("--out", required=True, metavar="FILE",
                   help="calibration file to write (rimu.calibration/3 JSON)")
    p.add_argument("--window", metavar="T0:T1",
                   help="use only the part of the record from T0 to T1 s "
                        "(either may be empty: '30:' or ':95'), or 'flight' for the span "
                        "between the log's own arm/take-off and land/disarm events")
    p.add_argument("--prior-misalignment-deg", type=float, default=2.0, metavar="DEG",
                   help="1-sigma tolerance of each IMU's mounting about "
                        "its nominal (default 2)")
    p.add_argument("--prior-scale-pct", type=float, default=3.0, metavar="PCT",
                   help="1-sigma relative scale-factor tolerance (a "
                        "datasheet's; default 3)")
    p.add_argument("--prior-nonorthogonality-pct", type=float, default=2.0, metavar="PCT",
                   help="1-sigma cross-axis tolerance (default 2)")
    p.add_argument("--reference", metavar="IMU",
                   help="reference IMU group (default: the first)")
    p.add_argument("--model", choices=MODELS, default="auto",
                   help="'full' (rotation, scale, non-orthogonality, each "
                        "estimated or held at the prior), 'rotation' (scale and "
                        "non-orthogonality equal to the reference's), or 'auto' (= full; "
                        "default)")
    p.add_argument("--no-time-offset", action="store_true",
                   help="do not fit the time offsets")
    p.add_argument("--drift-model", action="store_true",
                   help="also measure the slow drift of the residual's "
                        "parity; rimu tune then covers the drift over its horizon (fewer "
                        "alarms on a drifting set, larger detectable sizes: docs/drift.md)")
    p.add_argument("--report", metavar="DIR",
                   help="write report.md and PNG plots (residual before "
                        "and after, the offset of each piece, the periods left out) into DIR")


def covered_range_text(cal: Calibration) -> str | None:
    """The range the gyro calibration's samples covered, one line (None: no range stated).

    Shared by ``rimu calibrate in-flight`` and ``rimu calibrate static``: beyond it the
    monitor marks its answers out of the envelope, and ``rimu tune``'s correction flights
    stay inside it.
    """
    from fdi.units import DPS, G0

    g = cal.gyro
    if g.validated_rate is None:
        return None
    digits = 2 if max(g.validated_rate) < 10 * DPS else 0
    force = (f", specific force {g.validated_specific_force / G0:.2f} g"
             if g.validated_specific_force is not None else "")
    jolt = (f", jolt {g.validated_jolt:.3g} m/s^2 per sample"
            if g.validated_jolt is not None else "")
    return ("covered range (the monitor marks what lies beyond as out of its envelope; rimu "
            "tune's correction flights stay inside it): rate "
            + " / ".join(f"{v / DPS:.{digits}f}" for v in g.validated_rate)
            + f" deg/s about x / y / z{force}{jolt}")


def summary_text(cal: Calibration) -> str:
    """Readable summary of an in-flight calibration (its ``extra.inflight`` block)."""
    from fdi.extras import ImuTiming
    from fdi.units import DPH, MS

    ex = cal.extras
    timing, doc = ex.inflight, ex.inflight_alignment
    if timing is None or doc is None:
        return f"calibration of {cal.configuration}: no in-flight record"
    lines = _record_lines(timing, doc)
    for g, r in doc.imus.items():
        lines += _imu_lines(g, r, timing.imus.get(g, ImuTiming(time_offset_s=None)),
                            timing.reference)
    for v in doc.flights:
        lines.append(f"  flight {v.source}:")
        for g, d in v.imus.items():
            lines.append(f"    {g}: bias [" + ", ".join(f"{x / DPH:+.1f}" for x in d["bias_dph"])
                         + "] deg/h, time offset "
                         + f"{d['time_offset_ms'][0] / MS:+.3f} ms")
    if timing.time_offset_sign:
        lines.append(f"  sign: {timing.time_offset_sign}")
    return "\n".join(lines)


def _record_lines(timing, doc) -> list[str]:
    """The head of :func:`summary_text`: samples used and left out, window, prior,
    findings."""
    lines = [f"in-flight calibration against {timing.reference} "
             f"({doc.samples_used} of {doc.samples} samples used)"]
    for s in doc.left_out:
        lines.append(f"  left out {s.t0_s:.2f}-{s.t1_s:.2f} s: {s.reason} ({s.detail})")
    if doc.samples_nonfinite:
        lines.append(f"  left out {doc.samples_nonfinite} samples with a non-finite rate "
                     "in some IMU")
    if doc.window_s:
        lines.append(f"  part of the record used: {doc.window_s[0]:.2f}-{doc.window_s[1]:.2f} s")
    if doc.prior:
        pr = doc.prior
        lines.append(f"  prior (held where the motion does not excite): mounting "
                     f"±{pr.get('misalignment_mrad_sd', 0) / 17.453293:.2g} deg, scale "
                     f"±{100 * pr.get('scale_sd', 0):.2g} %, non-orthogonality "
                     f"±{pr.get('nonorthogonality_mrad_sd', 0) / 10:.2g} %, time offset "
                     f"±{pr.get('time_offset_ms_sd', 0):.3g} ms (1 sigma)")
    for x in doc.findings:
        lines.append(f"  finding: {x}")
    return lines


def _imu_lines(g: str, r, t, reference: str) -> list[str]:
    """The lines of :func:`summary_text` on one IMU ``g`` (its alignment ``r`` and timing
    ``t``)."""
    import numpy as np

    from calibration.inflight.offset_check import check_lines
    from fdi.units import DPH, DPS, MS

    lines = []
    th, ths = 1e3 * np.asarray(r.rotation), 1e3 * np.asarray(r.rotation_sd)
    if r.mounting and not np.allclose(r.mounting, np.eye(3)):
        from calibration.inflight.prior import mounting_text

        lines.append(f"  {g}: mounted {mounting_text(np.asarray(r.mounting))} against "
                     f"{reference}; the parts below are beyond that mounting")
    if r.parameters:
        est = [p.name for p in r.parameters if p.status == "estimated"]
        held = [p.name for p in r.parameters if p.status != "estimated"]
        lines.append(f"  {g}: estimated: {', '.join(est) or 'none'}; held at the prior: "
                     f"{', '.join(held) or 'none'}")
    lines.append(f"  {g} ({r.model}): rotation [" + ", ".join(
        f"{a:+.3f} ± {b:.3f}" for a, b in zip(th, ths, strict=True)) + "] mrad")
    if r.model == "full":
        sc, scs = 1e6 * np.asarray(r.scale), 1e6 * np.asarray(r.scale_sd)
        lines.append("      scale difference [" + ", ".join(
            f"{a:+.0f} ± {b:.0f}" for a, b in zip(sc, scs, strict=True)) + "] ppm")
    lines.append("      bias [" + ", ".join(
        f"{a / DPH:+.1f} ± {b / DPH:.1f}" for a, b in zip(r.bias, r.bias_sd, strict=True))
        + "] deg/h")
    offset = ("not fitted" if t.time_offset_s is None else
              f"{t.time_offset_s / MS:+.3f} ± {t.time_offset_sd_s / MS:.3f} ms")
    lines.append(f"      time offset {offset}; residual rms [" + ", ".join(
        f"{x / DPS:.3g}" for x in r.residual_rms) + f"] deg/s; HAC lags {r.hac_lags}")
    lines.extend(f"      {x}" for x in check_lines(t.check))
    if t.timing_jitter_s is not None:
        lines.append(f"      timing jitter {g}: {t.timing_jitter_s / MS:.2f} ± "
                     f"{t.timing_jitter_sd_s / MS:.2f} ms (thresholds widen with it while "
                     "the body accelerates)")
    lines.extend(f"      note: {n}" for n in r.notes if not n.startswith("held at the prior"))
    return lines


def parse_window(text: str | None) -> tuple[float, float] | str | None:
    """``--window``: ``"T0:T1"`` (either side may be empty) as seconds, ``"flight"``, None.

    Raises
    ------
    ConfigError
        Not two numbers with T0 < T1 (the message shows the form).
    """
    import math

    from fdi.errors import ConfigError

    if text is None:
        return None
    if text.strip() == "flight":
        return "flight"
    parts = text.split(":")
    try:
        if len(parts) != 2:
            raise ValueError
        t0 = float(parts[0]) if parts[0].strip() else -math.inf
        t1 = float(parts[1]) if parts[1].strip() else math.inf
    except ValueError:
        raise ConfigError(f"--window {text!r}: expected T0:T1 in seconds (e.g. 30:95, 30: or "
                          ":95) or 'flight'") from None
    if math.isnan(t0) or math.isnan(t1) or not t0 < t1:
        raise ConfigError(f"--window {text!r}: T0 must be smaller than T1")
    return t0, t1


def _prior(args: argparse.Namespace):
    import math

    from calibration.inflight.prior import Prior

    return Prior(misalignment_sd=math.radians(getattr(args, "prior_misalignment_deg", 2.0)),
                 scale_sd=getattr(args, "prior_scale_pct", 3.0) / 100.0,
                 nonorthogonality_sd=getattr(args, "prior_nonorthogonality_pct", 2.0) / 100.0)


def run(args: argparse.Namespace) -> int:
    """Run ``rimu calibrate in-flight``."""
    from calibration.inflight.calfile import calibration_from_fit
    from calibration.inflight.fit import fit_inflight
    from calibration.inflight.segments import flight_window
    from replay.flight_io import load_flight_dir
    from rimu.outputs import atomic_file, input_path, output_file

    dirs = args.in_flight if isinstance(args.in_flight, list | tuple) else [args.in_flight]
    for d in dirs:
        input_path(d, "DIR", kind="dir")
    out = output_file(args.out, "--out", inputs=tuple(dirs))
    rep = None
    if getattr(args, "report", None):
        from rimu.outputs import output_dir

        rep = output_dir(args.report, "--report", inputs=tuple(dirs))
    window = parse_window(getattr(args, "window", None))
    prior = _prior(args)
    from fdi.progress import current

    flights, fits = [], []
    for d in dirs:
        current().stage(f"reading the flight folder {d}")
        flight = load_flight_dir(d)
        win = flight_window(flight) if window == "flight" else window
        if window == "flight":
            print(f"{d}: the log's events give the flight {win[0]:.2f}-{win[1]:.2f} s")
        flights.append(flight)
        current().stage("fitting the set against its reference (axes, scale, bias, time "
                        "offsets)")
        fits.append(fit_inflight(flight, reference=getattr(args, "reference", None),
                                 model=getattr(args, "model", "auto"),
                                 time_offset=not getattr(args, "no_time_offset", False),
                                 prior=prior, window=win))
    fit, flight, joint, values = _joined(fits, flights)
    turn_on = joint.turn_on_sd if joint is not None else None
    current().stage("noise, tails and drift of the residual")
    cal = calibration_from_fit(fit, flight,
                               drift_model=bool(getattr(args, "drift_model", False)),
                               turn_on_sd=turn_on, flights=values)
    from replay.time_base import with_time_base

    cal = with_time_base(cal, flight)       # gaps, duplicates, empty rows: in the file too
    if joint is not None:
        for n in joint.notes:
            print(f"note: {n}")
        from fdi.units import DPH

        print("turn-on bias run-to-run sd over " + f"{len(fits)} flights (bias_turn_on_sd): "
              + "; ".join(f"{c.name} {c.bias_turn_on_sd / DPH:.0f} deg/h" for c in cal.gyro.sensors
                          if c.bias_turn_on_sd is not None))
    with atomic_file(out) as tmp:
        cal.save(tmp)
    print(summary_text(cal))
    tails = _tails_line(cal)
    if tails is not None:
        print(tails)
    rng = covered_range_text(cal)
    if rng is not None:
        print(rng)
    print(f"wrote {out}")
    if rep is not None:
        _write_report(rep, flight, cal)
    return 0


def _joined(fits: list, flights: list) -> tuple:
    """(fit, flight, joint or None, per-flight values) of one flight or several of one set
    (:func:`calibration.inflight.multi.combine_fits`)."""
    if len(fits) == 1:
        return fits[0], flights[0], None, ()
    from calibration.inflight.calfile import flight_values
    from calibration.inflight.multi import combine_fits

    joint = combine_fits(fits)
    values = tuple(flight_values(f, fl) for f, fl in zip(fits, flights, strict=True))
    return joint.fit, flights[joint.base], joint, values


def _tails_line(cal: Calibration) -> str | None:
    """One line on the residual's tails (None: no tail model)."""
    tails = cal.gyro.tails
    if tails is None:
        return None
    bad = [str(r.scale) for r in tails.scales if not r.gaussian]
    r1 = tails.scales[0]
    return (f"residual tails ({tails.samples} samples): "
            + (f"not Gaussian at window(s) {', '.join(bad)}" if bad else "Gaussian white")
            + f"; w={r1.scale}: excess kurtosis {r1.excess_kurtosis:.3g}"
            + (f", GPD xi {r1.gpd.shape:.2f} +- {r1.gpd.shape_sd:.2f}" if r1.gpd else "")
            + " (rimu tune and the monitor overbound the non-Gaussian scales)")


def _write_report(rep, flight, cal: Calibration) -> None:
    """``--report DIR``: report.md and the plots, all or none."""
    from calibration.inflight.report import write_flight_plots
    from fdi.progress import current
    from rimu.outputs import atomic_dir

    current().stage("plots")

    with atomic_dir(rep) as tmp:        # the page and its plots: all or none
        pngs = write_flight_plots(flight, cal, tmp)
        (tmp / "report.md").write_text(
            "```\n" + summary_text(cal) + "\n```\n\n"
            + "".join(f"![{p.stem}]({p.name})\n" for p in pngs), encoding="utf-8")
    print(f"wrote {rep / 'report.md'} and {', '.join(p.name for p in pngs)}")
