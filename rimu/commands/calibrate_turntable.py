"""``rimu calibrate turntable SESSION --out cal.json``: calibrate a turntable session.

Reads a session directory (``calibration.session_io.load_session``), runs
:func:`calibration.calibrate.calibrate`, writes the ``rimu.calibration/3`` file and prints a
summary; ``--compare TRUTH`` adds estimate, truth, error and error/σ side by side.
"""

from __future__ import annotations

import argparse
import logging
from typing import TYPE_CHECKING

from fdi.errors import ConfigError
from fdi.units import input_unit_factor, scale_factor_from_si, scale_factor_sd_from_si

if TYPE_CHECKING:
    from fdi.calfile import Calibration, SensorSet
    from fdi.extras import NoiseModel

BIAS_METHODS = ("model", "turns")
"""``--bias-method`` (:data:`calibration.calibrate.BIAS_METHODS`; kept here so that
``rimu calibrate turntable --help`` does not import the calibration; a test checks they agree)."""
NOISE_MODELS = ("auto", "white")
"""``--noise-model`` (:data:`calibration.calibrate.NOISE_MODELS`, likewise)."""

HELP = ("turntable session (rate test + multi-position test): scale factor, bias, "
        "misalignment, noise, model adequacy and effect terms")


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("session", metavar="SESSION",
                   help="session directory (manifest.json + samples.csv)")
    p.add_argument("--out", required=True, metavar="FILE",
                   help="calibration file to write (rimu.calibration/3 JSON)")
    p.add_argument("--compare", metavar="TRUTH",
                   help="truth sidecar (DIR/truth.json): print estimate, truth, error, error/sd")
    p.add_argument("--bias-method", choices=BIAS_METHODS, default="model",
                   help="gyro bias in the file: explicit Earth-rate model (default) or seed "
                        "000's average over whole outer-axis turns; both are printed")
    p.add_argument("--noise-model", choices=NOISE_MODELS, default="auto",
                   help="uncertainties: 'auto' (default) adds a Gauss-Markov bias process "
                        "common to each sensor set when the residual spectrum shows one "
                        "(coloured noise, likelihood-ratio test); 'white' assumes white noise")
    p.add_argument("--no-denoise", action="store_true",
                   help="fit the Earth rate to the raw outputs, not the wavelet-denoised ones")
    p.add_argument("--plot", metavar="DIR",
                   help="write PNG plots (per-step residuals, Earth-rate fit) into DIR")
    p.add_argument("--sensor-class", choices=("fog", "mems"), default=None,
                   help="sensor class whose physical bounds label the effect terms of a "
                        "session's calibration (default: from the calibration's gyro "
                        "noise, docs/diagnose.md)")
    from rimu.commands.calibrate_effects import add_calibrate_options

    add_calibrate_options(p)

def _set_summary(s: SensorSet, V_sd: tuple[tuple[float, ...], ...] | None) -> list[str]:
    import numpy as np

    from fdi.parity import parity_matrix

    rms_unit = "deg/s" if s.kind == "gyro" else "mg"
    rf = input_unit_factor(rms_unit)
    out = [f"{s.kind}: {s.n} sensors"]
    for c in s.sensors:
        u = c.scale_factor_unit
        bf = input_unit_factor(c.bias_unit)
        m, msd = 1e3 * c.misalignment, 1e3 * np.asarray(c.misalignment_sd)
        out.append(
            f"  {c.name:>4s}  SF {scale_factor_from_si(c.scale_factor, u):.6g} ± "
            f"{scale_factor_sd_from_si(c.scale_factor, c.scale_factor_sd, u):.2g} {u}"
            f"   bias {c.bias / bf:+.6g} ± {c.bias_sd / bf:.2g} {c.bias_unit}"
            f"   misalignment ({m[0]:+.4f} ± {msd[0]:.4f}, {m[1]:+.4f} ± {msd[1]:.4f}) mrad"
            f"   residual rms {c.residual_rms / rf:.3g} {rms_unit}")
    for g, M in zip(s.groups, s.misalignment_matrices, strict=False):
        name = ",".join(str(i + 1) for i in g)
        rows = np.atleast_2d(M)
        out.append(f"  M (sensors {name}) =")
        out.extend("    [" + " ".join(f"{v:+.7f}" for v in r) + "]" for r in rows)
    V, Vc = parity_matrix(s.H_nominal), parity_matrix(s.H)
    out.extend("  v   = [" + " ".join(f"{x:+.5f}" for x in r) + "]" for r in V)
    sd = np.asarray(V_sd, float) if V_sd else None
    for k, r in enumerate(Vc):
        line = "  v_c = [" + " ".join(f"{x:+.5f}" for x in r) + "]"
        if sd is not None and sd.shape == Vc.shape:
            line += "  sd [" + " ".join(f"{x:.5f}" for x in sd[k]) + "]"
        out.append(line)
    return out


