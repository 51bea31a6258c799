"""ROS-free replay: the nodes' cores over a recording, in message-time order.

What ``replay`` writes is what the three nodes publish for the same recording (the rules are
shared, and ``test/test_nodes_live.py`` checks live = replay):
- ``battery/voltage`` for accepted ``battery/adc`` samples at the node's publish_rate_hz
  (``core.ticker.Ticker`` on sample time),
- ``rotor/speed`` and ``rotor/rpm`` after each ``tachometer/adc`` batch that has a speed to
  stand behind (``core.tach_output.SpeedOutput``: none across a break, 0 only when stopped),
- ``predicted/speed`` and ``predicted/thrust`` on the estimator's 100 Hz grid from the first
  PWM message, fed with the published filtered voltage as the node is through ``battery/voltage``
  (no ``predicted/thrust`` for a model without a thrust coefficient, as the node publishes none),
  and beside them, at the same times, ``predicted/speed_sigma`` and ``predicted/thrust_sigma``
  (the one-sigma band, ``core.uncertainty``) for a model with a band (and a b, for the thrust's),
- with ``adapt`` (``replay --adapt``: the online adaptation, ``core.adaptation``, a physics or
  hybrid model), ``predicted/adapted`` (Float64MultiArray: the adapted parameters in
  ``ADAPTED`` order, in their ``UNITS``, the names comma-joined as layout.dim[0].label) after each
  measured speed the estimator takes, as the node publishes it; the adapted model can be saved
  at the end (``save_adapted``),
- with ``health`` (``replay --health``: the health monitor, ``core.health.HealthStream``, a physics
  or hybrid model), the estimator node's ``health`` status among its diagnostics, and the changes
  found in the summary,
- their stamped forms (``stamped_writer``): ``rotor/state`` once per new measurement, stamped
  with the middle of its revolution; ``predicted/state`` and ``predicted/wrench`` (with a
  thrust coefficient) stamped with the grid time,
- ``/diagnostics`` once a second, as each node publishes it: one DiagnosticArray per node, on
  the absolute topic whatever the namespace, status names carrying the node's namespace and
  name (``motor0/tachometer: tachometer``), hardware_id naming the motor or the pack.
A recording that already carries ``battery/voltage`` (e.g. an imported thrust-stand log) feeds
the estimator from it instead of filtering ``battery/adc``. A recording with the measured
topics and not the raw ones (``battery/voltage`` without ``battery/adc``, ``rotor/speed``
without ``tachometer/adc``: what ``import-csv`` writes) has them copied to the output as
recorded, as they would be on the bus while it plays, and the stage with no input (battery
filter, tachometer) is not run: its status is not reported, the summary says so in one line.
A recorded ``rotor/speed`` reaches the estimator as the node takes it during ``ros2 bag play``
(``ThrustEstimator.update_speed``, the decoded speed's path): the physics starts from the
measured speed, and adaptation and the health monitor follow it.
"""

from __future__ import annotations

import bisect
import dataclasses
import os
from collections.abc import Callable, Iterable
from typing import Any, NamedTuple, TypeAlias, TypedDict, cast

import numpy as np
from numpy.typing import NDArray

from . import contract as c
from .atomic import RECORDING, check_outputs
from .bagio import MOTOR_TOPICS, BagWriter, Bulk, Recording, open_recording, vehicle_topic
from .core.adaptation import ADAPTED, ADAPTED_LABEL, UNITS, PhysicsAdapter, adapter_for, finite_or_none
from .core.battery_filter import BatteryFilter, BatteryFilterConfig
from .core.estimator import NO_THRUST_MESSAGE, ThrustEstimator
from .core.health import HealthEvent, HealthStream, require_physics, seconds_tested_text
from .core.status import CoreStatus
from .core.tach_output import SpeedOutput
from .core.tachometer import Samples, TachometerConfig, TachometerDecoder
from .core.ticker import Ticker
from .core.wrench import check_spin_direction, reaction_torque_nm, torque_coefficient, wrench_status
from .errors import BadInputError
from .model import MODEL, HybridModel, Model, RangeJson, RangeReport, load_model, save_model
from .nodes.params import BATTERY_FILTER, TACHOMETER, THRUST_ESTIMATOR, diagnostic_name, hardware_id
from .physics.fallback import FallbackModel, fallback_model
from .stamped_writer import StampedWriter

ESTIMATOR_RATE_HZ = 100.0  #: thrust_estimator's output_rate_hz default
VOLTAGE_RATE_HZ = 20.0  #: battery_filter's publish_rate_hz default
DIAGNOSTICS_RATE_HZ = 1.0
#: The bulk path reads MCAP recordings in windows of this much bag time (bounded memory)
BULK_WINDOW_S = 60.0


