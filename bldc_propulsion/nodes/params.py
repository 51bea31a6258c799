"""What the nodes need that runs without ROS: node names, parameter tables, plain conversions.

Each node declares exactly the parameters of its table (``common.declare_parameters``), with the
description and range written here; ``config/propulsion.yaml`` lists the same names with the
same types, which ``test/test_launch_files.py`` checks without ROS. Parameters whose ``core``
flag is set are passed by name to the core's config dataclass; the others belong to the node.
"""

from __future__ import annotations

import difflib
import math
import re
import textwrap
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from bldc_propulsion import contract

Value = bool | int | float | str

# --- Node names (relative: a namespace like /motor0 is pushed by the launch file) ---
BATTERY_FILTER = "battery_filter"
TACHOMETER = "tachometer"
THRUST_ESTIMATOR = "thrust_estimator"
NODE_NAMES = (BATTERY_FILTER, TACHOMETER, THRUST_ESTIMATOR)

DIAGNOSTICS_PERIOD_S = 1.0  #: diagnostics are published once a second (node clock)
TACH_TIMEOUT_CHECK_PERIOD_S = 0.1  #: how often the tachometer looks for a silent input


@dataclass(frozen=True)
class Param:
    """One ROS parameter: name, default (its type is the parameter's type), range, meaning."""

    name: str
    default: Value
    description: str
    min: float | int | None = None  #: inclusive range, for int and float parameters
    max: float | int | None = None
    core: bool = True  #: passed to the core's config dataclass under the same name
    read_only: bool = True  #: only model_path can change while the node runs


def stream_params(depth: int, tolerance_s: float) -> tuple[Param, ...]:
    """The timing and queue parameters every fixed-rate input stream has (stream_time.py)."""
    return (
        Param("queue_depth", depth, "Input history (messages; best effort, so any sensor "
              "driver connects). Default: 0.5 s of input, so a node stalled that long loses "
              "nothing.", 1, 100000, core=False),
        Param("clock_tolerance_s", tolerance_s, "A message later than the transport-latency floor "
              "by more than this (s, on the publisher's clock) breaks the stream: the "
              "publisher skipped data or sent a late burst (docs/ros.md 'Timing and faults').",
              0.0001, 10.0, core=False),
        Param("use_source_timestamps", True, "Judge lateness on the publisher's clock "
              "(message info); false = on receipt (e.g. `ros2 bag play --rate` below 1).",
              core=False),
    )


BATTERY_FILTER_PARAMS: tuple[Param, ...] = (
    Param("sample_rate_hz", 1000.0, "Sample rate of battery/adc (Hz). The filter is "
          "rediscretised for it; samples further apart than max_gap_s restart it.", 1.0, 100000.0),
    Param("divider_ratio", 1.999, "Resistive divider ratio: battery volts per ADC-pin volt "
          "(the filter's DC gain).", 0.1, 100.0),
    Param("min_adc_v", 0.0, "Lowest plausible ADC-pin voltage (V); samples below are rejected "
          "and counted.", -100.0, 100.0),
    Param("max_adc_v", 10.0, "Highest plausible ADC-pin voltage (V); samples above are rejected "
          "and counted.", -100.0, 100.0),
    Param("max_gap_s", 0.5, "Largest gap between samples (s) the filter bridges; a longer "
          "gap restarts it from the next sample.", 0.0, 3600.0),
    Param("publish_rate_hz", 20.0, "Rate of battery/voltage (Hz, sample time). The filter "
          "sees every sample; its 2 s time constant makes a faster output cost CPU in every "
          "subscriber for nothing.", 0.1, 100000.0, core=False),
    *stream_params(500, 0.5),
)

#: name[0] of rotor/state and predicted/state (both nodes: one rotor, one name)
JOINT_NAME = Param("joint_name", contract.DEFAULT_JOINT_NAME, "name[0] of the JointState "
                   "outputs (rotor/state, predicted/state): the rotor's joint, e.g. "
                   "motor0_rotor on a vehicle.", core=False)

TACHOMETER_PARAMS: tuple[Param, ...] = (
    Param("sample_rate_hz", 20000.0, "Sample rate of the phototransistor ADC inside each "
          "tachometer/adc batch (Hz).", 1.0, 1.0e7),
    Param("blades", 2, "Propeller blades cutting the beam (each gives two edges per "
          "revolution).", 1, 12),
    Param("max_speed_rad_s", 2000.0, "Highest plausible rotor speed (rad/s); faster edge "
          "intervals are rejected as noise.", 1.0, 100000.0),
    Param("timeout_s", 0.3, "No edge for this long (s) in batches that keep coming means the "
          "rotor stopped: speed 0 is published (signal steady at the clear level). No batch "
          "for this long (node clock): nothing is published, diagnostics say the input is "
          "lost.", 0.001, 60.0),
    *stream_params(50, 0.005),
    JOINT_NAME,
)

