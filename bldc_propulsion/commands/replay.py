"""`bldc-propulsion replay`: the nodes' cores over a recording, without ROS (replay.py)."""

from __future__ import annotations

import argparse

from .. import contract as c
from .common import CommandResult, add_namespace_argument

NAME = "replay"
HELP = "run the estimation nodes' code over a recording, without ROS"
DESCRIPTION = (
    "Feed a recording through the same cores the rclpy nodes run (battery filter, "
    "tachometer decoder, thrust estimator) in message-time order, and write every "
    "output topic (/battery/voltage, /rotor/speed, /rotor/rpm, /predicted/speed, "
    "/predicted/thrust, /rotor/state, /predicted/state, /predicted/wrench, /diagnostics) "
    "to a new MCAP bag: what the nodes would publish "
    "during `ros2 bag play`. A recording that holds the measured /battery/voltage or "
    "/rotor/speed instead of /battery/adc or /tachometer/adc (an imported thrust-stand log) "
    "has them used as recorded, and the stage without input is not run. With --adapt (a physics "
    "or hybrid --model) the estimator adapts the propeller's loss and the friction factor to the "
    "measured speed and /predicted/adapted is written too. With --health (a physics or hybrid "
    "--model) the health monitor runs on what the estimator takes, as the node's parameter health: "
    "its status ('health') is among the estimator's /diagnostics and the changes it named are "
    "printed, a line each, as `bldc-propulsion health` prints them."
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", help="recording to replay (bag directory or .mcap file)")
    p.add_argument("-o", "--output", required=True, help="recording to write (bag directory or .mcap file)")
    p.add_argument("--model", help="model .npz (default: the first-principles fallback)")
    p.add_argument("--force", action="store_true", help="replace an existing recording")
    p.add_argument("--joint-name", default=c.DEFAULT_JOINT_NAME,
                   help="name[0] of rotor/state and predicted/state, as the nodes' joint_name (default %(default)s)")
    p.add_argument("--frame-id", default=c.DEFAULT_FRAME_ID,
                   help="header.frame_id of predicted/wrench, as the estimator's frame_id (default %(default)s)")
    p.add_argument("--spin-direction", type=int, default=c.DEFAULT_SPIN_DIRECTION, choices=(1, -1),
                   help="1 counter-clockwise seen from above, -1 clockwise: the sign of the reaction torque")
    p.add_argument("--adapt", action="store_true",
                   help="online adaptation (off by default; a physics or hybrid --model): the estimator "
                        "follows the measured rotor speed by adapting the propeller's loss and the friction "
                        "factor, as the node's parameter adapt; writes /predicted/adapted (Float64MultiArray: "
                        "those values, propeller loss fraction and friction factor, after each measured speed "
                        "taken) and adds the final values and sigmas to --json")
    p.add_argument("--save-adapted", metavar="OUT.npz",
                   help="with --adapt: write the adapted model (the physics with the adapted constants, b "
                        "scaled by the propeller's loss) to OUT.npz at the end")
    p.add_argument("--health", action="store_true",
                   help="run the health monitor (a physics or hybrid --model) as the node's parameter health: "
                        "the estimator's /diagnostics carry its 'health' status (OK, WARN while a change is "
                        "named or unnamed, ERROR with the named fault: effect, size, unit, onset_s, "
                        "detected_s), the summary a line per change, --json health.events")
    add_namespace_argument(p)


def run(args: argparse.Namespace) -> CommandResult:
    from ..core.wrench import check_rotor_name
    from ..replay import replay_bag, summary_text

    for option, value in (("--joint-name", args.joint_name), ("--frame-id", args.frame_id)):
        check_rotor_name(value, option)
    info = replay_bag(args.input, args.output, model_path=args.model, force=args.force,
                      namespace=args.namespace, joint_name=args.joint_name, frame_id=args.frame_id,
                      spin_direction=args.spin_direction, adapt=args.adapt, save_adapted=args.save_adapted,
                      health=args.health)
    return CommandResult(info, summary_text(info), warnings=info["warnings"])
