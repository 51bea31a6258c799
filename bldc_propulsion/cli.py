"""`bldc-propulsion`: one entry point, one subcommand per job.

Exit status 0 on success, 2 on bad input (one line on stderr naming the file, topic or
parameter), 1 on an internal fault. ``--json`` prints exactly one JSON object on stdout;
progress goes to stderr. Each subcommand is also a console script of its own so that
``ros2 run bldc_propulsion <name>`` works on ROS.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, NoReturn

from .errors import BadInputError


@dataclass
class CommandResult:
    """What a subcommand returns: JSON data for scripts and a text summary for people."""

    data: dict[str, Any]
    text: str = ""
    exit_code: int = 0
    warnings: list[str] = field(default_factory=list)


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
                        "the battery topics from /NS/ if recorded there, else from the root")


class OneLineParser(argparse.ArgumentParser):
    """argparse with the CLI's error convention: one line on stderr (no usage block), exit 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {' '.join(message.split())}\n")


def number(kind: type = float, lo: float | None = None, hi: float | None = None,
           lo_open: bool = False) -> Callable[[str], Any]:
    """An argparse type: a finite ``kind`` (int or float) within [lo, hi] ((lo, hi] with
    ``lo_open``). Every numeric option has a bound, so that no value can make a command run
    for days or exhaust memory."""
    def parse(text: str) -> Any:
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


