"""`bldc-propulsion import-log`: arguments and runner (the readers are in flightlogs/)."""

from __future__ import annotations

import argparse

from ..atomic import RECORDING, check_output
from .common import CommandResult, number, progress

NAME = "import-log"
HELP = "turn a flight-controller log (Betaflight CSV, PX4 ULog, ArduPilot DataFlash) into a vehicle recording"
DESCRIPTION = (
    "Convert a flight log into a vehicle recording with the contract's namespaced topics: "
    "/motorN/pwm (the motor command as a PWM level, on 50 Hz frames), /motorN/rotor/speed "
    "(rad/s from ESC RPM telemetry), /battery/voltage and /battery/current, N counting the "
    "log's motors from 0. Reads the CSV that Blackbox Explorer or blackbox_decode export from "
    "a Betaflight log, PX4 ULog files (actuator_motors or actuator_outputs, esc_status, "
    "battery_status) and ArduPilot DataFlash .bin logs (RCOU, ESC, BAT; needs the optional "
    "pymavlink). The unit mapping applied is written into the recording, and `info` prints it."
)
FORMAT_CHOICES = ("betaflight-csv", "ulog", "dataflash")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``import-log``: ``LOG -o BAG [--format F] [--pole-count N] [--motors LIST]
    [--motor-protocol P] [--force]``."""
    parser.add_argument("log", metavar="LOG", help="flight log: Betaflight CSV, PX4 .ulg or ArduPilot .bin")
    parser.add_argument("-o", "--output", required=True, help="bag directory (or .mcap file) to write")
    parser.add_argument("--format", choices=FORMAT_CHOICES, default=None,
                        help="the log's format (default: told by the file's first bytes)")
    parser.add_argument(
        "--pole-count", type=number(int, 2, 100), default=None, metavar="N",
        help=("the motor's magnet poles (e.g. 14 for a 12N14P motor): required when a Betaflight log "
              "has eRPM columns, which hold electrical RPM / 100 (shaft RPM = eRPM x 100 / (N / 2)); "
              "refused for PX4 and ArduPilot logs, whose ESC RPM is already mechanical"))
    parser.add_argument("--motors", default=None, metavar="LIST",
                        help="the log's motor indices to import, e.g. 0,1,2,3 (default: every motor with a command)")
    parser.add_argument(
        "--motor-protocol", choices=("dshot", "pwm"), default=None,
        help=("how Betaflight motor[i] values are read: dshot (48..2047 -> PWM level 0.05..0.10) or pwm "
              "(1000..2000 us, also Oneshot/Multishot). Default: from the log's header, else from the values"))
    parser.add_argument("--force", action="store_true", help="replace an existing output")


def run(args: argparse.Namespace) -> CommandResult:
    """Run the import; ``--json`` data has ``path``, ``rows``, ``motors``, ``duration_s``,
    ``command_mapping``, ``speed_source``, ``warnings`` and the rest of the summary."""
    from ..flightlogs import import_log, summary_text

    check_output(args.output, RECORDING, force=args.force, inputs=[args.log])  # before any work
    progress(f"importing {args.log}")
    info = import_log(args.log, args.output, fmt=args.format, pole_count=args.pole_count,
                      motors=args.motors, motor_protocol=args.motor_protocol, force=args.force)
    return CommandResult(info, summary_text(info), warnings=list(info.get("warnings", [])))
