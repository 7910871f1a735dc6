"""``rimu simulate calibration``: a simulated turntable session with its truth sidecar.

Writes ``DIR/manifest.json`` + ``DIR/samples.csv`` (:mod:`calibration.session_io`) and
``DIR/truth.json`` (:mod:`calibration.truth`). With ``--preset`` the true parameters are the
paper's (:mod:`calibration.presets`); without, nominal-ish parameters drawn with ``--seed``
(:func:`calibration.presets.random_truth`).
"""

from __future__ import annotations

import argparse
import dataclasses
from typing import Any

from calibration.effects import effects_help, parse_effect_sensors, parse_effects
from calibration.preset_names import PRESETS
from fdi.errors import ConfigError
from fdi.units import DPH
from rimu.argtypes import (
    SEED_MAX,
    bounded_float,
    nonnegative_float,
    nonnegative_int,
    positive_float,
)

MAX_SAMPLES = 20_000_000
"""Most samples one simulated session may hold (about 55 h at 100 Hz)."""

HELP = "simulate a turntable calibration session (manifest, samples, truth sidecar)"


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", metavar="CONFIG",
                   help="tetrad, cone6 or a TOML configuration file (default: the preset's)")
    p.add_argument("--out", metavar="DIR", required=True, help="session directory to write")
    p.add_argument("--seed", type=nonnegative_int(SEED_MAX), default=0,
                   help="random seed (default 0)")
    p.add_argument("--preset", choices=sorted(PRESETS),
                   help="true parameters of a seed paper: "
                        + "; ".join(f"{k}: {v}" for k, v in sorted(PRESETS.items())))
    p.add_argument("--sequence", metavar="FILE",
                   help="test sequence: tetrad-paper, cone-paper or a TOML sequence file "
                        "(default: the preset's, else tetrad-paper for the tetrad and "
                        "cone-paper otherwise)")
    p.add_argument("--table-rate-dps", type=positive_float(1e4), metavar="W",
                   help="replace the sequence's table rate w (deg/s)")
    p.add_argument("--turns", type=positive_float(1e4), metavar="K",
                   help="length of the rate steps in whole turns (default: the sequence's)")
    p.add_argument("--latitude-deg", type=bounded_float(-90.0, 90.0, name="latitude"),
                   metavar="X",
                   help="site latitude (default: the preset's; -23.2 tetrad, 37.5 others)")
    p.add_argument("--effect", action="append", metavar="NAME=VALUE[,NAME=VALUE]",
                   help="switch on an effect the calibration model lacks (repeatable): "
                        + effects_help())
    p.add_argument("--bias-instability-dph", type=nonnegative_float(1e6), default=0.0,
                   metavar="S",
                   help="add a first-order Gauss-Markov gyro bias of this standard deviation "
                        "(deg/h; default 0: white noise only)")
    p.add_argument("--bias-correlation-s", type=positive_float(1e9), default=100.0,
                   metavar="TAU",
                   help="its correlation time (s, default 100)")
    p.add_argument("--rate-random-walk-dph-rth", type=nonnegative_float(1e6), default=0.0,
                   metavar="Q",
                   help="add a gyro bias random walk of this density (deg/h/sqrt(h), "
                        "default 0)")
    p.add_argument("--effect-sensors", metavar="1,3",
                   help="sensors the effects touch, numbered from 1 within each kind "
                        "(default: all)")


def _check_size(seq: object, fs: float) -> None:
    """Refuse a session too long to simulate in memory (a tiny table rate, huge turns)."""
    n_samples = seq.duration_s * fs
    if not n_samples <= MAX_SAMPLES:
        raise ConfigError(f"sequence {seq.name}: {seq.duration_s:.4g} s at {fs:g} Hz is "
                          f"{n_samples:.3g} samples; at most {MAX_SAMPLES:.0e} are simulated "
                          "(check --turns and --table-rate-dps)")


