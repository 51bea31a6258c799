"""What the nodes need that runs without ROS: node names, parameter tables, plain conversions.

Each node declares exactly the parameters of its table (``common.declare_parameters``), with the
description and range written here; ``config/propulsion.yaml`` lists the same names with the
same types, which ``test/test_launch_files.py`` checks without ROS. Parameters whose ``core``
flag is set are passed by name to the core's config dataclass; the others belong to the node.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping, Sequence, Union

Value = Union[bool, int, float, str]

# --- Node names (relative: a namespace like /motor0 is pushed by the launch file) ---
BATTERY_FILTER = "battery_filter"
TACHOMETER = "tachometer"
THRUST_ESTIMATOR = "thrust_estimator"
NODE_NAMES = (BATTERY_FILTER, TACHOMETER, THRUST_ESTIMATOR)

HARDWARE_ID = "bldc_propulsion"  #: DiagnosticStatus.hardware_id of every status we publish
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
              "publisher skipped data or sent a late burst (README 'Timing and faults').",
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
)

THRUST_ESTIMATOR_PARAMS: tuple[Param, ...] = (
    Param("model_path", "", "Path of a trained model .npz. Empty: first-principles fallback "
          "(WARN on diagnostics). Can be changed at run time; a file that does not load is "
          "refused and the last good model kept.", core=False, read_only=False),
    Param("thrust_coefficient", 0.0, "b in thrust = b*w^2 (N s^2/rad^2); 0 = the model's "
          "own coefficient. A model without one (no thrust measured or stated in training) "
          "publishes no predicted/thrust unless this states it.", 0.0, 1.0, core=False),
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
)

NODE_PARAMS: dict[str, tuple[Param, ...]] = {
    BATTERY_FILTER: BATTERY_FILTER_PARAMS,
    TACHOMETER: TACHOMETER_PARAMS,
    THRUST_ESTIMATOR: THRUST_ESTIMATOR_PARAMS,
}


def core_kwargs(table: Sequence[Param], values: Mapping[str, Any]) -> dict[str, Any]:
    """The values of the table's core parameters, as keyword arguments of the core config."""
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


# --- Plain conversions (no message classes) ---

def level_byte(level: int) -> bytes:
    """CoreStatus level (0 OK, 1 WARN, 2 ERROR) as DiagnosticStatus.level, a ``byte`` field.

    rosidl maps the IDL ``byte`` to a length-1 ``bytes`` in Python: ``bytes([1]) ==
    DiagnosticStatus.WARN``; an ``int`` is refused by the message's setter.
    """
    return bytes([min(max(int(level), 0), 3)])


def diagnostic_name(node_fqn: str, core_name: str) -> str:
    """Status name: the node's fully qualified name, then the core's ("/motor0/tachometer: x")."""
    return f"{node_fqn}: {core_name}"


def key_values(values: Mapping[str, Any]) -> list[tuple[str, str]]:
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