class StatusJson(TypedDict):
    """One core status as the summary carries it (``CoreStatus``'s fields)."""

    name: str
    level: int
    message: str
    values: dict[str, str]


class BandWrittenJson(TypedDict):
    """Whether predicted/*_sigma were written, and the model's band or why not."""

    written: bool
    note: str


class AdaptedJson(TypedDict):
    """One adapted parameter at the end of a replay (``core.adaptation.UNITS``)."""

    value: float | None  #: None: not known (the pack's, until the current has varied enough)
    sigma: float | None
    unit: str


class AdaptationJson(TypedDict):
    """The online adaptation at the end of ``replay --adapt``."""

    state: str  #: "on", or why it was frozen last (the estimator's ``adaptation_state``)
    updates: int  #: measured speeds that updated the parameters
    frozen_samples: int  #: measured speeds that did not
    in_use: bool  #: whether the prediction used the adapted parameters at the end (the guard)
    parameters: dict[str, AdaptedJson]
    #: the changes the health monitor named that were taken into the model (--health,
    #: ``PhysicsAdapter.take_named``): name, size (its unit) and onset (s)
    named_changes_taken: list[dict[str, object]]
    saved: str | None  #: --save-adapted's model file


class HealthJson(TypedDict):
    """The health monitor's findings at the end of ``replay --health``."""

    events: list[dict[str, object]]  #: ``HealthEvent.as_dict`` of each change, in order
    duration_s: float  #: from the first to the last measured speed it took
    monitored_s: float  #: the part after the healthy reference, where changes can be found
    threshold: float
    #: changes that are no alarm (named below HealthConfig.min_size, unnamed that did not hold)
    minor: list[dict[str, object]]
    tested_s: dict[str, float]  #: channel -> seconds its tests ran (HealthRun.tested_s)


class ReplaySummary(TypedDict):
    """What ``replay_bag`` returns (``replay --json``)."""

    path: str
    input: str
    model: str | None
    namespace: str | None
    messages_in: int
    messages_out: int
    messages_in_per_topic: dict[str, int]
    duration_s: float
    read_error: str | None
    out_of_training_range: RangeJson | None
    measured_inputs: list[str]
    band: BandWrittenJson
    adaptation: AdaptationJson | None  #: None: --adapt not given
    health: HealthJson | None  #: None: --health not given
    warnings: list[str]
    status: list[StatusJson]


#: An event of the bulk path: a Float64 or BatteryState value, or a tachometer batch's samples
_EventValue: TypeAlias = "float | NDArray[np.float32]"


class _StreamingOnly(Exception):
    """The recording can only be read exactly message by message (see Recording.bulk)."""


class _Stamped(NamedTuple):
    """The stamped outputs' parameters (the nodes' joint_name, frame_id, spin_direction)."""

    joint_name: str
    frame_id: str
    spin_direction: int


#: The nodes' defaults (an immutable tuple, shared safely as a default argument).
_DEFAULT_STAMPED = _Stamped(c.DEFAULT_JOINT_NAME, c.DEFAULT_FRAME_ID, c.DEFAULT_SPIN_DIRECTION)


def replay_bag(
    in_path: str | os.PathLike[str],
    out_path: str | os.PathLike[str],
    *,
    model_path: str | os.PathLike[str] | None = None,
    force: bool = False,
    battery: BatteryFilterConfig | None = None,
    tachometer: TachometerConfig | None = None,
    namespace: str | None = None,
    reference: bool = False,
    joint_name: str = c.DEFAULT_JOINT_NAME,
    frame_id: str = c.DEFAULT_FRAME_ID,
    spin_direction: int = c.DEFAULT_SPIN_DIRECTION,
    adapt: bool = False,
    save_adapted: str | os.PathLike[str] | None = None,
    health: bool = False,
) -> ReplaySummary:
    """Replay ``in_path`` into a new bag at ``out_path``; returns the summary (``--json``).

    ``adapt``: the estimator adapts its model's physical parameters to the measured speed
    (``core.adaptation.adapter_for``; a network model or the fallback is refused before any
    work) and ``predicted/adapted`` is written; ``save_adapted``: the adapted model's file,
    written at the end (needs ``adapt``; checked with the other outputs before any work).
    ``health``: the health monitor runs on the estimator's inputs (a physics or hybrid model;
    refused before any work otherwise): its status among the estimator's diagnostics, its changes
    in the summary's ``health``.

    ``joint_name``, ``frame_id`` and ``spin_direction`` are the nodes' parameters of the same
    names (the stamped outputs' joint, the wrench's frame, the reaction torque's sign).

    With ``namespace`` (one motor of a vehicle's recording) the outputs are written as the
    quadrotor launch publishes them: under the namespace, ``battery/voltage`` at the root.

    Two paths write the same messages (times, values and diagnostics bit for bit) and return
    the same summary. The reference (``reference=True``, and any recording that only the
    streaming reader reads exactly: damaged, split into files, compressed per message; the
    bulk path then starts again with it) feeds every message to the cores one at a time, as
    the nodes do. The default reads the input topics in bulk (:meth:`Recording.bulk_windows`,
    ``BULK_WINDOW_S`` of recording at a time), filters the battery samples in arrays and
    visits only the sparse events in time order (PWM, tachometer batches, published voltages,
    timer ticks); ``test/test_replay_fast.py`` checks it against the reference message by
    message."""
    stamped = _Stamped(joint_name, frame_id, check_spin_direction(spin_direction, "replay"))
    if save_adapted is not None and not adapt:
        raise BadInputError(f"--save-adapted {save_adapted}: needs --adapt (there is nothing adapted to save)")
    check_outputs([(out_path, RECORDING, "-o"), (save_adapted, MODEL, "--save-adapted")], force=force,
                  inputs=[in_path, model_path])
    model = load_model(model_path) if model_path else fallback_model()
    if adapt:
        _adapter(model, model_path)  # refused now, before any work
    if health:
        _check_health(model, model_path)
    args = (in_path, out_path, model, model_path, force, battery, tachometer, namespace, stamped,
            adapt, save_adapted, health)
    if not reference:
        try:
            return _replay(*args, reference=False)
        except _StreamingOnly:  # nothing was written (the output is staged): the reference path
            pass
    return _replay(*args, reference=True)


