"""`bldc-propulsion import-csv`: arguments and runner (the converter is training/import_csv.py)."""

from __future__ import annotations

import argparse

from ..atomic import RECORDING, check_output
from .common import CommandResult, number, progress

NAME = "import-csv"
HELP = "turn an RCbenchmark / Tyto Robotics thrust-stand CSV log into a bag"
DESCRIPTION = (
    "Convert the CSV log a RCbenchmark / Tyto Robotics thrust stand exports (ESC signal "
    "in microseconds, voltage, current, thrust, RPM) into a bag with the contract's "
    "topics (/pwm at 50 Hz, /battery/voltage, /rotor/speed, /thrust/measured), so that "
    "data from a commercial stand trains, evaluates and goes through discrepancy."
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``import-csv``: ``CSV -o BAG [--force] [--pole-pairs N]``."""
    parser.add_argument("csv", metavar="CSV", help="RCbenchmark / Tyto Robotics CSV log")
    parser.add_argument("-o", "--output", required=True, help="bag directory to write")
    parser.add_argument("--force", action="store_true", help="replace an existing output")
    parser.add_argument(
        "--pole-pairs", type=number(int, 1, 100), default=None, metavar="N",
        help=(
            "divide the 'Motor Electrical Speed (RPM)' column by N (e.g. 7 for a 14-pole "
            "outrunner) because it holds raw commutation RPM. Default: none, the column is "
            "taken as shaft RPM, which is what the RCbenchmark software writes (it divides by "
            "the pole count set in its setup). Not used when optical RPM has data."
        ),
    )


def run(args: argparse.Namespace) -> CommandResult:
    """Run the import; ``--json`` data has ``path``, ``rows`` and the full summary."""
    from ..training.import_csv import import_csv, summary_text

    check_output(args.output, RECORDING, force=args.force, inputs=[args.csv])  # before any work
    progress(f"importing {args.csv}")
    info = import_csv(args.csv, args.output, force=args.force, pole_pairs=args.pole_pairs)
    return CommandResult(info, summary_text(info), warnings=list(info.get("warnings", [])))
