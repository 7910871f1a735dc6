"""``rimu export c --cal CAL --out DIR``: the calibrated monitor as a self-contained C99
module (:mod:`fdi.export`)."""

from __future__ import annotations

import argparse

from rimu.argtypes import positive_float

HELP = ("write the monitor of a calibrated set as a self-contained C99 module (static "
        "memory, <math.h> only) with its contract")


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("target", choices=("c",), help="what to export: c (a C99 module)")
    p.add_argument("--cal", required=True, metavar="FILE", help="calibration file")
    p.add_argument("--thresholds", metavar="FILE",
                   help="a rimu.thresholds or rimu.tuning file made for this calibration "
                        "(default: computed from the calibration, as rimu monitor-file)")
    p.add_argument("--false-alarms-per-hour", type=positive_float(1e9), metavar="X",
                   help="false-alarm budget for computed thresholds")
    p.add_argument("--kind", choices=("gyro", "accel"), default="gyro",
                   help="sensor set to monitor (default gyro)")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="folder for rimu_monitor.h, rimu_monitor.c and README.md")
    p.add_argument("--float32", action="store_true",
                   help="float32 arithmetic (microcontrollers without a double-precision "
                        "unit; bounded differences: docs/export-c.md)")
    p.add_argument("--no-effects", action="store_true",
                   help="do not compensate the calibration's effect terms (as rimu "
                        "monitor-file --no-effects)")
    p.add_argument("--depth", metavar="D", default="auto",
                   help="healthy sets carried: 'all' (every one of the 2^n), or D: those "
                        "within D exclusions, of a sensor or a whole IMU each, and every set "
                        "of whole IMUs (default auto: all up to 9 sensors, else the largest "
                        "D <= 2 whose tables fit 224 KiB, 1 at least)")
    p.add_argument("--harness", action="store_true",
                   help="also write rimu_harness.c (samples.csv on stdin, answers as CSV on "
                        "stdout) and rimu_block.c (a block entry for ctypes)")


def run(args: argparse.Namespace) -> int:
    from fdi.calfile import load_calibration
    from fdi.errors import ConfigError
    from fdi.export import generate_c
    from fdi.export.c import API_VERSION
    from replay.threshold_choice import select
    from rimu.outputs import atomic_dir, input_path, output_dir

    depth: int | str | None = args.depth
    if args.depth == "all":
        depth = None
    elif args.depth != "auto":
        try:
            depth = int(args.depth)
        except ValueError:
            depth = -1
        if depth < 0:
            raise ConfigError(f"--depth: expected all, auto or a whole number, got "
                              f"{args.depth!r}")
    input_path(args.cal, "--cal")
    if args.thresholds:
        input_path(args.thresholds, "--thresholds")
    ins = [args.cal] + ([args.thresholds] if args.thresholds else [])
    final = output_dir(args.out, "--out", inputs=ins)
    cal = load_calibration(args.cal)
    choice = select(cal, kind=args.kind, thresholds_file=args.thresholds,
                    false_alarms_per_hour=args.false_alarms_per_hour,
                    calibration_file=args.cal)
    how = choice.to_dict()
    note = (f"{how.get('source', 'computed')}"
            + (f" {args.thresholds}" if args.thresholds else "")
            + f", {choice.thresholds.false_alarms_per_hour:g} false alarms per hour")
    mod = generate_c(cal, choice.thresholds, kind=args.kind,
                     precision="float32" if args.float32 else "float64",
                     harness=args.harness, thresholds_note=note,
                     effects=not args.no_effects, depth=depth)
    with atomic_dir(final) as tmp:
        for name, text in mod.files.items():
            (tmp / name).write_text(text, encoding="utf-8")
    print(f"wrote {final}/: {', '.join(mod.files)}")
    carried = ("every set" if mod.depth is None
               else f"up to {mod.depth} exclusion{'s' if mod.depth != 1 else ''} of a sensor "
                  f"or an IMU")
    print(f"calibration fingerprint {mod.fingerprint}; {mod.n} {args.kind} sensors, "
          f"{mod.sets} healthy-set tables ({carried}); {mod.precision}")
    print(f"identity {mod.identity}; table CRC-32 {mod.table_crc:#010x}; "
          f"API version {API_VERSION}")
    print(f"state {mod.state_bytes} bytes, tables {mod.table_bytes} bytes, worst case "
          f"{mod.ops_per_step} arithmetic operations per step")
    if mod.applied_terms or mod.not_applied:
        print(f"effect terms compensated: {len(mod.applied_terms)}; not compensated (as in "
              f"the Python monitor): {len(mod.not_applied)} (README.md)")
    return 0