def _setup(args: argparse.Namespace) -> tuple[Any, Any, Any, Any, str]:
    """Configuration, sequence, truth, noise model and where the parameters came from."""
    from calibration.presets import default_sequence_name, preset, random_truth
    from calibration.sequence import load_sequence
    from fdi.geometry import load_configuration

    if args.preset:
        seq, truth, noise = preset(args.preset)
        if args.config:
            cfg = load_configuration(args.config)
            if cfg.name != truth.configuration or cfg.n != truth.gyro.n:
                raise ConfigError(f"--preset {args.preset} is for the {truth.configuration} "
                                  f"configuration, not {args.config!r}")
        else:
            cfg = load_configuration(truth.configuration)
        source = f"preset {args.preset}"
    else:
        if not args.config:
            raise ConfigError("give --config (tetrad, cone6 or a file) or --preset")
        cfg = load_configuration(args.config)
        truth = random_truth(cfg, seed=args.seed, latitude_deg=args.latitude_deg)
        seq, noise = None, None
        source = f"random parameters (seed {args.seed})"
    if args.latitude_deg is not None:
        if not -90.0 <= args.latitude_deg <= 90.0:
            raise ConfigError(f"--latitude-deg must be in [-90, 90], got {args.latitude_deg}")
        truth = dataclasses.replace(truth, latitude_deg=args.latitude_deg)
    if (args.sequence or seq is None or args.table_rate_dps is not None
            or args.turns is not None):
        name = args.sequence or (seq.source if seq is not None else default_sequence_name(cfg))
        seq = load_sequence(name, table_rate_dps=args.table_rate_dps, turns=args.turns)
    return cfg, seq, truth, noise, source


def _noise(args: argparse.Namespace, noise: Any) -> Any:
    """The preset's noise model with the gyro bias instability / random walk options."""
    from calibration.simulate import SessionNoise

    if args.bias_instability_dph < 0 or args.rate_random_walk_dph_rth < 0 \
            or args.bias_correlation_s <= 0:
        raise ConfigError("--bias-instability-dph and --rate-random-walk-dph-rth must be >= 0, "
                          "--bias-correlation-s > 0")
    if not (args.bias_instability_dph or args.rate_random_walk_dph_rth):
        return noise
    base = noise or SessionNoise()
    return dataclasses.replace(
        base, bias_instability={**base.bias_instability,
                                "gyro": args.bias_instability_dph * DPH},
        bias_correlation_s=args.bias_correlation_s,
        random_walk={**base.random_walk,
                     "gyro": args.rate_random_walk_dph_rth * DPH / 60.0})


def _summary(args: argparse.Namespace, out: Any, cfg: Any, seq: Any, session: Any,
             effects: dict[str, float], source: str) -> str:
    """The one-paragraph description of what was written."""
    n_rate = len(seq.rate_steps())
    n_pos = len(seq.position_steps())
    kinds = f"{cfg.n} gyros" + ("" if session.raw_accel is None
                                else f" and {session.raw_accel.shape[1]} accelerometers")
    eff = ", ".join(f"{k}={v:g} on sensors {','.join(map(str, session.meta['effect_sensors'][k]))}"
                    for k, v in effects.items() if v != 0.0) or "none"
    extra_noise = ""
    if args.bias_instability_dph:
        extra_noise += (f" + gyro bias instability {args.bias_instability_dph:g} deg/h "
                        f"(correlation {args.bias_correlation_s:g} s)")
    if args.rate_random_walk_dph_rth:
        extra_noise += f" + gyro bias random walk {args.rate_random_walk_dph_rth:g} deg/h/sqrt(h)"
    return (f"Wrote a simulated calibration session to {out}/ (manifest.json, samples.csv, "
            f"truth.json): configuration {cfg.name} ({kinds}), sequence {seq.name} "
            f"({len(seq.steps)} steps: {n_rate} rate, {n_pos} position; table rate "
            f"{seq.table_rate_dps:g} deg/s), {session.t.size} samples at "
            f"{session.sample_rate_hz:g} Hz ({session.t.size / session.sample_rate_hz:g} s), "
            f"latitude {session.latitude_deg:g} deg, true parameters from {source}, seed "
            f"{args.seed}, noise: white per the truth{extra_noise}, effects: {eff}.")


def run(args: argparse.Namespace) -> int:
    from calibration.simulate import save_simulation, simulate_session
    from rimu.outputs import atomic_dir, output_dir

    final = output_dir(args.out, "--out")
    effects = parse_effects(args.effect)
    sensors = parse_effect_sensors(args.effect_sensors)
    cfg, seq, truth, noise, source = _setup(args)
    _check_size(seq, float(truth.sample_rate_hz))
    noise = _noise(args, noise)
    session = simulate_session(cfg, seq, truth, seed=args.seed, effects=effects,
                               effect_sensors=sensors, noise=noise)
    with atomic_dir(final) as tmp:
        save_simulation(session, truth, tmp)
    print(_summary(args, final, cfg, seq, session, effects, source))
    return 0