def _adapter(model: object, model_path: str | os.PathLike[str] | None) -> PhysicsAdapter:
    """The adaptation of ``model`` (a physics or hybrid model); one line naming --model otherwise."""
    if model_path is None:
        raise BadInputError("--adapt needs --model with a physics or hybrid model (the first-principles "
                            "fallback has no fitted parameters to adapt)")
    try:
        return adapter_for(model)
    except BadInputError as e:
        raise BadInputError(f"--model {model_path}: {e}") from None


def _check_health(model: object, model_path: str | os.PathLike[str] | None) -> None:
    """--health's model: a physics or hybrid one; one line naming --model otherwise."""
    if model_path is None:
        raise BadInputError("--health needs --model with a physics or hybrid model (the first-principles "
                            "fallback has no fitted physics to give the faults' signatures)")
    require_physics(model, "the health monitor (--health)", f"--model {model_path}")


def _health_json(stream: HealthStream | None) -> HealthJson | None:
    """The monitor's findings for the summary; None without it."""
    if stream is None:
        return None
    run = stream.run()
    return {"events": [e.as_dict() for e in run.events], "duration_s": run.duration_s,
            "monitored_s": run.monitored_s, "threshold": run.threshold,
            "minor": [e.as_dict() for e in run.minor], "tested_s": dict(run.tested_s)}


def health_lines(events: list[HealthEvent], indent: str = "  ") -> list[str]:
    """The changes as the health command prints them, a line each (``HealthEvent.text``)."""
    return [indent + e.text() for e in events]


def adapted_model(model: Model, adapter: PhysicsAdapter) -> Model:
    """``model`` with the adapted physics (``PhysicsAdapter.adapted_plant``): a hybrid keeps its
    network (a correction of the physics' speed, which it still is), its b (the hybrid's own)
    scaled by the propeller's loss and its metadata saying what was adapted."""
    plant = adapter.adapted_plant()
    if not isinstance(model, HybridModel):
        return plant
    net = model.network
    b = net.thrust_coefficient
    return HybridModel(plant, dataclasses.replace(
        net, thrust_coefficient=None if b is None else b * adapter.thrust_factor,
        metadata={**net.metadata, "adapted": plant.metadata["adapted"]}))


def _adaptation_json(est: ThrustEstimator, saved: str | os.PathLike[str] | None) -> AdaptationJson | None:
    """The adaptation's end state for the summary; None without one."""
    ad = est.adapter
    if not isinstance(ad, PhysicsAdapter):
        return None
    return {"state": est.adaptation_state(), "updates": ad.updates, "frozen_samples": ad.frozen_samples,
            "in_use": ad.in_use,
            "parameters": {n: {"value": finite_or_none(v), "sigma": finite_or_none(s), "unit": UNITS[n]}
                           for n, (v, s) in ad.values().items()},
            "named_changes_taken": ad.named_changes(),
            "saved": None if saved is None else str(saved)}