def _noise_lines(nm: NoiseModel | None) -> list[str]:
    """What the noise model did, per sensor set (``extra["noise_model"]``)."""
    from calibration.residuals import GM_LR_THRESHOLD
    from fdi.extras import SD_FACTOR_KEYS

    if nm is None:
        return []
    out = [f"noise model: {nm.method or '?'}"]
    for kind in ("gyro", "accel"):
        r = nm.sets.get(kind)
        if r is None:
            continue
        if not r.applied:
            lr = r.likelihood_ratio
            why = f" (likelihood ratio {lr:.2f} <= {GM_LR_THRESHOLD})" if lr is not None else ""
            out.append(f"  {kind}: white noise kept{why}")
            continue
        unit, f = ("deg/h", input_unit_factor("deg/h")) if kind == "gyro" else \
            ("mg", input_unit_factor("mg"))
        out.append(f"  {kind}: Gauss-Markov bias {r.bias_instability / f:.3g} {unit}, "
                   f"correlation {r.correlation_s:.3g} s (likelihood ratio "
                   f"{r.likelihood_ratio:.1f})")
        if r.sigma_correlation_s is not None:
            out.append(f"    sigma at correlation {r.sigma_correlation_s:.3g} s, bias "
                       f"{r.sigma_bias_instability / f:.3g} {unit} (largest bias variance "
                       "in the profile interval of the correlation time"
                       + (", cut at a quarter of the record: a slower process is not "
                          "excluded and would need wider sigma)" if r.sigma_cut
                          else ")"))
        out.append("    sd factors over white noise:")
        for name in SD_FACTOR_KEYS:
            out.append(f"    {name:<13s}"
                       + " ".join(f"{x:.2f}" for x in r.sd_factor.get(name, ())))
    return out