THRUST_ESTIMATOR_PARAMS: tuple[Param, ...] = (
    Param("model_path", "", "Path of a trained model .npz. Empty: first-principles fallback "
          "(WARN on diagnostics). Can be changed at run time; a file that does not load is "
          "refused and the last good model kept.", core=False, read_only=False),
    Param("thrust_coefficient", 0.0, "b in thrust = b*w^2 (N s^2/rad^2); 0 = the model's "
          "own coefficient. A model without one (no thrust measured or stated in training) "
          "publishes no predicted/thrust unless this states it.", 0.0, 1.0, core=False),
    Param("adapt", False, "Online adaptation (physics or hybrid model): with rotor/speed "
          "coming, the propeller's loss and the friction factor follow the measured speed "
          "(bounded RLS, frozen while the speed is stale or the rotor at rest), the pack's "
          "resistance the battery voltage's sag, the prediction "
          "and thrust use them; published on predicted/adapted and diagnostics (adapted_*). "
          "A network model or the fallback is refused.", core=False),
    Param("health", False, "Health monitor (physics or hybrid model): with rotor/speed coming, "
          "a sequential test on the measured speed and the pack voltage names a change in flight "
          "(propeller_damage, pack_resistance, bearing_friction, motor_heating) on diagnostics, "
          "status 'health': WARN while a change is being named, ERROR with the named fault "
          "(effect, size, unit, onset_s, detected_s), kept until the model is loaded again. "
          "A network model or the fallback is refused.", core=False),
    Param("output_rate_hz", 100.0, "Rate of predicted/speed and predicted/thrust (Hz, node "
          "clock). Kept under `ros2 bag play --clock`: every output time passed by a /clock "
          "step is predicted.", 1.0, 1000.0, core=False),
    Param("output_delay_s", 0.02, "A grid time is predicted once the node clock is this far "
          "past it (s), so commands published before it have arrived (transport latency); an "
          "input arriving later than that still emits every grid time up to its own time "
          "first.", 0.0, 1.0, core=False),
    Param("pwm_timeout_s", 0.0, "With a flight controller that publishes pwm at a fixed "
          "rate: no pwm for this long (s) stops predicting (diagnostics ERROR) instead of "
          "predicting from a stale command. 0 = off (pwm published only on change).",
          0.0, 60.0, core=False),
    Param("queue_depth", 100, "Input history per subscription (messages; best effort, so "
          "any sensor driver connects). Default: 2 s of pwm at 50 Hz and of battery/voltage.",
          1, 100000, core=False),
    Param("use_source_timestamps", True, "Time pwm by the publisher's clock (message info) "
          "mapped onto the node clock, so a stall does not bunch commands; false = receipt "
          "time.", core=False),
    JOINT_NAME,
    Param("frame_id", contract.DEFAULT_FRAME_ID, "header.frame_id of predicted/wrench: the "
          "rotor's frame (z along the rotor axis, up: the thrust's direction).", core=False),
    Param("spin_direction", contract.DEFAULT_SPIN_DIRECTION, "1: the rotor turns "
          "counter-clockwise seen from above, -1: clockwise. Sets the sign of "
          "predicted/wrench torque.z, the reaction torque on the body (opposite the spin).",
          -1, 1, core=False),
)

NODE_PARAMS: dict[str, tuple[Param, ...]] = {
    BATTERY_FILTER: BATTERY_FILTER_PARAMS,
    TACHOMETER: TACHOMETER_PARAMS,
    THRUST_ESTIMATOR: THRUST_ESTIMATOR_PARAMS,
}


def core_kwargs(table: Sequence[Param], values: Mapping[str, object]) -> dict[str, Any]:
    """The values of the table's core parameters, as keyword arguments of the core config (each
    of the type of its field: ``Config(**kwargs)`` checks them by name)."""
    return {p.name: values[p.name] for p in table if p.core}