def _input_topics(rec: Recording) -> tuple[list[str], bool, list[str]]:
    """The topics replay reads (raw inputs, then measured ones), whether the recording has a
    filtered voltage, and the measured topics standing in for raw ones it lacks (used as
    recorded); a recording with none, or a vehicle's root, is refused in one line."""
    inputs = [t for t in (c.TOPIC_PWM, c.TOPIC_BATTERY_ADC, c.TOPIC_TACH_ADC) if rec.has(t)]
    has_voltage = rec.has(c.TOPIC_BATTERY_VOLTAGE, c.BATTERY_STATE)
    if has_voltage:
        inputs.append(c.TOPIC_BATTERY_VOLTAGE)
    measured = [topic for topic, raw, ok in (
        (c.TOPIC_BATTERY_VOLTAGE, c.TOPIC_BATTERY_ADC, has_voltage),
        (c.TOPIC_ROTOR_SPEED, c.TOPIC_TACH_ADC, rec.has(c.TOPIC_ROTOR_SPEED, c.FLOAT64)),
    ) if ok and not rec.has(raw)]
    if c.TOPIC_ROTOR_SPEED in measured:
        inputs.append(c.TOPIC_ROTOR_SPEED)
    for topic, msgtype in ((c.TOPIC_PWM, c.FLOAT64), (c.TOPIC_BATTERY_ADC, c.FLOAT64),
                           (c.TOPIC_TACH_ADC, c.FLOAT32_ARRAY)):
        if rec.has(topic):
            rec.require(topic, msgtype)
    if not inputs:
        raise rec.missing_error([c.TOPIC_PWM, c.TOPIC_BATTERY_ADC, c.TOPIC_TACH_ADC])
    if rec.motors_elsewhere():
        raise rec.missing_error(MOTOR_TOPICS)  # a vehicle's recording: only its battery is at the root
    return inputs, has_voltage, measured


def _replay(
    in_path: str | os.PathLike[str],
    out_path: str | os.PathLike[str],
    model: Model | FallbackModel,
    model_path: str | os.PathLike[str] | None,
    force: bool,
    battery: BatteryFilterConfig | None,
    tachometer: TachometerConfig | None,
    namespace: str | None,
    stamped: _Stamped,
    adapt: bool,
    save_adapted: str | os.PathLike[str] | None,
    health: bool,
    *,
    reference: bool,
) -> ReplaySummary:
    with open_recording(in_path, namespace) as rec:
        ns = rec.namespace
        inputs, has_voltage, measured = _input_topics(rec)
        filt = BatteryFilter(battery or BatteryFilterConfig())
        tach = TachometerDecoder(tachometer or TachometerConfig())
        est = ThrustEstimator(model, adapter=_adapter(model, model_path) if adapt else None)
        monitor = HealthStream(est) if health else None
        with BagWriter(out_path, force=force, t0_ns=rec.t0_ns) as bag:
            node = _Nodes(bag, filt, tach, est, lambda topic: vehicle_topic(topic, ns), has_voltage, measured,
                          stamped, ns, monitor)
            if reference:
                node.run_reference(rec.messages(inputs, tolerant=True))
            else:
                for bulk in rec.bulk_windows(inputs, BULK_WINDOW_S):
                    if bulk is None:  # only the streaming reader reads it exactly: start again
                        raise _StreamingOnly
                    node.run_bulk(bulk, rec.t0_ns)
            end = (rec.end_ns - rec.t0_ns) * 1e-9
            node.timers_until(end)
            node.counts["messages_out"] = bag.messages_written
        if monitor is not None:  # the end of the data: a change still being named, as it stands
            monitor.finish()
        counts, per_topic_in = node.counts, node.per_topic_in
        tach.check_timeout(end)  # a tachometer silent until the end: its status says so
        statuses = [*([] if c.TOPIC_BATTERY_VOLTAGE in measured else filt.status()),
                    *([] if c.TOPIC_ROTOR_SPEED in measured else tach.status()), *est.status(),
                    *node.wrench_status(), *node.health_status()]
        n = max(est.predictions, 1)
        ranged = None if est.is_fallback else RangeReport(
            str(in_path), est.clipped / n, {k: v / n for k, v in est.clipped_by_input.items() if v})
        warnings = [w for w in (ranged.warning() if ranged else None,) if w]
        if est.thrust_coefficient is None:
            warnings.append(f"--model {model_path}: no {c.TOPIC_PREDICTED_THRUST} written: {NO_THRUST_MESSAGE}")
        if save_adapted is not None and isinstance(est.adapter, PhysicsAdapter) and not isinstance(
                model, FallbackModel):  # (--adapt refuses the fallback)
            save_model(adapted_model(model, est.adapter), save_adapted, force=force)
        return {
            "path": str(out_path),
            "input": str(in_path),
            "model": str(model_path) if model_path else None,
            "namespace": ns,
            "messages_in": counts["messages_in"],
            "messages_out": counts["messages_out"],
            "messages_in_per_topic": per_topic_in,
            "duration_s": end,
            "read_error": rec.read_error,
            "out_of_training_range": ranged.as_dict() if ranged else None,
            "measured_inputs": ["/" + topic for topic in measured],
            "band": {"written": est.band is not None, "note": est.band_note},  # predicted/*_sigma, or why not
            "adaptation": _adaptation_json(est, save_adapted),
            "health": _health_json(monitor),
            "warnings": warnings,
            "status": [
                {"name": s.name, "level": s.level, "message": s.message, "values": dict(s.values)}
                for s in statuses
            ],
        }


