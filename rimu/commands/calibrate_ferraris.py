"""``rimu calibrate ferraris CSV --sample-rate-hz HZ --out CAL``: known-angle rotation
(Ferraris) sessions, one of the procedures of :mod:`rimu.commands.calibrate`."""

from __future__ import annotations

import argparse

from fdi.errors import ConfigError
from fdi.units import G0
from rimu.argtypes import bounded_float, nonnegative_float

__all__ = ["HELP", "configure", "run", "summary_lines"]

HELP = ("Ferraris session (static positions + known-angle rotations, imucal's procedure): "
        "scale factors, biases, axes and the gyro g-sensitivity")


MIN_ROTATION_DEG = 10.0
"""Smallest rotation angle (deg) the gyro scale factors can be fitted from."""


def configure(p: argparse.ArgumentParser) -> None:
    """The options of ``rimu calibrate ferraris``."""
    p.add_argument("ferraris", metavar="CSV",
                   help="the session: CSV with gyr_x..z, acc_x..z and a 'part' column "
                        "(x_p ... z_rot), or with --sections")
    p.add_argument("--out", required=True, metavar="FILE",
                   help="calibration file to write (rimu.calibration/3 JSON)")
    p.add_argument("--sections", metavar="JSON",
                   help="section list {\"x_p\": {\"start\": i, \"end\": j}, ...} (0-based rows, "
                        "end exclusive) for a CSV without a 'part' column")
    p.add_argument("--sample-rate-hz", metavar="HZ",
                   type=bounded_float(1.0, 1e6, name="sample rate in Hz"),
                   help="sample rate of the CSV (required: the CSV does not hold it)")
    p.add_argument("--rotation-deg", default=-360.0,
                   type=bounded_float(-3600.0, 3600.0, min_abs=MIN_ROTATION_DEG,
                                      name="rotation in deg"),
                   help="nominal rotation angle about each axis (default -360: clockwise "
                        "seen from above, imucal's convention)")
    p.add_argument("--gravity", type=bounded_float(0.1, 100.0, name="gravity in m/s^2"),
                   default=G0,
                   help=f"local gravity in m/s^2 (default {G0})")
    p.add_argument("--position-sd-deg", type=nonnegative_float(90.0), default=1.0,
                   help="sd of each tilt component of a position or rotation axis (default 1)")
    p.add_argument("--angle-sd-deg", type=nonnegative_float(360.0), default=1.0,
                   help="sd of each rotation angle (default 1)")
    p.add_argument("--latitude-deg", type=bounded_float(-90.0, 90.0, name="latitude in deg"),
                   default=None,
                   help="latitude: removes the vertical Earth rate from the static gyro "
                        "means (default: counted as an uncertainty)")
    p.add_argument("--raw-unit", default="count",
                   help="unit of the raw outputs in the CSV (default count)")


def summary_lines(cal) -> list[str]:
    """Readable result: per sensor SF, bias, axis with sds, imucal's matrices."""
    import numpy as np

    from fdi.units import DEG, input_unit_factor

    ex = cal.extras
    fe = ex.ferraris
    out = [f"Ferraris calibration of {ex.source} ({cal.sample_rate_hz:g} Hz; "
           f"rotation {fe.rotation / DEG:g} deg, position sd {fe.position_sd / DEG:g} deg, "
           f"angle sd {fe.angle_sd / DEG:g} deg, gravity {fe.gravity:g} m/s^2)"]
    for kind, per in (("gyro", "deg/s"), ("accel", "m/s^2")):
        s = cal.sets[kind]
        f = input_unit_factor(per) if kind == "gyro" else 1.0
        out.append(f"{kind}: counts per {per} (imucal K), bias in counts (imucal b), axis "
                   "(imucal R row), misalignment mrad")
        for c in s.sensors:
            k = f / c.scale_factor
            m, msd = 1e3 * c.misalignment, 1e3 * np.asarray(c.misalignment_sd)
            out.append(
                f"  {c.name}  K {k:.6g} ± {k * c.scale_factor_sd / c.scale_factor:.2g}"
                f"   b {c.bias / c.scale_factor:+.5g} ± {c.bias_sd / c.scale_factor:.2g}"
                f"   axis [{' '.join(f'{x:+.5f}' for x in c.axis)}]"
                f"   misalignment ({m[0]:+.2f} ± {msd[0]:.2f}, {m[1]:+.2f} ± {msd[1]:.2f})")
    k, ksd = fe.g_sensitivity_raw_per_m_s2, fe.g_sensitivity_raw_per_m_s2_sd
    out.append("gyro g-sensitivity, counts per m/s^2 (imucal K_ga):")
    out.extend("  " + "  ".join(f"{v:+.5f} ± {e:.5f}" for v, e in zip(r, re, strict=True))
               for r, re in zip(k, ksd, strict=True))
    c2 = fe.chi2_dof
    out.append(f"static fits, chi2/dof ({fe.chi2_dof_dof} dof per sensor): accel "
               + " ".join(f"{x:.2f}" for x in c2.get("accel", ())) + "; gyro "
               + " ".join(f"{x:.2f}" for x in c2.get("gyro", ()))
               + "; rotations: 0 spare dof (their sd rests on --angle-sd-deg)")
    out.extend(f"warning: {w}" for w in ex.warnings)
    return out


def run(args: argparse.Namespace) -> int:
    """Run ``rimu calibrate ferraris``: load, calibrate, write, print."""
    from calibration.ferraris import FerrarisOptions, ferraris_calibrate
    from calibration.ferraris_io import load_ferraris
    from rimu.outputs import atomic_file, input_path, output_file

    if args.sample_rate_hz is None:
        raise ConfigError("rimu calibrate ferraris needs --sample-rate-hz (the CSV does not "
                          "hold it)")
    input_path(args.ferraris, "CSV")
    if args.sections:
        input_path(args.sections, "--sections")
    out = output_file(args.out, "--out", inputs=(args.ferraris, args.sections))
    s = load_ferraris(args.ferraris, args.sample_rate_hz, sections=args.sections,
                      gyro_raw_unit=args.raw_unit, accel_raw_unit=args.raw_unit)
    opt = FerrarisOptions(rotation_deg=args.rotation_deg, gravity=args.gravity,
                          position_sd_deg=args.position_sd_deg,
                          angle_sd_deg=args.angle_sd_deg, latitude_deg=args.latitude_deg)
    cal = ferraris_calibrate(s, opt)
    with atomic_file(out) as tmp:
        cal.save(tmp)
    print("\n".join(summary_lines(cal)))
    print(f"wrote {out}")
    return 0
