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
    "data from a commercial stand trains, evaluates and goes through discrepancy. Thrust "
    "in N, kgf, gf or lbf. When the ESC's own tool set the command (the ESC signal column "
    "is empty), give it with --command-column or --command-from."
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``import-csv``: ``CSV -o BAG [--force] [--pole-pairs N]
    [--command-column NAME [--command-unit U] | --command-from ESC_LOG.csv] [--drop-contradicted]``."""
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
    command = parser.add_mutually_exclusive_group()
    command.add_argument(
        "--command-column", metavar="NAME",
        help=(
            "read the ESC command from this column of the log instead of 'ESC signal (µs)' "
            "(which is empty when the ESC's own tool set the command), e.g. 'Servo 1 (µs)'"
        ),
    )
    command.add_argument(
        "--command-from", metavar="ESC_LOG.csv",
        help=(
            "read the command from the ESC's own log of the same run (AutoQuad ESC32 utility CSV: "
            "Timestamp, RPM, Duty in %%); its clock is aligned to the log's by cross-correlating "
            "the speed both files record, and the import is refused if they do not line up"
        ),
    )
    parser.add_argument(
        "--drop-contradicted", action="store_true",
        help=(
            "leave /rotor/speed out (a gap, which training, evaluate and health skip) where the thrust "
            "contradicts it for half a second or more: a probe that misses the rotor at low speed. "
            "Default: written as read, with a warning naming the spans (a load cell touched or "
            "drifted contradicts a right speed the same way: look at the log before choosing)"
        ),
    )
    parser.add_argument(
        "--command-unit", metavar="us|duty|percent",
        help=(
            "unit of --command-column: us (pulse width), duty (0..1) or percent (0..100); a duty "
            "maps to the PWM level 0.05 + 0.05 x duty. Default: the unit in the column's name "
            "('(µs)', '(%%)')"
        ),
    )


def run(args: argparse.Namespace) -> CommandResult:
    """Run the import; ``--json`` data has ``path``, ``rows`` and the full summary."""
    from ..training.import_csv import import_csv, summary_text

    check_output(args.output, RECORDING, force=args.force,
                 inputs=[args.csv, args.command_from])  # before any work
    progress(f"importing {args.csv}" + (f" with the command from {args.command_from}" if args.command_from else ""))
    info = import_csv(args.csv, args.output, force=args.force, pole_pairs=args.pole_pairs,
                      command_column=args.command_column, command_unit=args.command_unit,
                      command_from=args.command_from, drop_contradicted=args.drop_contradicted)
    return CommandResult(info, summary_text(info), warnings=list(info.get("warnings", [])))