def diagnostic_source(namespace: str | None, node: str) -> tuple[str, str]:
    """(status name prefix, hardware_id) of ``node``'s diagnostics where replay puts the node: as
    the quadrotor launch does, the battery filter at the root (the vehicle's one pack) and the
    motor's nodes under ``namespace``; so a recording's /diagnostics reads as the live bus does."""
    ns = "" if namespace is None or node == BATTERY_FILTER else namespace
    return diagnostic_name(f"/{ns}/{node}" if ns else f"/{node}", ""), hardware_id(ns, node)


class _Nodes:
    """The three nodes' cores, timers and publishers over one replay."""

    def __init__(self, bag: BagWriter, filt: BatteryFilter, tach: TachometerDecoder,
                 est: ThrustEstimator, topic_out: Callable[[str], str], has_voltage: bool,
                 measured: Iterable[str] = (),
                 stamped: _Stamped = _DEFAULT_STAMPED,
                 namespace: str | None = None,
                 health: HealthStream | None = None) -> None:
        self.bag, self.filt, self.tach, self.est = bag, filt, tach, est
        self.health = health
        self.stamped = StampedWriter(bag, topic_out(c.TOPIC_ROTOR_STATE), topic_out(c.TOPIC_PREDICTED_STATE),
                                     topic_out(c.TOPIC_PREDICTED_WRENCH), joint_name=stamped.joint_name,
                                     frame_id=stamped.frame_id)
        self.spin_direction = stamped.spin_direction
        self.torque_coefficient = torque_coefficient(est.model)
        self.has_voltage = has_voltage
        #: battery/voltage, rotor/speed recorded in place of the raw topics: copied to the output
        self.measured = frozenset(measured)
        self.speed_out = SpeedOutput(tach)
        self.predictions = Ticker(ESTIMATOR_RATE_HZ)
        self.voltage_out = Ticker(VOLTAGE_RATE_HZ)
        self.next_diag: float | None = None
        self.counts = {"messages_in": 0, "messages_out": 0}
        self.per_topic_in: dict[str, int] = {}
        #: the battery filter's diagnostics; the bulk path hands out statuses taken in advance.
        #: A stage that has no input because the recording holds its output reports nothing.
        self.filter_status: Callable[[], list[CoreStatus]] = (
            list if c.TOPIC_BATTERY_VOLTAGE in self.measured else filt.status)
        self.tach_status: Callable[[], list[CoreStatus]] = list if c.TOPIC_ROTOR_SPEED in self.measured else tach.status
        (self.speed_topic, self.thrust_topic, self.voltage_topic, self.rotor_topic,
         self.rpm_topic) = map(topic_out, (
            c.TOPIC_PREDICTED_SPEED, c.TOPIC_PREDICTED_THRUST, c.TOPIC_BATTERY_VOLTAGE,
            c.TOPIC_ROTOR_SPEED, c.TOPIC_ROTOR_RPM))
        self.speed_sigma_topic, self.thrust_sigma_topic = map(topic_out, (
            c.TOPIC_PREDICTED_SPEED_SIGMA, c.TOPIC_PREDICTED_THRUST_SIGMA))
        self.adapted_topic = topic_out(c.TOPIC_PREDICTED_ADAPTED)
        #: each node's diagnostics: (status name prefix, hardware_id, its statuses now); a stage
        #: whose statuses are empty (not run) publishes nothing
        self.diagnostics: tuple[tuple[str, str, Callable[[], list[CoreStatus]]], ...] = (
            (*diagnostic_source(namespace, BATTERY_FILTER), lambda: self.filter_status()),
            (*diagnostic_source(namespace, TACHOMETER), lambda: self.tach_status()),
            (*diagnostic_source(namespace, THRUST_ESTIMATOR),
             lambda: [*est.status(), *self.wrench_status(), *self.health_status()]),
        )

    def timers_until(self, t: float) -> None:
        """Outputs due up to t, emitted before an input at t is applied (as the nodes
        do: a grid time equal to an input's time sees the state before it)."""
        predictions, next_diag = self.predictions, self.next_diag
        if t < predictions.next_s and (next_diag is None or t < next_diag):
            return
        bag, est = self.bag, self.est
        for tick in predictions.due(t):
            p = est.predict(tick)
            if p.ready:
                bag.write_float64(self.speed_topic, tick, p.speed_rad_s)
                if p.thrust_n is not None:
                    bag.write_float64(self.thrust_topic, tick, p.thrust_n)
                if p.speed_sigma_rad_s is not None:  # the model has a band (core.uncertainty)
                    bag.write_float64(self.speed_sigma_topic, tick, p.speed_sigma_rad_s)
                    if p.thrust_sigma_n is not None:
                        bag.write_float64(self.thrust_sigma_topic, tick, p.thrust_sigma_n)
                self.stamped.prediction(tick, p.speed_rad_s, p.thrust_n, reaction_torque_nm(
                    self.torque_coefficient, p.speed_rad_s, self.spin_direction))
        while next_diag is not None and next_diag <= t:
            self.tach.check_timeout(next_diag)
            for prefix, hardware, node_statuses in self.diagnostics:
                statuses = node_statuses()
                if statuses:
                    bag.write_diagnostics(c.TOPIC_DIAGNOSTICS_ABSOLUTE, next_diag, statuses, prefix, hardware)
            next_diag += 1.0 / DIAGNOSTICS_RATE_HZ
        self.next_diag = next_diag

    def wrench_status(self) -> list[CoreStatus]:
        """The node's status on predicted/wrench's torque (core.wrench)."""
        return wrench_status(self.torque_coefficient, self.est.thrust_coefficient is not None)

    def health_status(self) -> list[CoreStatus]:
        """The node's health status (with the monitor on), as it publishes it."""
        return [] if self.health is None else [self.health.status()]

    # --- the inputs, as the nodes' callbacks take them ------------------------------------
    def pwm(self, t: float, value: float) -> None:
        if self.est.update_pwm(t, value):
            self.predictions.start(t)
            if self.health is not None:
                self.health.update_pwm(t, value)

    def estimator_voltage(self, t: float, v: float) -> None:
        """The estimator node takes a battery/voltage (and the health monitor what it took)."""
        if self.est.update_voltage(t, v) and self.health is not None:
            self.health.update_voltage(t, v)

    def voltage_published(self, t: float, v: float) -> None:
        """The battery filter publishes ``v``; the estimator takes it unless the recording
        carries its own battery/voltage."""
        self.bag.write_battery_state(self.voltage_topic, t, v)
        if not self.has_voltage:  # as the node receives it: BatteryState.voltage is a float32
            self.estimator_voltage(t, float(np.float32(v)))

    def voltage_recorded(self, t: float, v: float) -> None:
        """The recording's battery/voltage: the estimator's voltage; also the output's when
        there is no battery/adc for the filter to publish from."""
        if c.TOPIC_BATTERY_VOLTAGE in self.measured:
            self.bag.write_battery_state(self.voltage_topic, t, v)
        self.estimator_voltage(t, v)

    def speed_recorded(self, t: float, w: float) -> None:
        """The recording's rotor/speed (no tachometer/adc to decode): the output's, as recorded;
        its stamped form at the recorded time, the instant the log gives it (no revolution to
        place it in); and the estimator's, as the node takes it while the recording plays."""
        self.bag.write_float64(self.rotor_topic, t, w)
        self.bag.write_float64(self.rpm_topic, t, w * c.RAD_S_TO_RPM)
        self.stamped.rotor_state(t, t, w)
        self.speed_taken(t, w)

    def speed_taken(self, t: float, w: float) -> None:
        """A measured speed as the estimator node takes rotor/speed: the estimator, then (if it
        accepted it) predicted/adapted with adaptation on, and the health monitor."""
        if not self.est.update_speed(t, w):
            return
        if self.est.adapter is not None:
            self.adapted(t)
        if self.health is not None:
            self.health.update_speed(t, w)

    def tach_batch(self, t: float, samples: Samples) -> None:
        self.tach.process_batch(t, samples, result=False)
        out = self.speed_out
        speed = out.after_batch(t)
        if speed is not None:
            self.bag.write_float64(self.rotor_topic, t, speed)
            self.bag.write_float64(self.rpm_topic, t, speed * c.RAD_S_TO_RPM)
            if out.fresh:
                self.stamped.rotor_state(t, out.stamp_s, speed)
            self.speed_taken(t, speed)

    def adapted(self, t: float) -> None:
        """predicted/adapted after a measured speed the estimator took (adaptation on)."""
        assert self.est.adapter is not None
        values = self.est.adapter.values()
        self.bag.write_float64_array(self.adapted_topic, t, [values[n][0] for n in ADAPTED], ADAPTED_LABEL)

    # --- the reference: every message in turn ----------------------------------------------
    def run_reference(self, messages: Iterable[tuple[str, float, Any]]) -> None:  # rosbags messages
        counts, per_topic_in = self.counts, self.per_topic_in
        for topic, t, msg in messages:
            self.timers_until(t)
            counts["messages_in"] += 1
            per_topic_in[topic] = per_topic_in.get(topic, 0) + 1
            if self.next_diag is None:
                self.next_diag = t + 1.0 / DIAGNOSTICS_RATE_HZ
            if topic == c.TOPIC_PWM:
                self.pwm(t, float(msg.data))
            elif topic == c.TOPIC_BATTERY_ADC:
                v = self.filt.update(t, float(msg.data))
                if v is not None and self.voltage_out.take(t):
                    self.voltage_published(t, v)
            elif topic == c.TOPIC_BATTERY_VOLTAGE:
                self.voltage_recorded(t, float(msg.voltage))
            elif topic == c.TOPIC_TACH_ADC:
                self.tach_batch(t, msg.data)
            elif topic == c.TOPIC_ROTOR_SPEED:
                self.speed_recorded(t, float(msg.data))

    # --- the bulk path ----------------------------------------------------------------------
    def run_bulk(self, bulk: Bulk, t0_ns: int) -> None:
        """The same as :meth:`run_reference` over ``bulk``'s messages (the next window of them:
        state carries from one call to the next).

        Every message is a possible timer point (the first message at or after the next
        prediction or diagnostics time triggers them, and the tick times depend on which
        message did), so the message times stay one array searched for the next trigger;
        between triggers only events are visited: PWM, tachometer batches, battery/voltage and
        rotor/speed messages and the battery samples after which the filter publishes. The battery filter
        runs over the samples in arrays (``BatteryFilter.process``, the same arithmetic as
        ``update``), cut at the diagnostics times so that its counters there are exact.
        """
        n = len(bulk.ns)
        if n == 0:
            return
        times = ((bulk.ns - t0_ns) * 1e-9).tolist()  # as float((ns - t0) * 1e-9) per message
        code = bulk.code
        self.counts["messages_in"] += n
        first = {int(k): int(np.argmax(code == k)) for k in np.unique(code)}
        for k in sorted(first, key=first.__getitem__):  # topics in order of first appearance
            topic = bulk.topics[k]
            self.per_topic_in[topic] = self.per_topic_in.get(topic, 0) + int(np.count_nonzero(code == k))
        if self.next_diag is None:
            self.next_diag = times[0] + 1.0 / DIAGNOSTICS_RATE_HZ
        # events: (message index, kind, value); the battery samples that publish are added below
        events: list[tuple[int, int, _EventValue]] = []
        for k, topic in enumerate(bulk.topics):
            where = np.flatnonzero(code == k).tolist()
            vals = bulk.values[topic]  # the topic's type decides the form (bagio.BulkValues)
            if topic == c.TOPIC_PWM:
                events += zip(where, [0] * len(where), cast("NDArray[np.float64]", vals).tolist(), strict=True)
            elif topic == c.TOPIC_TACH_ADC:
                batches = cast("list[NDArray[np.float32]]", vals)
                events += zip(where, [2] * len(where), batches, strict=True)
                self.tach.expect(batches)  # their level trackers are computed many at a time
            elif topic == c.TOPIC_BATTERY_VOLTAGE:
                events += zip(where, [3] * len(where), cast("NDArray[np.float64]", vals).tolist(), strict=True)
            elif topic == c.TOPIC_ROTOR_SPEED:
                events += zip(where, [4] * len(where), cast("NDArray[np.float64]", vals).tolist(), strict=True)
            elif topic == c.TOPIC_BATTERY_ADC:
                events += self._battery(np.asarray(where), np.asarray(times)[where],
                                        cast("NDArray[np.float64]", vals))
        events.sort(key=lambda e: e[0])
        self._visit(times, events)

    def _battery(self, where: np.ndarray, t: np.ndarray, adc: np.ndarray) -> list[tuple[int, int, float]]:
        """Filter every battery sample; the filter's statuses at the diagnostics times (taken
        now, in order, for :meth:`timers_until`); the (message index, 1, volts) events of the
        samples after which the filter publishes (the Ticker's rule at each accepted sample)."""
        filt, end = self.filt, len(t)
        out = np.empty(end)
        statuses: list[list[CoreStatus]] = []
        diag, a = self._diag_due(), 0
        while a < end:
            b = int(np.searchsorted(t, diag, side="left"))  # samples before diagnostics at `diag`
            out[a:b] = filt.process(t[a:b], adc[a:b])
            a = b
            if a < end:
                statuses.append(filt.status())
                diag += 1.0 / DIAGNOSTICS_RATE_HZ
        later = iter(statuses)
        self.filter_status = lambda: next(later, None) or self.filt.status()
        accepted = np.flatnonzero(~np.isnan(out))
        ta = t[accepted].tolist()
        events: list[tuple[int, int, float]] = []
        ticker, i = self.voltage_out, 0
        while i < len(ta):
            if ticker.take(ta[i]):  # the first accepted sample at or after the next grid time
                k = int(accepted[i])
                events.append((int(where[k]), 1, float(out[k])))
            i = bisect.bisect_left(ta, ticker.next_s, i + 1)
        return events

    def _diag_due(self) -> float:
        """The next diagnostics time, in the bulk path (which sets it from the first message)."""
        assert self.next_diag is not None, "set before the bulk events are visited"
        return self.next_diag

    def _visit(self, times: list[float], events: list[tuple[int, int, _EventValue]]) -> None:
        n, predictions = len(times), self.predictions
        done = 0  # messages before this index have been applied
        for pos, kind, value in events:
            while True:  # timers triggered by messages up to and including this one
                due = min(predictions.next_s, self._diag_due())
                j = bisect.bisect_left(times, due, done)
                if j > pos:
                    break
                self.timers_until(times[j])
                done = j + 1
            t = times[pos]
            # the kind says which form the value has (casts only: no check in this loop)
            if kind == 0:
                self.pwm(t, cast(float, value))
            elif kind == 1:
                self.voltage_published(t, cast(float, value))
            elif kind == 2:
                self.tach_batch(t, cast("NDArray[np.float32]", value))
            elif kind == 3:
                self.voltage_recorded(t, cast(float, value))
            else:
                self.speed_recorded(t, cast(float, value))
            done = pos + 1
        while True:
            j = bisect.bisect_left(times, min(predictions.next_s, self._diag_due()), done)
            if j >= n:
                break
            self.timers_until(times[j])
            done = j + 1


