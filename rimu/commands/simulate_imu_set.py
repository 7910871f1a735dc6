"""``rimu simulate flight --imus K``: a flight of several three-axis IMUs with a truth sidecar.

Reached through ``rimu simulate flight`` (its ``--imus`` option); builds a
:class:`replay.imu_set.ImuSetSpec` from the options and writes the flight folder.
"""

from __future__ import annotations

import argparse

from fdi.errors import ConfigError
from fdi.units import DPH, DPS, G0, MS
from rimu.argtypes import (
    MAX_SAMPLES,
    float_list,
    nonnegative_float,
    positive_float,
    positive_int,
)

MAX_IMUS = 16
"""At most this many IMUs in one simulated set."""
MAX_TIME_OFFSET_MS = 1000.0
"""Largest time offset of one IMU (ms)."""
IMU_ONLY = ("--time-offset-ms", "--timing-jitter-ms", "--vibration", "--effect-imus")
"""Options of ``--imus`` refused without it (their defaults are empty)."""

__all__ = ["check_imu_options", "configure_options", "run"]


def configure_options(p: argparse.ArgumentParser) -> None:
    """The options ``rimu simulate flight`` adds for ``--imus``."""
    g = p.add_argument_group("several IMUs (--imus K; --cal not needed)")
    g.add_argument("--imus", type=positive_int(MAX_IMUS), metavar="K",
                   help="simulate K three-axis IMUs (gyros monitored, accelerometers and "
                        "temperatures kept beside them)")
    g.add_argument("--time-offset-ms", default=(), metavar="T1,T2,...",
                   type=float_list(-MAX_TIME_OFFSET_MS, MAX_TIME_OFFSET_MS,
                                   name="time offsets in ms"),
                   help="time offset of each IMU in ms (K values; default all 0)")
    g.add_argument("--timing-jitter-ms", default=(), metavar="S1,S2,...",
                   type=float_list(0.0, MAX_TIME_OFFSET_MS, name="jitters in ms"),
                   help="sd of each IMU's random sampling-time error in ms, independent per "
                        "sample (K values; default all 0)")
    g.add_argument("--misalignment-mrad", type=nonnegative_float(1e3), default=10.0, metavar="X",
                   help="sd of each IMU's misalignment angles (mrad, default 10)")
    g.add_argument("--scale-ppm", type=nonnegative_float(1e6), default=5000.0, metavar="X",
                   help="sd of each scale error (ppm, default 5000)")
    g.add_argument("--gyro-noise-dps", type=nonnegative_float(1e3), default=2e-3 / DPS, metavar="X",
                   help="gyro white noise per sample (deg/s, default 0.115)")
    g.add_argument("--g-sensitivity", type=nonnegative_float(1e3), default=0.0, metavar="DPS_PER_G",
                   help="sd of each g-sensitivity entry ((deg/s)/g; default 0)")
    g.add_argument("--warm-up", type=nonnegative_float(1e3), default=0.0, metavar="DPS",
                   help="sd of the warm-up bias at t=0 (deg/s; decays in --warm-up-s)")
    g.add_argument("--warm-up-s", type=positive_float(1e6), default=60.0, metavar="S")
    g.add_argument("--temperature-coeff", type=nonnegative_float(1e3), default=0.0,
                   metavar="DPS_PER_C",
                   help="sd of the bias temperature coefficient ((deg/s)/degC; temperatures "
                        "are then logged)")
    g.add_argument("--vibration", default=(), metavar="HZ:DPS",
                   type=float_list(0.0, 1e6, count=2, sep=":", name="non-negative numbers"),
                   help="a vibration line: frequency (aliased above Nyquist) and sd of its "
                        "amplitude per axis")
    g.add_argument("--drift", type=nonnegative_float(1e6), default=0.0, metavar="DPH_PER_RTS",
                   help="bias random walk ((deg/h)/sqrt(s); default 0)")
    g.add_argument("--effect-imus", default=(), metavar="J,...",
                   type=float_list(1, MAX_IMUS, name="IMU numbers"),
                   help="IMUs (1-based) that carry the effects (default all)")


