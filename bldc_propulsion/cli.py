"""`bldc-propulsion`: one entry point, one subcommand per job (a module each in commands/).

Exit status 0 on success, 2 on bad input (one line on stderr naming the file, topic or
parameter), 1 on an internal fault. ``--json`` prints exactly one JSON object on stdout;
progress goes to stderr. Each subcommand is also a console script of its own so that
``ros2 run bldc_propulsion <name>`` works on ROS.

Ctrl-C (SIGINT) ends the command with status 130 and no traceback at any moment: during the
start-up (these imports, building the parser) the process leaves at once, as nothing is written
yet; while a command runs, KeyboardInterrupt lets its outputs remove their staging files and
``main`` says "interrupted" in one line; once it has finished, the signal is ignored. The
subcommand modules import numpy, scipy, rosbags and matplotlib only inside their ``run``, so
that ``--help`` answers at once.
"""

from __future__ import annotations

import os
import signal
import sys

from . import quiet_start

#: The console scripts that run ``main`` (setup.py): as one of them, or as ``python -m``, this
#: process is the command line, and SIGINT during the start-up ends it quietly (status 130).
_PROGRAMS = {"bldc-propulsion", "info", "simulate", "train", "evaluate", "replay", "discrepancy",
             "import-csv", "import-log"}

_EXECUTABLE = __name__ == "__main__" or quiet_start.started_as(_PROGRAMS)
if _EXECUTABLE:
    quiet_start.install(130, (signal.SIGINT,))

import argparse  # noqa: E402 - after the handler: Ctrl-C during these imports is quiet too
import json  # noqa: E402
import traceback  # noqa: E402
from collections.abc import Callable, Sequence  # noqa: E402
from types import ModuleType  # noqa: E402
from typing import NoReturn  # noqa: E402

from .commands import MODULES  # noqa: E402
from .commands.common import CommandResult  # noqa: E402
from .errors import BadInputError  # noqa: E402

#: name -> module of every subcommand (commands/__init__.py), in --help order.
_SUBCOMMANDS: dict[str, ModuleType] = {m.NAME: m for m in MODULES}


class OneLineParser(argparse.ArgumentParser):
    """argparse with the CLI's error convention: one line on stderr (no usage block), exit 2."""

    #: Called once before the help is printed: help text that needs a heavy import (a
    #: subcommand module's optional ``help_details(parser)``), so that building the parser
    #: does not import it.
    help_details: Callable[[argparse.ArgumentParser], None] | None = None

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {' '.join(message.split())}\n")

    def format_help(self) -> str:
        details, self.help_details = self.help_details, None
        if details is not None:
            details(self)
        return super().format_help()


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
        p.help_details = getattr(module, "help_details", None)
        p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
        p.set_defaults(run=module.run)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit status (also used by the console scripts)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    interrupted = f"bldc-propulsion {args.command}: interrupted; no output was written"
    try:
        # from here on outputs may be staged: KeyboardInterrupt lets them clean up
        quiet_start.end(signal.SIGINT)
        result: CommandResult = args.run(args)
    except BadInputError as exc:
        print(f"bldc-propulsion {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(interrupted, file=sys.stderr)
        return 130
    except Exception:
        # a Ctrl-C turned into another exception on the way (a KeyboardInterrupt raised while a C
        # extension initialises, scipy's HiGHS imported on first use, comes out as "ImportError:
        # initialization failed") is no internal fault
        if quiet_start.interrupted():
            print(interrupted, file=sys.stderr)
            return 130
        # an internal fault: say so, with the traceback for a bug report
        traceback.print_exc()
        print(f"bldc-propulsion {args.command}: internal error (exit 1); please report it", file=sys.stderr)
        return 1
    finally:
        if _EXECUTABLE and signal.getsignal(signal.SIGINT) is quiet_start.interrupt:
            signal.signal(signal.SIGINT, signal.SIG_IGN)  # done (or failed): nothing left to stop
    for warning in result.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    if getattr(args, "json", False):
        print(json.dumps(result.data, default=_json_default))
    elif result.text:
        print(result.text)
    return result.exit_code


def _json_default(obj: object) -> object:
    """What ``json.dumps`` makes of what it cannot write: numpy scalars and arrays as numbers and
    lists, anything else as its text."""
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
main_health = _entry("health")
main_import_csv = _entry("import-csv")
main_import_log = _entry("import-log")


def console_main() -> None:
    status = main()
    if status == 130:
        # interrupted and reported: leave with the documented status. CPython records a
        # KeyboardInterrupt raised inside some C calls as unhandled even when caught here, and
        # then ends the process by SIGINT at exit (-2 instead of 130, one start in four at 0.5 s)
        for stream in (sys.stdout, sys.stderr):
            stream.flush()
        os._exit(130)
    sys.exit(status)


if __name__ == "__main__":
    console_main()
