"""`bldc-propulsion simulate`: the bench simulator, recorded as a bag."""

from __future__ import annotations

import argparse

from .common import SEED, CommandResult, parse_assignments

NAME = "simulate"
HELP = "simulate the test bench and record it as a rosbag2 bag"
DESCRIPTION = (
    "Simulate the bench (3S LiPo, ESC, AXI 2212/34 motor, 12x4.5 propeller, infrared "
    "phototransistor) under a command profile and write what a real bench records "
    "(/pwm, /battery/adc, /tachometer/adc, /thrust/measured) plus ground truth "
    "(/truth/speed, /truth/thrust) as an MCAP bag. Every physical effect can be "
    "switched off (0), kept at its realistic strength (1, the default) or scaled. With "
    "--namespace motorN the run is recorded as one motor of a quadrotor: its topics under "
    "/motorN/, /battery/adc at the root. --fault NAME=SIZE@TIME changes the bench mid-recording "
    "(the truth a health monitor is judged against), kept in the recording's metadata."
)


def help_details(p: argparse.ArgumentParser) -> None:
    """The profiles, effects and faults, listed below the options: they live in the simulator
    (numpy, scipy), so they are imported only when this help is printed (cli.OneLineParser)."""
    from ..sim import EFFECT_DOCS, FAULT_DOCS, PROFILES

    effects = "\n".join(f"  {name}: {doc}" for name, doc in EFFECT_DOCS.items())
    faults = "\n".join(f"  {name}: {doc}" for name, doc in FAULT_DOCS.items())
    p.epilog = (f"profiles: {', '.join(PROFILES)}\neffects:\n{effects}\n"
                f"faults (--fault NAME=SIZE@TIME, TIME in seconds from the start):\n{faults}")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.add_argument("--profile", required=True, help="command profile (listed below)")
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
        help="override a bench constant (see bldc_propulsion/physics/params.py); repeatable",
    )
    p.add_argument(
        "--fault", action="append", metavar="NAME=SIZE@TIME",
        help="change the bench from TIME (s, inside the duration) on, e.g. propeller_damage=0.1@20 "
             "(faults and their SIZE listed below); repeatable, each from its own onset",
    )
    p.add_argument("--namespace", metavar="NS",
                   help="record as one motor of a vehicle (e.g. motor0): its topics under /NS/, "
                        "/battery/adc at the root, as the quadrotor launch records them")
    p.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap", help="bag storage")
    p.add_argument("-o", "--output", required=True, help="recording to write (bag directory or .mcap file)")
    p.add_argument("--force", action="store_true", help="replace an existing recording")


def run(args: argparse.Namespace) -> CommandResult:
    from ..sim.faults import parse_fault
    from ..sim.record import simulate_to_bag

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
        namespace=args.namespace,
        faults=[parse_fault(text) for text in args.fault or ()],
    )
    where = f" (motor topics under /{info['namespace']}, battery at the root)" if info["namespace"] else ""
    text = (
        f"wrote {info['path']}{where}: {info['duration_s']:.1f} s of '{info['profile']}', "
        f"{info['messages']} messages, speed {info['speed_min_rad_s']:.0f}..{info['speed_max_rad_s']:.0f} rad/s, "
        f"battery {info['voltage_end_v']:.2f} V at the end"
        + (f"; faults {', '.join(info['faults'])}" if info["faults"] else "")
    )
    return CommandResult(info, text)
