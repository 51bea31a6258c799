"""What every subcommand shares: its result type, progress lines, and argument helpers.

A leaf module (it imports nothing of the package but errors), so that the subcommand modules
and ``cli`` import it without a cycle.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

from ..errors import BadInputError


@dataclass
class CommandResult:
    """What a subcommand returns: JSON data for scripts and a text summary for people."""

    data: Mapping[str, object]  #: printed as JSON (--json); a command's own TypedDict or dict
    text: str = ""
    exit_code: int = 0
    warnings: list[str] = field(default_factory=list)


def with_warnings(result: CommandResult, lines: Sequence[str]) -> CommandResult:
    """``result`` with ``lines`` first among its warnings (printed and in --json's ``warnings``):
    for what the inputs said before the command's own work (a recording's speed gaps)."""
    if not lines:
        return result
    warnings = [*lines, *result.warnings]
    return dataclasses.replace(result, data={**result.data, "warnings": warnings}, warnings=warnings)


def progress(message: str) -> None:
    """One progress line on stderr (never on stdout: stdout belongs to --json)."""
    print(message, file=sys.stderr, flush=True)


def parse_assignments(items: Sequence[str] | None, option: str) -> dict[str, float]:
    """``NAME=VALUE`` pairs -> dict; BadInputError naming the option and the bad item."""
    out: dict[str, float] = {}
    for item in items or []:
        name, sep, value = item.partition("=")
        if not sep or not name:
            raise BadInputError(f"{option} {item}: expected NAME=VALUE")
        try:
            number = float(value)
        except ValueError:
            raise BadInputError(f"{option} {item}: {value!r} is not a number") from None
        if not math.isfinite(number):
            raise BadInputError(f"{option} {item}: value must be finite")
        out[name.strip()] = number
    return out


def add_namespace_argument(p: argparse.ArgumentParser) -> None:
    """``--namespace motorN``: one motor of a vehicle's recording (interfaces.md, "A quadrotor")."""
    p.add_argument("--namespace", metavar="NS",
                   help="read one motor of a vehicle's recording: its topics under /NS/ (e.g. motor0), "
                        "the battery topics from /NS/ if recorded there, else from the root. One "
                        "recording's own motor: BAG@NS (e.g. flight.mcap@motor1), which wins over --namespace")


def number(kind: type = float, lo: float | None = None, hi: float | None = None,
           lo_open: bool = False) -> Callable[[str], float]:
    """An argparse type: a finite ``kind`` (int or float) within [lo, hi] ((lo, hi] with
    ``lo_open``). Every numeric option has a bound, so that no value can make a command run
    for days or exhaust memory."""
    def parse(text: str) -> float:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not {'an integer' if kind is int else 'a number'}") from None
        if not math.isfinite(value) or (lo is not None and (value <= lo if lo_open else value < lo)) \
                or (hi is not None and value > hi):
            low = "" if lo is None else f"{'>' if lo_open else '>='} {lo:g}"
            high = "" if hi is None else f"<= {hi:g}"
            raise argparse.ArgumentTypeError(f"{text!r} must be {' and '.join(x for x in (low, high) if x)}")
        return value
    parse.__name__ = kind.__name__  # argparse names the type in its messages
    return parse


#: Bounds shared by several commands.
SEED = number(int, 0, 2**32 - 1)
HIDDEN = number(int, 1, 200)
EPOCHS = number(int, 1, 100_000)