def check_table(table: Sequence[Param]) -> None:
    """Raise ValueError if a default is outside its range or a range is on a non-number."""
    for p in table:
        if p.min is None and p.max is None:
            continue
        if isinstance(p.default, bool) or not isinstance(p.default, (int, float)):
            raise ValueError(f"{p.name}: a range needs an int or float parameter")
        if p.min is None or p.max is None or not p.min <= p.default <= p.max:
            raise ValueError(f"{p.name}: default {p.default} outside [{p.min}, {p.max}]")
        if isinstance(p.default, int) and not (isinstance(p.min, int) and isinstance(p.max, int)):
            raise ValueError(f"{p.name}: an integer parameter needs an integer range")


# --- Command line: --help, and parameters no node declares ---

#: Parameters rclpy itself declares on every node (or on demand): never a typo of ours.
ROS_OWN_PARAMETERS = ("use_sim_time", "start_type_description_service")
ROS_OWN_PREFIXES = ("qos_overrides.",)
#: How alike a misspelt name and a parameter must be to be offered as "did you mean"
#: (difflib ratio): 'tachomter_rate' -> 'sample_rate_hz' is 0.57, 'foo' -> anything < 0.25.
NEAREST_CUTOFF = 0.5


def type_name(default: Value) -> str:
    """A parameter's type as ROS names it (``ros2 param describe``)."""
    if isinstance(default, bool):
        return "boolean"
    if isinstance(default, int):
        return "integer"
    if isinstance(default, float):
        return "double"
    return "string"


def as_typed(value: Value) -> str:
    """A value as written after ``-p NAME:=`` or in a params file (true, 2, 2.0, '')."""
    if isinstance(value, bool):
        return "true" if value else "false"
    return repr(value) if isinstance(value, str) else str(value)


def parameters_help(table: Sequence[Param], width: int = 79) -> str:
    """The parameters of a table as --help lists them: name, type, default, range, meaning."""
    lines: list[str] = []
    for p in table:
        facts = [type_name(p.default), f"default {as_typed(p.default)}"]
        if p.min is not None:
            facts.append(f"range [{p.min}, {p.max}]")
        if not p.read_only:
            facts.append("settable at run time")
        lines.append(f"  {p.name} ({', '.join(facts)})")
        lines.extend(textwrap.wrap(p.description, width, initial_indent=" " * 6,
                                   subsequent_indent=" " * 6))
    return "\n".join(lines)


def node_help(prog: str, summary: str, table: Sequence[Param]) -> str:
    """The whole --help of a node executable."""
    intro = textwrap.fill(
        "Parameters (after --ros-args: -p NAME:=VALUE, or --params-file FILE as "
        "config/propulsion.yaml; a wrong type or a value out of range stops the node with one "
        "line, exit status 2; an unknown name is a warning):", 79)
    return (f"usage: {prog} [-h] [--ros-args [-p NAME:=VALUE ...] [--params-file FILE]]\n\n"
            f"{textwrap.fill(summary, 79)}\n\n{intro}\n{parameters_help(table)}\n")


def own_arguments(argv: Sequence[str]) -> list[str]:
    """The program's own words of ``argv``: those outside ``--ros-args ... [--]`` sections,
    where every word is ROS's (rcl's grammar). Unlike rclpy's ``remove_ros_args`` this does not
    judge the ROS words, so ``--help`` works whatever they are and ``rclpy.init`` reports a
    bad one in one line (``common.run_node``)."""
    own: list[str] = []
    ros = False
    for word in argv:
        if word == "--ros-args":
            ros = True
        elif word == "--" and ros:
            ros = False
        elif not ros:
            own.append(word)
    return own


def wants_help(argv: Sequence[str]) -> bool:
    """True if ``-h`` or ``--help`` is among the program's own arguments (argv without the
    program name)."""
    return any(word in ("-h", "--help") for word in own_arguments(argv))


def rcl_error_line(text: str) -> str:
    """rcl's refusal of the ROS arguments as one line: without its preamble and the C source
    locations it appends (", at /project/src/rcl/arguments.c:415")."""
    text = re.sub(r",? at \S+\.c:\d+", "", text.replace("failed to initialize rcl: ", ""))
    return " ".join(text.split())


