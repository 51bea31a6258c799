"""`bldc-propulsion replay`: the nodes' cores over a recording, without ROS (replay.py)."""

from __future__ import annotations

import argparse

from .common import CommandResult, add_namespace_argument

NAME = "replay"
HELP = "run the estimation nodes' code over a recording, without ROS"
DESCRIPTION = (
    "Feed a recording through the same cores the rclpy nodes run (battery filter, "
    "tachometer decoder, thrust estimator) in message-time order, and write every "
    "output topic (/battery/voltage, /rotor/speed, /rotor/rpm, /predicted/speed, "
    "/predicted/thrust, /diagnostics) to a new MCAP bag: what the nodes would publish "
    "during `ros2 bag play`. A recording that holds the measured /battery/voltage or "
    "/rotor/speed instead of /battery/adc or /tachometer/adc (an imported thrust-stand log) "
    "has them used as recorded, and the stage without input is not run."
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", help="recording to replay (bag directory or .mcap file)")
    p.add_argument("-o", "--output", required=True, help="recording to write (bag directory or .mcap file)")
    p.add_argument("--model", help="model .npz (default: the first-principles fallback)")
    p.add_argument("--force", action="store_true", help="replace an existing recording")
    add_namespace_argument(p)


def run(args: argparse.Namespace) -> CommandResult:
    from ..replay import replay_bag, summary_text

    info = replay_bag(args.input, args.output, model_path=args.model, force=args.force,
                      namespace=args.namespace)
    return CommandResult(info, summary_text(info), warnings=info["warnings"])
