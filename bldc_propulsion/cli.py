"""`bldc-propulsion`: one entry point, one subcommand per job (a module each in commands/).

Exit status 0 on success, 2 on bad input (one line on stderr naming the file, topic or
parameter), 1 on an internal fault. ``--json`` prints exactly one JSON object on stdout;
progress goes to stderr. Each subcommand is also a console script of its own so that
``ros2 run bldc_propulsion <name>`` works on ROS.
"""

from __future__ import annotations

import argparse
import json
import sys
import traceback
from collections.abc import Callable, Sequence
from types import ModuleType
from typing import Any, NoReturn

from .commands import MODULES
from .commands.common import CommandResult
from .errors import BadInputError

#: name -> module of every subcommand (commands/__init__.py), in --help order.
_SUBCOMMANDS: dict[str, ModuleType] = {m.NAME: m for m in MODULES}


class OneLineParser(argparse.ArgumentParser):
    """argparse with the CLI's error convention: one line on stderr (no usage block), exit 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {' '.join(message.split())}\n")



def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="bldc-propulsion",
        description=(
            "Estimate rotor speed and thrust of a brushless motor + propeller from the PWM "
            "command and the battery voltage; simulate the bench, train and evaluate models, "
            "replay recordings, and find which physical effect a model is missing."
        ),
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, module in _SUBCOMMANDS.items():
        p = sub.add_parser(name, help=module.HELP, description=module.DESCRIPTION)
        module.add_arguments(p)
        p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
        p.set_defaults(run=module.run)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit status (also used by the console scripts)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        result: CommandResult = args.run(args)
    except BadInputError as exc:
        print(f"bldc-propulsion {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"bldc-propulsion {args.command}: interrupted; no output was written", file=sys.stderr)
        return 130
    except Exception:  # an internal fault: say so, with the traceback for a bug report
        traceback.print_exc()
        print(f"bldc-propulsion {args.command}: internal error (exit 1); please report it", file=sys.stderr)
        return 1
    for warning in result.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    if getattr(args, "json", False):
        print(json.dumps(result.data, default=_json_default))
    elif result.text:
        print(result.text)
    return result.exit_code


def _json_default(obj: Any) -> Any:
    import numpy as np

    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    return str(obj)


def _entry(name: str) -> Callable[[], None]:
    def run() -> None:
        sys.exit(main([name, *sys.argv[1:]]))

    run.__doc__ = f"`ros2 run bldc_propulsion {name}`: same as `bldc-propulsion {name}`."
    return run


main_info = _entry("info")
main_simulate = _entry("simulate")
main_train = _entry("train")
main_evaluate = _entry("evaluate")
main_replay = _entry("replay")
main_discrepancy = _entry("discrepancy")
main_import_csv = _entry("import-csv")
main_import_log = _entry("import-log")


def console_main() -> None:
    sys.exit(main())


if __name__ == "__main__":
    console_main()