def summary_text(info: ReplaySummary) -> str:
    """A few lines a person reads after a replay."""
    lines = [
        f"replayed {info['input']} ({info['duration_s']:.1f} s) -> {info['path']}",
        f"  messages in {info['messages_in']}, out {info['messages_out']}; "
        f"model: {info['model'] or 'first-principles fallback'}",
    ]
    measured = info.get("measured_inputs") or []
    if measured:
        stages = {"/" + c.TOPIC_BATTERY_VOLTAGE: ("to the estimator and the output", "/" + c.TOPIC_BATTERY_ADC,
                                                  "battery filter"),
                  "/" + c.TOPIC_ROTOR_SPEED: ("to the estimator and the output", "/" + c.TOPIC_TACH_ADC,
                                              "tachometer")}
        lines.append(
            "  [INFO] measured " + " and ".join(f"{m} ({stages[m][0]})" for m in measured)
            + " used as recorded: the recording has no " + " or ".join(stages[m][1] for m in measured)
            + ", so the " + " and ".join(stages[m][2] for m in measured) + " did not run")
    ad = info.get("adaptation")
    if ad:
        vals = ", ".join(f"{n} {p['value']:.4g} +/- {p['sigma']:.2g} ({p['unit']})" if p["value"] is not None
                         else f"{n} not known (the voltage has not shown it)"
                         for n, p in ad["parameters"].items())
        lines.append(f"  adaptation ({ad['state']}; {ad['updates']} updates): {vals}"
                     + (f"; adapted model -> {ad['saved']}" if ad["saved"] else ""))
    hj = info.get("health")
    if hj:
        events = [HealthEvent.from_dict(e) for e in hj["events"]]
        lines.append(f"  health monitor: {len(events)} change{'' if len(events) == 1 else 's'} over "
                     f"{hj['monitored_s']:.1f} s monitored ("
                     + seconds_tested_text(hj["tested_s"]) + f"threshold {hj['threshold']:.1f})"
                     + ("" if events or hj["monitored_s"] > 0.0 else
                        ": too short, the first reference + window seconds are the healthy reference"))
        lines += health_lines(events, "    ")
    for s in info["status"]:
        level = ("OK", "WARN", "ERROR")[min(int(s["level"]), 2)]
        vals = ", ".join(f"{k}={v}" for k, v in s["values"].items() if _worth_saying(k, v))
        lines.append(f"  [{level}] {s['name']}: {s['message']}" + (f" ({vals})" if vals else ""))
    if info.get("read_error"):
        lines.append(f"  recording damaged: kept the readable part; {info['read_error']}")
    return "\n".join(lines)


#: Counters a replay summary shows when they are not zero: what went wrong, not what went well.
_PROBLEM_WORDS = ("reject", "loss", "glitch", "gap", "clipped", "mismatch", "reset", "missing",
                  "nonfinite", "suppressed", "unverified", "not_ready", "resync")


def _worth_saying(key: str, value: str) -> bool:
    if key in ("accepted", "edges", "speeds", "predictions", "batches", "samples"):
        return True
    return any(w in key for w in _PROBLEM_WORDS) and value not in ("0", "False", "nan", "")