def summary_text(cal: Calibration, sensor_class: str | None = None) -> str:
    """The readable summary ``rimu calibrate turntable`` prints (``sensor_class``: the class whose
    physical bounds label the effect terms, default from the gyro noise)."""
    from fdi.units import DEG, DPH

    ex = cal.extras
    lines = [f"calibration of {ex.source or '?'} ({cal.configuration}, "
             f"{cal.sample_rate_hz:g} Hz, latitude {cal.latitude_deg} deg)"]
    for kind, s in cal.sets.items():
        lines.extend(_set_summary(s, ex.parity_sd.get(kind)))
    gb = ex.gyro_bias
    if gb is not None and gb.turns is not None:
        f = input_unit_factor(gb.unit)
        lines.append(f"gyro bias, both methods ({gb.unit}); file uses "
                     f"'{ex.method.part('bias', 'model')}':")
        for i, c in enumerate(cal.gyro.sensors):
            lines.append(f"  {c.name:>4s}  model {gb.model[i] / f:+.6g} ± {gb.model_sd[i] / f:.2g}"
                         f"   turns {gb.turns[i] / f:+.6g} ± {gb.turns_sd[i] / f:.2g}"
                         "   (vertical Earth rate removed: "
                         f"{gb.vertical_correction[i] / f:+.4g})")
    rt = ex.rate_test
    if rt is not None and rt.chi2_dof:
        lines.append("rate test: pairs " + " ".join(f"{a}/{b}" for a, b in rt.pairs)
                     + "; chi2/dof of the step differences: "
                     + " ".join(f"{x:.2f}" for x in rt.chi2_dof)
                     + "; of the per-step residual means: "
                     + " ".join(f"{x:.2f}" for x in ex.step_residual_chi2_dof))
    if cal.earth_rate_dph is not None:
        er = ex.earth_rate_fit
        lines.append(f"Earth rate from the outer-axis modulation: {cal.earth_rate_dph:.4f} ± "
                     f"{cal.earth_rate_dph_sd:.4f} deg/h"
                     + (f" ({len(er.steps)} steps, per-step scatter sd "
                        f"{er.scatter_sd / DPH:.3f}, heading of table zero "
                        f"{er.heading_offset / DEG:+.2f} ± {er.heading_offset_sd / DEG:.2f}"
                        " deg)" if er is not None else "")
                     + (" - not resolved at this noise level (below 3 sd)"
                        if cal.earth_rate_dph < 3 * (cal.earth_rate_dph_sd or 0.0) else ""))
    lines.extend(_noise_lines(ex.noise_model))
    from calibration.diagnose.adequacy_text import format_adequacy

    lines.extend(format_adequacy(cal, sensor_class=sensor_class))
    return "\n".join(lines)


def _flight_hint(path: str) -> None:
    """A flight folder given as a turntable session: say which option reads it."""
    from pathlib import Path

    from fdi.errors import FileFormatError
    from fdi.fileio import read_json_object

    m = Path(path) / "manifest.json"
    try:
        schema = str(read_json_object(m).get("schema", ""))
    except FileFormatError:         # the session loader reports a bad manifest itself
        return
    if schema.startswith("rimu.flight/"):
        raise ConfigError(f"{path}: is a flight folder ({schema}), not a turntable session; "
                          f"to calibrate its IMUs against each other use: rimu calibrate "
                          f"in-flight {path} --out FILE")


def run(args: argparse.Namespace) -> int:
    """Run ``rimu calibrate turntable``."""
    from calibration.session_io import load_session
    from fdi.calfile import check_plausible
    from rimu.commands.calibrate_effects import calibrate_with_check
    from rimu.outputs import atomic_file, input_path, output_dir, output_file

    input_path(args.session, "SESSION", kind="dir")
    _flight_hint(args.session)
    out = output_file(args.out, "--out", inputs=(args.compare,))
    if args.compare:
        input_path(args.compare, "--compare")
    if args.plot:
        output_dir(args.plot, "--plot", inputs=(args.session,))
    from fdi.progress import current

    current().stage("reading the session")
    session = load_session(args.session)
    truth = None
    if args.compare:
        from calibration.truth import load_truth

        truth, effects, effect_sensors = load_truth(args.compare)
    current().stage("calibrating (rate test, multi-position test, noise, model adequacy)")
    cal = calibrate_with_check(session, args, bias_method=args.bias_method,
                               denoise=not args.no_denoise, noise_model=args.noise_model)
    check_plausible(cal, str(args.session))
    compared = None
    if truth is not None:
        from calibration.compare import compare, format_comparison

        compared = format_comparison(compare(cal, truth, effects, effect_sensors))
    with atomic_file(out) as tmp:
        cal.save(tmp)
    print(summary_text(cal, sensor_class=args.sensor_class))
    for w in cal.extras.warnings:
        logging.getLogger("rimu").warning(w)
    print(f"wrote {out}")
    if compared is not None:
        print(f"\ncompared with {args.compare}:")
        print(compared)
    if args.plot:
        from calibration.plots import write_plots

        current().stage("plots")
        for p in write_plots(session, cal, args.plot):
            print(f"wrote {p}")
    return 0
