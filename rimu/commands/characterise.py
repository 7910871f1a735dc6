"""``rimu characterise DIR``: noise, Allan terms, tails, lines, shared modes and slow drift
of an ingested flight folder (see :mod:`replay.ingest.characterise_flight`)."""

from __future__ import annotations

import argparse
import json

from rimu.argtypes import probability

HELP = ("noise density, Allan deviation and its noise terms, tails, lines, shared modes "
        "and slow drift of a flight folder (one IMU or many, at rest or moving)")


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("flight", metavar="DIR", help="flight folder (rimu.flight/1, rimu ingest)")
    p.add_argument("--alpha", type=probability(), default=0.01, metavar="A",
                   help="family-wise level of the drift tests (default 0.01)")
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    p.add_argument("--report", metavar="DIR",
                   help="write characterise.json, report.md and PNG plots into DIR")


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from fdi.fileio import to_jsonable
    from replay.flight_io import load_flight_dir
    from replay.ingest.characterise_flight import characterise_flight, text, write_plots
    from rimu.outputs import atomic_write_text, input_path, output_dir

    input_path(args.flight, "DIR", kind="dir")
    out = output_dir(args.report, "--report") if args.report else None
    from fdi.progress import current

    current().stage("reading the flight folder")
    flight = load_flight_dir(args.flight)
    current().stage("characterising (noise density, Allan deviation, tails, lines, drift)")
    doc = to_jsonable({**characterise_flight(flight, alpha=args.alpha),
                       "time_base": flight.time_base.to_dict()})
    js = json.dumps(doc, indent=1, allow_nan=False) + "\n"
    summary = text(doc)
    print(js if args.json else summary, end="" if args.json else "\n")
    if out is not None:
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        current().stage("plots")
        pngs = write_plots(doc, flight, out)
        atomic_write_text(out / "characterise.json", js)
        atomic_write_text(out / "report.md", "```\n" + summary + "\n```\n\n" + "".join(
            f"![{p.stem}]({p.name})\n" for p in pngs))
        if not args.json:
            print(f"wrote {out / 'report.md'}, characterise.json and "
                  f"{', '.join(p.name for p in pngs)}")
    return 0
