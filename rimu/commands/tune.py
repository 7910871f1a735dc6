"""``rimu tune --cal CAL --false-alarms-per-hour X --out FILE``: thresholds for a rate."""

from __future__ import annotations

import argparse

from fdi.calfile import load_calibration
from fdi.errors import ConfigError

HELP = ("tune thresholds for a false-alarm rate; print them and the detectable fault size "
        "per window scale")


def _scales(text: str) -> tuple[int, ...]:
    out = []
    for part in text.replace(",", " ").split():
        try:
            v = float(part)
        except ValueError:
            raise ConfigError(f"unknown scale {part!r}: expected window lengths in samples, "
                              f"e.g. --scales 1,2,4,8") from None
        if not (v == int(v) and v >= 1):
            raise ConfigError(f"unknown scale {part!r}: expected a positive integer window "
                              f"length in samples")
        out.append(int(v))
    return tuple(out)


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("--cal", required=True, metavar="FILE", help="calibration file")
    p.add_argument("--false-alarms-per-hour", required=True, type=float, metavar="X",
                   help="target rate of false alarms per hour of healthy operation")
    p.add_argument("--scales", metavar="LIST",
                   help="window lengths in samples, e.g. 1,2,4,...,128 (default 1 ... 128)")
    p.add_argument("--kind", default="gyro", choices=("gyro", "accel"))
    p.add_argument("--simulate-hours", type=float, default=4.0, metavar="H",
                   help="healthy flight hours simulated per correction pass (default 4; "
                        "0: analytic only)")
    p.add_argument("--seed", type=int, default=0, help="seed of the correction flights")
    p.add_argument("--out", required=True, metavar="FILE",
                   help="write the rimu.tuning/1 file here (for --thresholds)")


def run(args: argparse.Namespace) -> int:
    from thresholds.tune import tune

    if not args.false_alarms_per_hour > 0:
        raise ConfigError(f"--false-alarms-per-hour must be positive, got "
                          f"{args.false_alarms_per_hour:g}")
    if args.simulate_hours < 0:
        raise ConfigError("--simulate-hours must be >= 0")
    cal = load_calibration(args.cal)
    scales = _scales(args.scales) if args.scales else 7
    tu = tune(cal, false_alarms_per_hour=args.false_alarms_per_hour, kind=args.kind,
              scales=scales, simulate_hours=args.simulate_hours, seed=args.seed)
    th = tu.thresholds
    corr = tu.assumptions["simulation_correction"]
    print(f"thresholds for {th.false_alarms_per_hour:g} false alarms/h, {th.n} {th.kind} "
          f"sensors at {th.sample_rate_hz:g} Hz (correction {corr['factor']:.3f}: "
          f"{corr['note']})")
    d0 = tu.detectable[0]
    print(f"{'scale':>6} {'window_s':>9} {'alpha':>10} {'chi2 thr':>9} {'var f':>6} "
          f"{'detectable (99 %)':>18} {'sigma':>7}")
    for w, a, t, f, d in zip(th.scales, th.alpha, th.threshold, th.variance_factor,
                             tu.detectable, strict=True):
        print(f"{w:6d} {w / th.sample_rate_hz:9.3f} {a:10.3e} {t:9.2f} {f:6.2f} "
              f"{d.size_unit_value:12.4g} {d.unit:5s} {d.size_sigma:7.2f}")
    print(f"detectable sizes: one full window, at rest, worst sensor {d0.sensor}")
    print(f"noise model: {th.noise_model} (residual tails of the calibration, per scale):")
    for c in tu.choices:
        print(f"  {c.text()}")
    tu.save(args.out)
    print(f"wrote {args.out}")
    return 0
