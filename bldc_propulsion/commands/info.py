"""`bldc-propulsion info`: what recordings hold and what they can be used for (../info.py)."""

from __future__ import annotations

import argparse

from .common import CommandResult, add_namespace_argument

NAME = "info"
HELP = "what a recording holds and what it can be used for (like `ros2 bag info`)"
DESCRIPTION = (
    "Print each recording's topics (type, messages, rate, gaps), duration, the PWM and "
    "battery-voltage ranges, whether the tachometer decodes, and which commands can use "
    "it (train, evaluate, discrepancy, replay) or why not."
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("recordings", nargs="+", metavar="BAG", help="recordings (bag directory or .mcap file)")
    add_namespace_argument(p)


def run(args: argparse.Namespace) -> CommandResult:
    from ..info import recording_info, summary_text

    infos = [recording_info(p, args.namespace) for p in args.recordings]
    return CommandResult({"recordings": infos}, "\n\n".join(summary_text(i) for i in infos))
