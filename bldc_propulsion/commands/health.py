"""`bldc-propulsion health`: the health monitor (core/health.py) over recordings, offline: per
recording a timeline of the changes found, named with the contract's fault names."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, Any, TypedDict

from .common import CommandResult, add_namespace_argument, number

if TYPE_CHECKING:  # imported where used, so that `--help` does not load numpy, scipy and rosbags
    from collections.abc import Sequence

    from ..core.estimator import SpeedModel
    from ..core.health import HealthConfig, HealthRun
    from ..recordings import Signals

NAME = "health"
HELP = "find and name propulsion faults in recordings (health monitor)"
DESCRIPTION = (
    "Run the health monitor over recordings as the estimator receives them: a physics or hybrid "
    "model predicts the rotor speed from the command and the filtered battery voltage, and a "
    "sequential test (GLR) on the measured speed and the pack voltage finds where they change "
    "and names the change: propeller_damage (fraction of thrust and power lost), "
    "pack_resistance (factor on the pack's sag per ampere), bearing_friction (factor on the "
    "friction torque) or motor_heating (kelvin hotter than the model expects); a change no "
    "candidate explains is reported unnamed. The first seconds of each recording (--reference "
    "plus the test window, 25 s by default) are the healthy reference: nothing is found there. "
    "Measured speed is /rotor/speed if recorded, else decoded from /tachometer/adc. A simulated "
    "recording's injected faults (simulate --fault) are printed beside what was found."
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--model", required=True, metavar="MODEL.npz",
                   help="a physics or hybrid model (train --kind physics): the faults' signatures come "
                        "from its physics; a network model has none")
    p.add_argument("recordings", nargs="+", metavar="BAG", help="recordings to monitor")
    p.add_argument("--false-alarms-per-hour", type=number(float, 0.0, 100.0, lo_open=True), default=None,
                   metavar="RATE", help="false alarms per hour of healthy flight the threshold allows "
                                        "(default 0.01; the threshold is its chi-square tail, Bonferroni "
                                        "over every test of an hour)")
    p.add_argument("--reference", type=number(float, 5.0, 600.0), default=None, metavar="S",
                   help="most seconds of data before a candidate onset that the model's own error, the "
                        "drift and the noise are fitted on (default 40; the monitor arms once it has 20, "
                        "or S if less)")
    add_namespace_argument(p)


def config_of(args: argparse.Namespace) -> HealthConfig:
    """The monitor's settings from the command line (defaults where not given)."""
    from ..core.health import HealthConfig

    over: dict[str, Any] = {}  # HealthConfig's keyword arguments by name, each of its own type
    if args.false_alarms_per_hour is not None:
        over["false_alarms_per_hour"] = args.false_alarms_per_hour
    if args.reference is not None:
        over["reference_s"] = args.reference
    return HealthConfig(**over)


def run(args: argparse.Namespace) -> CommandResult:
    from ..core.health import require_physics
    from ..model import load_model
    from ..recordings import load_all

    model = load_model(args.model)
    require_physics(model, "the health monitor", f"--model {args.model}")
    cfg = config_of(args)
    signals = load_all(args.recordings, "health", namespace=args.namespace)
    out, lines = monitor_recordings(model, signals, cfg)
    first = out[0]
    data: dict[str, object] = {"model": args.model, "kind": model.kind, "threshold": first["threshold"],
                            "recordings": out}
    return CommandResult(data, "\n".join(lines))


def monitor_recordings(model: SpeedModel, signals: Sequence[Signals], config: HealthConfig | None = None
                       ) -> tuple[list[RecordingHealth], list[str]]:
    """The monitor over each recording (``core.health.run_health``, the stream the node and
    ``replay --health`` run): per recording its --json result and its timeline's lines."""
    from ..bagio import open_recording
    from ..core.health import run_health

    out: list[RecordingHealth] = []
    lines: list[str] = []
    for sig in signals:
        with open_recording(sig.path, sig.namespace) as rec:
            injected = [f.spec for f in rec.faults]
        result = run_health(model, sig.pwm_events, sig.voltage_events, sig.speed_events, config)
        out.append(recording_dict(sig.path, result, injected))
        lines += timeline(sig.path, result, injected)
    return out, lines


class RecordingHealth(TypedDict):
    """``recording_dict``: one recording's result in --json."""

    path: str
    duration_s: float
    monitored_s: float
    threshold: float
    events: list[dict[str, object]]
    minor: list[dict[str, object]]  #: no alarm: named below the smallest worth one, or unnamed that did not hold
    injected_faults: list[str]
    noise: dict[str, dict[str, float]]  #: channel -> the monitor's noise figures (a, b, visit, kappa)
    tested_s: dict[str, float]  #: channel -> seconds its tests ran (HealthRun.tested_s)


def recording_dict(path: str, r: HealthRun, injected: list[str]) -> RecordingHealth:
    """One recording's result as --json gives it."""
    return {"path": path, "duration_s": r.duration_s, "monitored_s": r.monitored_s, "threshold": r.threshold,
            "events": [e.as_dict() for e in r.events], "minor": [e.as_dict() for e in r.minor],
            "injected_faults": injected, "tested_s": dict(r.tested_s),
            "noise": {k: {"a": v[0], "b": v[1], "visit": v[2], "kappa": v[3]} for k, v in r.noise.items()}}


def timeline(path: str, r: HealthRun, injected: list[str]) -> list[str]:
    """One recording's timeline as text: a line per change, or that none was found."""
    from ..core.health import seconds_tested_text

    head = (f"{path}: {r.duration_s:.1f} s, monitored {r.monitored_s:.1f} s ({seconds_tested_text(r.tested_s)}"
            f"threshold {r.threshold:.1f})")
    if injected:
        head += f"; injected (simulated truth): {', '.join(injected)}"
    out = [head]
    if r.monitored_s <= 0.0:
        out.append("  too short to monitor: the first reference + window seconds are the healthy reference")
    elif not r.events:
        out.append(f"  no change {'worth an alarm' if r.minor else 'detected'} over {r.monitored_s:.1f} s")
    out += ["  " + e.text() for e in r.events]
    out += ["  minor, no alarm: " + e.text().strip() for e in r.minor]
    return out