def check_imu_options(args: argparse.Namespace) -> None:
    """Refuse what ``--imus`` cannot honour, and its options without it (one line each)."""
    from rimu.argtypes import refuse_together

    if not getattr(args, "imus", None):
        for opt in IMU_ONLY:
            if getattr(args, opt[2:].replace("-", "_")):
                raise ConfigError(f"rimu simulate flight: {opt} applies to --imus only")
        return
    given = {"--imus": args.imus, "--cal": args.cal, "--fault": args.fault,
             "--truth": args.truth, "--effects-from-cal": args.effects_from_cal,
             "--kind accel": args.kind == "accel" or None}
    refuse_together("rimu simulate flight", given, "--imus",
                    ("--cal", "--fault", "--truth", "--effects-from-cal", "--kind accel"))
    from replay.can_write import LOG_SUFFIXES

    if str(args.out).lower().endswith(LOG_SUFFIXES):
        raise ConfigError(f"--out {args.out}: --imus writes a flight folder, not a CAN log; "
                          "give a folder name")
    if args.time_offset_ms and len(args.time_offset_ms) != args.imus:
        raise ConfigError(f"--time-offset-ms: expected {args.imus} values (one per IMU), got "
                          f"{len(args.time_offset_ms)}")
    if args.timing_jitter_ms and len(args.timing_jitter_ms) != args.imus:
        raise ConfigError(f"--timing-jitter-ms: expected {args.imus} values (one per IMU), "
                          f"got {len(args.timing_jitter_ms)}")
    bad = [x for x in args.effect_imus if x != int(x) or x > args.imus]
    if bad:
        raise ConfigError(f"--effect-imus: {bad[0]:g} is not an IMU number (1 to {args.imus})")


def run(args: argparse.Namespace) -> int:
    """Run ``rimu simulate flight --imus K``."""
    from replay.flight_io import save_flight_dir
    from replay.imu_set import ImuEffects, ImuSetSpec, simulate_imu_set
    from rimu.outputs import atomic_dir, output_dir

    check_imu_options(args)
    out = output_dir(args.out, "--out", schema="rimu.flight/1")
    fs = args.rate or 50.0
    if args.duration * fs * args.imus > MAX_SAMPLES:
        raise ConfigError(f"--duration {args.duration:g} s at {fs:g} Hz for {args.imus} IMUs is "
                          f"{args.duration * fs * args.imus:.3g} IMU samples; at most "
                          f"{MAX_SAMPLES:.0e} are simulated in memory at once")
    vib_hz, vib = 0.0, 0.0
    if args.vibration:
        vib_hz, vib = args.vibration[0], args.vibration[1] * DPS
    eff = ImuEffects(g_sensitivity=args.g_sensitivity * DPS / G0, warm_up=args.warm_up * DPS,
                     warm_up_s=args.warm_up_s, temperature_coeff=args.temperature_coeff * DPS,
                     vibration_hz=vib_hz, vibration=vib, random_walk=args.drift * DPH,
                     imus=tuple(int(x) for x in args.effect_imus))
    spec = ImuSetSpec(imus=args.imus, duration_s=args.duration,
                      sample_rate_hz=fs, seed=args.seed,
                      time_offset_s=tuple(1e-3 * x for x in args.time_offset_ms),
                      timing_jitter_s=tuple(MS * x for x in args.timing_jitter_ms),
                      misalignment_sd=1e-3 * args.misalignment_mrad,
                      scale_sd=1e-6 * args.scale_ppm, noise_sd=args.gyro_noise_dps * DPS,
                      max_rate_dps=args.max_rate if args.max_rate != 300.0 else 200.0,
                      effects=eff)
    flight = simulate_imu_set(spec)
    with atomic_dir(out) as tmp:
        save_flight_dir(flight, tmp)
    print(f"wrote {out}: {flight.t.shape[0]} samples of {spec.imus} IMUs at "
          f"{flight.sample_rate_hz:g} Hz (truth in {out / 'truth.json'})")
    return 0

