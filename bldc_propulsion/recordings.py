"""Recordings -> aligned signals on one time grid, decoded by the same cores the nodes run.

What training, evaluation, ``info`` and the discrepancy workflow read: bagio opens the
recording, this module turns it into ``Signals`` (one per recording, refused when listed twice).

Measured speed is ``rotor/speed`` when a recording carries it (ESC telemetry, an imported
thrust-stand log), else decoded from ``tachometer/adc``; battery voltage is ``battery/voltage``
when recorded, else ``battery/adc`` through the battery filter. ``truth/*`` is never read.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import contract as c
from .bagio import MIN_GAP_S, Recording, open_recording, pauses
from .core.battery_filter import BatteryFilter, BatteryFilterConfig
from .core.features import zero_order_hold
from .core.tach_output import revolution_middle
from .core.tachometer import STARTING, TachometerConfig, TachometerDecoder
from .errors import BadInputError, BagError
from .specs import spec_path

#: Grid on which features and targets are aligned: 100 Hz resolves the rotor's ~0.1 s time
#: constant and the 50 Hz command, and matches the estimator node's output rate.
GRID_RATE_HZ = 100.0
#: Least recording (after alignment) that is worth training or evaluating on.
MIN_SAMPLES = 50


@dataclass
class Signals:
    """One recording's signals on a common grid (SI units)."""

    path: str
    sha256: str
    t: np.ndarray  #: grid times (s from the recording's start)
    pwm: np.ndarray  #: PWM level, zero-order hold of the command
    voltage: np.ndarray  #: filtered battery voltage (V)
    speed: np.ndarray  #: measured rotor speed (rad/s)
    thrust: np.ndarray | None  #: measured thrust (N) if recorded
    current: np.ndarray | None = None  #: battery current (A) if recorded
    speed_source: str = ""
    voltage_source: str = ""
    namespace: str | None = None  #: the motor's namespace in a vehicle's recording
    #: raw event streams, for features that need them (e.g. PWM command times)
    pwm_events: tuple[np.ndarray, np.ndarray] = field(default=(np.zeros(0), np.zeros(0)))
    voltage_events: tuple[np.ndarray, np.ndarray] = field(default=(np.zeros(0), np.zeros(0)))
    #: the measured speed as measured (times, rad/s), before the grid interpolated it: its noise
    speed_events: tuple[np.ndarray, np.ndarray] = field(default=(np.zeros(0), np.zeros(0)))
    #: (last sample before, first after) of each gap in the measured speed (``speed_gaps``): NaN
    #: in ``speed`` between them, so training and scoring skip what was not measured
    speed_gaps: tuple[tuple[float, float], ...] = ()

    @property
    def key(self) -> tuple[str, str | None]:
        """What makes two recordings the same data: the content and the motor read from it."""
        return self.sha256, self.namespace

    @property
    def duration_s(self) -> float:
        return float(self.t[-1] - self.t[0]) if len(self.t) else 0.0