def unknown_parameters(given: Iterable[str], table: Sequence[Param],
                       siblings: Iterable[Sequence[Param]] = ()) -> list[str]:
    """One warning per parameter given to a node that neither it nor any node of ``siblings``
    declares (rclpy ignores it silently: a typo in a vehicle's YAML would go unnoticed), with
    the node's nearest parameter name.

    A name a sibling declares is not warned about: a launch file's parameter dict, and every
    ``-p`` of a propulsion_all process, reach every node of the process (e.g. model_path
    reaches the tachometer), so it is meant for the sibling. ROS's own parameters are skipped.
    """
    own = [p.name for p in table]
    known = set(own).union(p.name for t in siblings for p in t)
    warnings = []
    for name in sorted(set(given)):
        if name in known or name in ROS_OWN_PARAMETERS or name.startswith(ROS_OWN_PREFIXES):
            continue
        nearest = difflib.get_close_matches(name, own, n=1, cutoff=NEAREST_CUTOFF)
        hint = (f"did you mean '{nearest[0]}'?" if nearest
                else f"no parameter of this node is close; it has {', '.join(own)}")
        warnings.append(f"unknown parameter '{name}' ignored: {hint}")
    return warnings


# --- Plain conversions (no message classes) ---

def level_byte(level: int) -> bytes:
    """CoreStatus level (0 OK, 1 WARN, 2 ERROR) as DiagnosticStatus.level, a ``byte`` field.

    rosidl maps the IDL ``byte`` to a length-1 ``bytes`` in Python: ``bytes([1]) ==
    DiagnosticStatus.WARN``; an ``int`` is refused by the message's setter.
    """
    return bytes([min(max(int(level), 0), 3)])


def diagnostic_name(node_fqn: str, core_name: str) -> str:
    """Status name: the node's name with its namespace, then the core's ("motor0/tachometer: x").

    Every node publishes on the one absolute /diagnostics, so the name must tell the motors
    apart; without a leading slash, as diagnostic_updater writes names ("tachometer: x" at
    the root) and the aggregator's analyzers match them by prefix.
    """
    return f"{node_fqn.lstrip('/')}: {core_name}"


def hardware_id(node_namespace: str, node_name: str) -> str:
    """DiagnosticStatus.hardware_id: the hardware a node watches, so monitors group by it.

    A motor's nodes name their motor, which is their namespace ("motor0", "vehicle/motor0"),
    or "motor" at the root (the one motor of a bench or a single-motor launch). The battery
    filter (recognised by its node name, ``BATTERY_FILTER``) watches the pack: "battery" at the
    root (a vehicle's one pack, shared by every motor), "motor0/battery" when a single-motor
    launch puts it in a motor's namespace.
    """
    namespace = node_namespace.strip("/")
    if node_name == BATTERY_FILTER:
        return f"{namespace}/battery" if namespace else "battery"
    return namespace or "motor"


def key_values(values: Mapping[str, object]) -> list[tuple[str, str]]:
    """CoreStatus.values as (key, value) string pairs, in the core's order."""
    return [(str(k), str(v)) for k, v in values.items()]


def stamp_to_seconds(sec: int, nanosec: int) -> float:
    """builtin_interfaces/Time fields as float seconds."""
    return float(sec) + float(nanosec) * 1e-9


def seconds_to_stamp(t_s: float) -> tuple[int, int]:
    """Float seconds as builtin_interfaces/Time (sec, nanosec), nanosec in [0, 1e9)."""
    ns = int(round(t_s * 1e9))
    sec, nanosec = divmod(ns, 1_000_000_000)
    return int(sec), int(nanosec)


def finite_or_nan(x: float) -> float:
    """x as a float, NaN when it is not finite (what the messages use for 'unknown')."""
    x = float(x)
    return x if math.isfinite(x) else math.nan


def rotor_name(namespace: str) -> str:
    """The joint name and frame id of the rotor of a motor namespace on a vehicle (``motor0`` ->
    ``motor0_rotor``), set by the quadrotor launch and ``propulsion_all --motors N``: one name per
    rotor, so a consumer tells them apart; ``rotor`` (the parameters' default) at the root."""
    ns = namespace.strip('/').replace('/', '_')
    return f'{ns}_{contract.DEFAULT_JOINT_NAME}' if ns else contract.DEFAULT_JOINT_NAME


def namespaces(motors: int) -> list[str]:
    """Namespaces of an all-in-one process: [''] for one motor, motor0..motorN-1 for N > 1.

    One motor keeps the process namespace (the root names, or ``-r __ns:=/ns``), so that a
    bench recording plays straight into it; several motors get motor0, motor1, ...
    """
    if motors < 1:
        raise ValueError(f"motors must be >= 1, got {motors}")
    return [""] if motors == 1 else [f"motor{i}" for i in range(motors)]


for _table in NODE_PARAMS.values():
    check_table(_table)