# --- subcommands -------------------------------------------------------------------------
def _add_simulate(sub: argparse._SubParsersAction) -> None:
    from .sim import EFFECT_DOCS, PROFILES

    effects = "\n".join(f"  {name}: {doc}" for name, doc in EFFECT_DOCS.items())
    p = sub.add_parser(
        "simulate",
        help="simulate the test bench and record it as a rosbag2 bag",
        description=(
            "Simulate the bench (3S LiPo, ESC, AXI 2212/34 motor, 12x4.5 propeller, infrared "
            "phototransistor) under a command profile and write what a real bench records "
            "(/pwm, /battery/adc, /tachometer/adc, /thrust/measured) plus ground truth "
            "(/truth/speed, /truth/thrust) as an MCAP bag. Every physical effect can be "
            "switched off (0), kept at its realistic strength (1, the default) or scaled."
        ),
        epilog=f"profiles: {', '.join(PROFILES)}\neffects:\n{effects}",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--profile", required=True, help="command profile: " + ", ".join(PROFILES))
    p.add_argument("--duration", required=True, type=float,
                   help="recording length in seconds (at most 1800: longer runs in parts)")
    p.add_argument("--seed", type=SEED, default=0, help="random seed (same seed, same bag)")
    p.add_argument("--soc", type=float, default=1.0, help="starting state of charge, 0..1 (default 1)")
    p.add_argument(
        "--effect", action="append", metavar="NAME=VALUE",
        help="strength of a physical effect (0 off, 1 realistic); repeatable",
    )
    p.add_argument(
        "--param", action="append", metavar="NAME=VALUE",
        help="override a bench constant (see bldc_propulsion/sim/params.py); repeatable",
    )
    p.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap", help="bag storage")
    p.add_argument("-o", "--output", required=True, help="bag directory to write")
    p.add_argument("--force", action="store_true", help="replace an existing output")
    p.set_defaults(run=_run_simulate)


def _run_simulate(args: argparse.Namespace) -> CommandResult:
    from .sim.record import simulate_to_bag

    info = simulate_to_bag(
        args.output,
        profile=args.profile,
        duration_s=args.duration,
        seed=args.seed,
        soc=args.soc,
        effects=parse_assignments(args.effect, "--effect"),
        params=parse_assignments(args.param, "--param"),
        storage=args.storage,
        force=args.force,
    )
    text = (
        f"wrote {info['path']}: {info['duration_s']:.1f} s of '{info['profile']}', "
        f"{info['messages']} messages, speed {info['speed_min_rad_s']:.0f}..{info['speed_max_rad_s']:.0f} rad/s, "
        f"battery {info['voltage_end_v']:.2f} V at the end"
    )
    return CommandResult(info, text)


def _add_replay(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "replay",
        help="run the estimation nodes' code over a recording, without ROS",
        description=(
            "Feed a recording through the same cores the rclpy nodes run (battery filter, "
            "tachometer decoder, thrust estimator) in message-time order, and write every "
            "output topic (/battery/voltage, /rotor/speed, /rotor/rpm, /predicted/speed, "
            "/predicted/thrust, /diagnostics) to a new MCAP bag: what the nodes would publish "
            "during `ros2 bag play`."
        ),
    )
    p.add_argument("input", help="recording to replay (bag directory or .mcap file)")
    p.add_argument("-o", "--output", required=True, help="bag directory to write")
    p.add_argument("--model", help="model .npz (default: the first-principles fallback)")
    p.add_argument("--force", action="store_true", help="replace an existing recording")
    add_namespace_argument(p)
    p.set_defaults(run=_run_replay)


def _run_replay(args: argparse.Namespace) -> CommandResult:
    from .replay import replay_bag, summary_text

    info = replay_bag(args.input, args.output, model_path=args.model, force=args.force,
                      namespace=args.namespace)
    return CommandResult(info, summary_text(info), warnings=info["warnings"])


def _add_train(sub: argparse._SubParsersAction) -> None:
    from .training.command import add_train_arguments

    p = sub.add_parser(
        "train",
        help="train the speed model (n-H-1 network, Levenberg-Marquardt) from recordings",
        description=(
            "Train the paper's network (default 3-25-1: filtered battery voltage, PWM, PWM "
            "through a 0.25 s lag) with Levenberg-Marquardt on the training recordings, stop "
            "early on separate validation recordings, and save weights, scaling and "
            "provenance to an .npz model file."
        ),
    )
    add_train_arguments(p)


def _add_evaluate(sub: argparse._SubParsersAction) -> None:
    from .training.command import add_evaluate_arguments

    p = sub.add_parser(
        "evaluate",
        help="measure a model's speed error on recordings",
        description=(
            "Run a model over recordings and compare its predicted rotor speed with the "
            "measured one (/rotor/speed if recorded, else decoded from /tachometer/adc): "
            "RMSE, RMSE as %% of the speed range, maximum error, and for chirp-like "
            "recordings the error per command frequency band."
        ),
    )
    add_evaluate_arguments(p)


def _add_import_csv(sub: argparse._SubParsersAction) -> None:
    from .training.command_import import add_import_arguments

    p = sub.add_parser(
        "import-csv",
        help="turn an RCbenchmark / Tyto Robotics thrust-stand CSV log into a bag",
        description=(
            "Convert the CSV log a RCbenchmark / Tyto Robotics thrust stand exports (ESC signal "
            "in microseconds, voltage, current, thrust, RPM) into a bag with the contract's "
            "topics (/pwm at 50 Hz, /battery/voltage, /rotor/speed, /thrust/measured), so that "
            "data from a commercial stand trains, evaluates and goes through discrepancy."
        ),
    )
    add_import_arguments(p)


def _add_discrepancy(sub: argparse._SubParsersAction) -> None:
    from .discrepancy.command import add_arguments

    p = sub.add_parser(
        "discrepancy",
        help="find where a model and measurements disagree, name the missing effect, add it",
        description=(
            "Run a model (trained network or bench physics) over measured recordings, find "
            "where and when it disagrees with the measured speed, test which physical effect "
            "explains the disagreement (battery_voltage, rotor_lag, input_delay, "
            "esc_deadband, spin_down_asymmetry, motor_heating), add the best one to the "
            "model, and show the error shrink on held-out recordings."
        ),
    )
    add_arguments(p)


def _add_info(sub: argparse._SubParsersAction) -> None:
    from .info import add_info_arguments

    p = sub.add_parser(
        "info",
        help="what a recording holds and what it can be used for (like `ros2 bag info`)",
        description=(
            "Print each recording's topics (type, messages, rate, gaps), duration, the PWM and "
            "battery-voltage ranges, whether the tachometer decodes, and which commands can use "
            "it (train, evaluate, discrepancy, replay) or why not."
        ),
    )
    add_info_arguments(p)


_SUBCOMMANDS: dict[str, Callable[[argparse._SubParsersAction], None]] = {
    "info": _add_info,
    "simulate": _add_simulate,
    "train": _add_train,
    "evaluate": _add_evaluate,
    "replay": _add_replay,
    "discrepancy": _add_discrepancy,
    "import-csv": _add_import_csv,
}


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
    for add in _SUBCOMMANDS.values():
        add(sub)
    for action in sub.choices.values():
        action.add_argument("--json", action="store_true", help="print one JSON object on stdout")
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


def console_main() -> None:
    sys.exit(main())


if __name__ == "__main__":
    console_main()