def recording_sha256(path: str | os.PathLike[str]) -> str:
    """sha256 over a bag's files (sorted relative names and contents): provenance in models."""
    p = Path(path)
    h = hashlib.sha256()
    files = sorted(f for f in p.rglob("*") if f.is_file()) if p.is_dir() else [p]
    for f in files:
        h.update(str(f.relative_to(p) if p.is_dir() else f.name).encode())
        with open(f, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
    return h.hexdigest()


#: How far before a spin-up's first measured revolution a decoded 0 is still kept, in durations
#: of that revolution. The rotor left rest before the revolution's first edge: the blade had to
#: reach the beam, 0 to half a revolution away with two blades. From rest at a constant
#: acceleration that angle takes 0 to 1.37 times the first revolution's time (0.81 for a quarter
#: revolution, the middle); the speed is interpolated from the last kept 0 to the first revolution.
SPIN_UP_MARGIN_REVOLUTIONS = 1.0


def decode_speed(rec: Recording, config: TachometerConfig | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Speed samples (t, rad/s) from ``tachometer/adc`` through the tachometer core.

    Each 4-edge estimate is the mean speed over the last revolution, so it is placed at the
    middle of that revolution (removes the half-revolution lag: 60 ms at 50 rad/s). While the
    core reports no signal and no edge arrives (rotor at rest), zeros are placed at the batch
    times. A 0 is not placed once edges arrive before the first revolution is complete (the
    rotor is turning, its speed is not yet known), nor, seen from the whole recording, shortly
    before a spin-up's first revolution (``SPIN_UP_MARGIN_REVOLUTIONS``): there the rotor was
    already turning, and a 0 would be a wrong measurement of up to the speed it reached.
    """
    dec = TachometerDecoder(config or TachometerConfig())
    times: list[np.ndarray] = []
    values: list[np.ndarray] = []
    zeros: list[float] = []
    for t_batch, samples in rec.tachometer():
        out = dec.process_batch(t_batch, samples)
        if len(out.speed):
            # speed k spans one revolution ending at its edge: placed at its middle
            revolution = 2.0 * np.pi / np.maximum(out.speed, 1e-9)
            end = out.edge_t[-len(out.speed):]
            if zeros:  # the first revolution after rest: no 0 from shortly before it
                keep_until = end[0] - (1.0 + SPIN_UP_MARGIN_REVOLUTIONS) * revolution[0]
                while zeros and zeros[-1] > keep_until:
                    zeros.pop()
                times.append(np.asarray(zeros))
                values.append(np.zeros(len(zeros)))
                zeros = []
            times.append(np.asarray(revolution_middle(end, out.speed)))
            values.append(np.asarray(out.speed, dtype=float))
        elif out.speed_now == 0.0 and not out.signal_ok and not len(out.all_edge_t) \
                and out.state != STARTING:
            zeros.append(float(t_batch))
    times.append(np.asarray(zeros))
    values.append(np.zeros(len(zeros)))
    _check_clock(rec.path, c.TOPIC_TACH_ADC, dec.time_resyncs + dec.rejected_batches, dec.batches)
    t = np.concatenate(times)
    v = np.concatenate(values)
    if not len(t):
        return np.zeros(0), np.zeros(0)
    order = np.argsort(t, kind="stable")
    return t[order], v[order]


#: share of messages out of time order above which a recording's clock is not trusted
MAX_CLOCK_FAULT_FRACTION = 0.01


def _check_clock(path: str | os.PathLike[str], topic: str, faults: int, total: int) -> None:
    """BagError when a topic's times repeat or overlap: the recording's clock went backwards.

    The reader delivers messages in time order, so a clock that jumped back shows up as
    repeated times (scalars) or overlapping batches (tachometer). A few are tolerated (a
    glitch the cores reject and count); more would train or score on interleaved data.
    """
    if faults > max(1, MAX_CLOCK_FAULT_FRACTION * total):
        raise BagError(
            f"{path}: topic /{c.bare(topic)}: {faults} of {total} messages repeat or overlap "
            "earlier times (the recording's clock went backwards or jumped)"
        )


def _repeats(t: np.ndarray, v: np.ndarray) -> int:
    """Messages at the same time as the previous one with a different value."""
    return int(np.count_nonzero((np.diff(t) <= 0) & (np.diff(v) != 0))) if len(t) > 1 else 0


def read_voltage(rec: Recording, battery: BatteryFilterConfig | None = None) -> tuple[np.ndarray, np.ndarray, str]:
    """(t, filtered battery volts, source): ``battery/voltage`` when recorded, else
    ``battery/adc`` through the battery filter (rejected samples dropped)."""
    if rec.has(c.TOPIC_BATTERY_VOLTAGE):
        volt_t, volt = rec.battery_voltages(c.TOPIC_BATTERY_VOLTAGE)
        return volt_t, volt, "battery/voltage (recorded)"
    if not rec.has(c.TOPIC_BATTERY_ADC):
        raise rec.missing_error([c.TOPIC_BATTERY_VOLTAGE, c.TOPIC_BATTERY_ADC])
    adc_t, adc = rec.scalars(c.TOPIC_BATTERY_ADC)
    _check_clock(rec.path, c.TOPIC_BATTERY_ADC, _repeats(adc_t, adc), len(adc_t))
    v = BatteryFilter(battery or BatteryFilterConfig()).process(adc_t, adc)
    ok = np.isfinite(v)
    return adc_t[ok], v[ok], "battery/adc through the battery filter"


def read_speed(rec: Recording, tachometer: TachometerConfig | None = None) -> tuple[np.ndarray, np.ndarray, str]:
    """(t, measured rotor speed rad/s, source): ``rotor/speed`` when recorded, else decoded
    from ``tachometer/adc`` (the contract's rule for evaluate and discrepancy)."""
    if rec.has(c.TOPIC_ROTOR_SPEED):
        speed_t, speed = rec.scalars(c.TOPIC_ROTOR_SPEED)
        return speed_t, speed, "rotor/speed (recorded)"
    if not rec.has(c.TOPIC_TACH_ADC):
        raise rec.missing_error([c.TOPIC_ROTOR_SPEED, c.TOPIC_TACH_ADC])
    speed_t, speed = decode_speed(rec, tachometer)
    return speed_t, speed, "tachometer/adc through the tachometer decoder"


#: A measured speed's samples further apart than ``bagio.GAP_FACTOR`` times their median interval
#: and a floor leave the speed between them unknown (a telemetry dropout, a tachometer that lost
#: the blades). A recorded speed's floor is ``bagio.MIN_GAP_S``, so that ``info``'s gaps of
#: /rotor/speed are these. A speed decoded from the tachometer's is ``DECODED_SPEED_GAP_S``: a slow
#: spin-up's first revolution follows the last 0 by up to ~0.55 s on the bundled bags, and the
#: straight line between them is the decoder's intended estimate (``SPIN_UP_MARGIN_REVOLUTIONS``).
RECORDED_SPEED_GAP_S = MIN_GAP_S
DECODED_SPEED_GAP_S = 1.0


def speed_gaps(t: np.ndarray, min_gap_s: float) -> list[tuple[float, float]]:
    """(before, after) of each pair of consecutive speed samples further apart than ``min_gap_s``
    and ``GAP_FACTOR`` median intervals: the rotor's speed between them is unknown. Interpolating
    across one would train and score on a straight line drawn through, say, a punch-out."""
    return [(float(t[i]), float(t[i + 1])) for i in np.flatnonzero(pauses(t, min_gap_s))]


def read_speed_gaps(rec: Recording, t: np.ndarray) -> list[tuple[float, float]]:
    """``speed_gaps`` of ``read_speed``'s times ``t``, at the floor of its source (recorded or decoded)."""
    return speed_gaps(t, RECORDED_SPEED_GAP_S if rec.has(c.TOPIC_ROTOR_SPEED) else DECODED_SPEED_GAP_S)


def speed_on_grid(grid: np.ndarray, t: np.ndarray, v: np.ndarray, gaps: Sequence[tuple[float, float]]
                  ) -> np.ndarray:
    """The measured speed interpolated on ``grid``, NaN strictly inside each of ``gaps``."""
    out = np.interp(grid, t, v)
    for before, after in gaps:
        out[(grid > before) & (grid < after)] = np.nan
    return out


def gap_warnings(signals: Sequence[Signals]) -> list[str]:
    """One line per recording whose measured speed has gaps: how many, how long, where (the
    grid's clock), and that they are left out."""
    lines = []
    for s in signals:
        if s.speed_gaps:
            total = sum(b - a for a, b in s.speed_gaps)
            a, b = max(s.speed_gaps, key=lambda g: g[1] - g[0])
            lines.append(f"{s.path}: the measured speed ({s.speed_source}) has {len(s.speed_gaps)} gap(s), "
                         f"{total:.2f} s in all, the longest {b - a:.2f} s from {a:.2f} s: left out "
                         "(no speed there to train or score on)")
    return lines


def load_signals(
    path: str | os.PathLike[str],
    *,
    grid_rate_hz: float = GRID_RATE_HZ,
    battery: BatteryFilterConfig | None = None,
    tachometer: TachometerConfig | None = None,
    need_speed: bool = True,
    namespace: str | None = None,
) -> Signals:
    """Read one recording (one motor's topics with ``namespace``; ``PATH@NS`` names it in the
    path: specs.py) and align its signals on a ``grid_rate_hz`` grid."""
    with open_recording(path, namespace) as rec:
        if rec.message_count == 0:
            raise BagError(f"{path}: recording is empty")
        if not rec.has(c.TOPIC_PWM):
            raise rec.missing_error([c.TOPIC_PWM])
        pwm_t, pwm = rec.scalars(c.TOPIC_PWM)
        _check_clock(path, c.TOPIC_PWM, _repeats(pwm_t, pwm), len(pwm_t))
        if len(pwm_t) < 2:
            raise BagError(f"{path}: topic /pwm has {len(pwm_t)} messages, need at least 2")
        volt_t, volt, voltage_source = read_voltage(rec, battery)
        if len(volt_t) < 2:
            raise BagError(f"{path}: battery voltage has fewer than 2 valid samples")
        speed_t: np.ndarray | None = None  # the values below are read only where their times are not None
        speed = np.zeros(0)
        gaps: list[tuple[float, float]] = []
        speed_source = ""
        if rec.has(c.TOPIC_ROTOR_SPEED) or rec.has(c.TOPIC_TACH_ADC) or need_speed:
            speed_t, speed, speed_source = read_speed(rec, tachometer)
            gaps = read_speed_gaps(rec, speed_t)
        thrust_t: np.ndarray | None = None
        thrust = np.zeros(0)
        if rec.has(c.TOPIC_THRUST_MEASURED):
            thrust_t, thrust = rec.scalars(c.TOPIC_THRUST_MEASURED)
        current_t: np.ndarray | None = None
        current = np.zeros(0)
        if rec.has("battery/current", c.FLOAT64):
            current_t, current = rec.scalars("battery/current")

    start = max(pwm_t[0], volt_t[0], speed_t[0] if speed_t is not None and len(speed_t) else -np.inf)
    stop = min(pwm_t[-1], volt_t[-1], speed_t[-1] if speed_t is not None and len(speed_t) else np.inf)
    if need_speed and (speed_t is None or len(speed_t) < 2):
        raise BagError(f"{path}: no rotor speed could be measured (tachometer decoded no speed)")
    grid = np.arange(np.ceil(start * grid_rate_hz), np.floor(stop * grid_rate_hz) + 1) / grid_rate_hz
    if len(grid) < MIN_SAMPLES:
        raise BadInputError(
            f"{path}: only {max(len(grid), 0)} aligned samples at {grid_rate_hz:g} Hz "
            f"(need at least {MIN_SAMPLES}: the recording is too short)"
        )
    return Signals(
        path=str(path),
        sha256=recording_sha256(spec_path(path)),
        t=grid,
        pwm=zero_order_hold(pwm_t, pwm, grid),
        voltage=np.interp(grid, volt_t, volt),
        speed=speed_on_grid(grid, speed_t, speed, gaps) if speed_t is not None else np.full(len(grid), np.nan),
        thrust=np.interp(grid, thrust_t, thrust) if thrust_t is not None and len(thrust_t) > 1 else None,
        current=np.interp(grid, current_t, current) if current_t is not None and len(current_t) > 1 else None,
        speed_source=speed_source,
        voltage_source=voltage_source,
        namespace=rec.namespace,
        pwm_events=(pwm_t, pwm),
        voltage_events=(volt_t, volt),
        speed_events=(speed_t, speed) if speed_t is not None else (np.zeros(0), np.zeros(0)),
        speed_gaps=tuple(gaps),
    )


def load_all(paths: Sequence[str | os.PathLike[str]], what: str, namespace: str | None = None) -> list[Signals]:
    """Load recordings (one motor's topics with ``namespace``); a recording listed twice (same
    content) is refused, not double-counted."""
    return unique([load_signals(p, namespace=namespace) for p in paths], what)


def unique(out: list[Signals], what: str) -> list[Signals]:
    """``out`` unless a recording is in it twice (same content, same motor): BadInputError naming
    both. Two motors of one vehicle's recording are two recordings."""
    seen: dict[tuple[str, str | None], str] = {}
    for s in out:
        if s.key in seen:
            raise BadInputError(f"{s.path}: same recording as {seen[s.key]} ({what})")
        seen[s.key] = s.path
    return out
