"""thrust_estimator: pwm + battery/voltage (+ rotor/speed) -> predicted/speed, predicted/thrust.

Timing: a PWM command (Float64, no header) is timed by its publisher's clock mapped onto the
node clock (``stream_time.EventStream``), so commands queued during a stall keep their own
times; battery/voltage by its header stamp. Predictions are made on a grid of output_rate_hz
(``core.ticker.Ticker``, started at the first command): before each input is applied, every grid
time up to it is predicted, and a timer (25 Hz: inputs usually come faster) emits the grid
times the node clock has passed by output_delay_s (so inputs published before a grid time have
arrived). So the rate holds under
``ros2 bag play --clock`` at 40 Hz, and the outputs are the ones ``replay`` writes for the same
recording.

What is not published: nothing before the first command and voltage; with pwm_timeout_s > 0,
nothing while the command is older than that (diagnostics ERROR). A lost command (a jump in the
publisher's sequence numbers) is counted and reported on diagnostics.

rotor/speed (Float64 rad/s, the tachometer's), when something publishes it, is timed as pwm is
and never predicted from: a physics or hybrid model's physics starts from the latest measured
speed instead of at rest when it starts (the first command, and a command after a stale one:
``core.estimator.ThrustEstimator.update_speed``), so a node started on a turning rotor is right
from its first prediction. Without it nothing changes.

A model without a thrust coefficient (trained with no thrust measured or stated) gives no
predicted/thrust: the topic is not even advertised while such a model is loaded, and a
diagnostics status (WARN) says why; the parameter thrust_coefficient > 0 states a b for it.

Stamped forms (header.stamp = the grid time a prediction answers, on the node clock):
predicted/state (JointState, name[0] = joint_name, velocity[0] = predicted speed) and, with a b,
predicted/wrench (WrenchStamped in frame_id: force.z = thrust, torque.z = the reaction torque
on the body, signed by spin_direction, where the model knows the propeller's torque, else 0
and a WARN saying so: ``core.wrench``).

The project's additions beyond the contract (docs/ros.md): predicted/speed_sigma and
predicted/thrust_sigma (Float64, rad/s and N), the one-sigma band of each prediction
(``core.uncertainty``), at the same grid times as predicted/speed; advertised only while the
model has a band (and, for the thrust's, a b); without one, diagnostics say why (``band``).

adapt (parameter, default false; a physics or hybrid model, refused at start for another):
the online adaptation (``core.adaptation``): each measured speed on rotor/speed updates the
propeller's loss and the friction factor, and the battery voltage the pack's series resistance,
which the prediction and the thrust then use. After each measured speed the estimator takes,
predicted/adapted (Float64MultiArray, the project's addition: the values in ``ADAPTED`` order,
propeller loss fraction, friction factor and the pack's resistance in ohm (NaN until known),
layout.dim[0].label the names comma-joined) is published; diagnostics carry ``adaptation`` (on,
or why frozen) and each ``adapted_*`` value with its sigma. A model reload keeps adapt (a network
is then refused like a file that does not load) and starts from the new model's constants.

health (parameter, default false; a physics or hybrid model, refused at start for another): the
health monitor (``core.health.HealthStream``, the code ``replay --health`` and ``bldc-propulsion
health`` run) takes every input the estimator accepts and tests each measured speed on rotor/speed
against the offline model. Its diagnostics status ``health``: OK (no change), WARN (a change seen
and being named, or left unnamed), ERROR (a named fault: the latest stays until the model is
loaded again, the same model_path set again included), with ``effect``, ``size``, ``unit``,
``onset_s`` and ``detected_s`` on the node's clock.

model_path '' uses the first-principles fallback and says so on diagnostics (WARN). A model
file that does not load stops the node at start (one-line error, exit status 2); changed at run
time (``ros2 param set``), such a file is refused and the last good model kept.
"""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING, Any

from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from sensor_msgs.msg import BatteryState
from std_msgs.msg import Float64

if TYPE_CHECKING:
    from rclpy.parameter import Parameter

    from bldc_propulsion.core.health import HealthStream

from bldc_propulsion import contract
from bldc_propulsion.core.estimator import ThrustEstimator
from bldc_propulsion.core.status import ERROR, OK, WARN, CoreStatus, counters
from bldc_propulsion.core.ticker import Ticker
from bldc_propulsion.core.wrench import check_spin_direction, reaction_torque_nm, torque_coefficient, wrench_status
from bldc_propulsion.errors import BadInputError
from bldc_propulsion.model import load_model
from bldc_propulsion.nodes.common import (
    JointStateOutput,
    NamedValuesOutput,
    NodeClock,
    ScalarOutput,
    WithInfo,
    WrenchOutput,
    declare_parameters,
    diagnostic_array,
    input_qos,
    run_node,
    stamp_s,
    stamped_name,
)
from bldc_propulsion.nodes.params import DIAGNOSTICS_PERIOD_S, THRUST_ESTIMATOR, THRUST_ESTIMATOR_PARAMS
from bldc_propulsion.nodes.stream_time import EventStream
from bldc_propulsion.physics.fallback import fallback_model

FALLBACK_TIMER_HZ = 25.0


class ThrustEstimatorNode(Node):

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(THRUST_ESTIMATOR, **kwargs)
        self.now_s = NodeClock(self)
        params = declare_parameters(self, THRUST_ESTIMATOR_PARAMS)
        self.thrust_coefficient = params['thrust_coefficient'] or None
        self.model_path = params['model_path']
        self.adapt = bool(params['adapt'])
        self.health_on = bool(params['health'])
        self.core = make_estimator(self.model_path, self.thrust_coefficient, self.adapt,
                                   self.get_fully_qualified_name())  # BadInputError
        #: the health monitor on the estimator's inputs (parameter health); None: off
        self.health = make_health(self.core, self.model_path, self.get_fully_qualified_name()) \
            if self.health_on else None
        self.reload_error = ''
        self.pwm_stream = EventStream(params['use_source_timestamps'])
        self.speed_stream = EventStream(params['use_source_timestamps'])
        self.pwm_timeout_s = params['pwm_timeout_s']
        self.ticks = Ticker(params['output_rate_hz'])
        self.output_delay_s = params['output_delay_s']
        self.last_pwm_s: float | None = None
        self.stale_ticks = 0  #: grid times not predicted because the command was stale
        self.late_inputs = 0  #: inputs timed at or before a grid time already published

        self.spin_direction = check_spin_direction(
            params['spin_direction'], f'{self.get_fully_qualified_name()}: parameter spin_direction')
        self.frame_id = stamped_name(self, 'frame_id', params['frame_id'])
        self.speed_out = ScalarOutput(self, contract.TOPIC_PREDICTED_SPEED)
        self.state_out = JointStateOutput(
            self, contract.TOPIC_PREDICTED_STATE, stamped_name(self, 'joint_name', params['joint_name']))
        self.thrust_out: ScalarOutput | None = None
        self.wrench_out: WrenchOutput | None = None
        self.match_thrust_output()
        self.speed_sigma_out: ScalarOutput | None = None
        self.thrust_sigma_out: ScalarOutput | None = None
        self.match_band_output()
        #: predicted/adapted (with adapt: the adaptation's values after each measured speed, in
        #: the order of adapted_names)
        self.adapted_out: NamedValuesOutput | None = None
        self.adapted_names: tuple[str, ...] = ()
        if self.adapt:  # the adaptation and the health monitor are imported only when used (start-up)
            from bldc_propulsion.core.adaptation import ADAPTED, ADAPTED_LABEL

            self.adapted_names = ADAPTED
            self.adapted_out = NamedValuesOutput(
                self, contract.TOPIC_PREDICTED_ADAPTED, ADAPTED_LABEL, len(ADAPTED))
        self.diagnostics_pub = self.create_publisher(
            DiagnosticArray, contract.TOPIC_DIAGNOSTICS_ABSOLUTE, 10)
        qos = input_qos(params['queue_depth'])
        self.pwm_sub = self.create_subscription(
            Float64, contract.TOPIC_PWM, WithInfo(self.on_pwm), qos)
        self.voltage_sub = self.create_subscription(
            BatteryState, contract.TOPIC_BATTERY_VOLTAGE, self.on_voltage, qos)
        self.measured_speed_sub = self.create_subscription(
            Float64, contract.TOPIC_ROTOR_SPEED, WithInfo(self.on_speed), qos)
        # Inputs emit the grid up to their own time; the timer only covers quiet inputs, so
        # it runs at most at FALLBACK_TIMER_HZ (each callback costs as much as a message).
        self.output_timer = self.create_timer(
            max(self.ticks.period_s, 1.0 / FALLBACK_TIMER_HZ), self.on_timer)
        self.diagnostics_timer = self.create_timer(DIAGNOSTICS_PERIOD_S, self.publish_diagnostics)
        self.add_on_set_parameters_callback(self.on_set_parameters)

    def on_pwm(self, msg: Float64, info: dict | None) -> None:
        t, _lost = self.pwm_stream.place_info(self.now_s(), info)
        self.count_late(t)
        self.publish_until(t)
        if self.command_stale(t) and self.core.measured_speed_at(t) is not None:
            self.core.restart_physics()  # the rotor did something unknown meanwhile: measured
            if self.health is not None:
                self.health.restart_physics()
        if self.core.update_pwm(t, msg.data):
            self.last_pwm_s = t
            self.ticks.start(t)
            if self.health is not None:
                self.health.update_pwm(t, msg.data)

    def on_speed(self, msg: Float64, info: dict | None) -> None:
        t, _lost = self.speed_stream.place_info(self.now_s(), info)
        self.count_late(t)
        self.publish_until(t)
        if not self.core.update_speed(t, msg.data):
            return
        adapter = self.core.adapter
        if adapter is not None and self.adapted_out is not None:
            values = adapter.values()
            self.adapted_out.publish([values[n][0] for n in self.adapted_names])
        if self.health is not None:
            for event in self.health.update_speed(t, msg.data):
                self.get_logger().warn(f'health: {event.text().strip()}')

    def on_voltage(self, msg: BatteryState) -> None:
        t = stamp_s(msg.header.stamp)
        self.count_late(t)
        self.publish_until(t)
        if self.core.update_voltage(t, msg.voltage) and self.health is not None:
            self.health.update_voltage(t, msg.voltage)

    def match_thrust_output(self) -> None:
        """predicted/thrust and predicted/wrench exist while the model has a b: a subscriber
        then sees no publisher, rather than a topic that stays silent (the diagnostics say why).
        The wrench's kQ follows the model (a reload may bring or drop it)."""
        self.torque_coefficient = torque_coefficient(self.core.model)
        if self.core.thrust_coefficient is not None and self.thrust_out is None:
            self.thrust_out = ScalarOutput(self, contract.TOPIC_PREDICTED_THRUST)
            self.wrench_out = WrenchOutput(self, contract.TOPIC_PREDICTED_WRENCH, self.frame_id)
        elif (self.core.thrust_coefficient is None and self.thrust_out is not None
              and self.wrench_out is not None):  # the two come and go together
            self.destroy_publisher(self.thrust_out.publisher)
            self.destroy_publisher(self.wrench_out.publisher)
            self.thrust_out = self.wrench_out = None

    def match_band_output(self) -> None:
        """predicted/speed_sigma exists while the model has a band, predicted/thrust_sigma while
        it has a band and a b (as predicted/thrust: no silent topic; the estimator's status
        value ``band`` says why there is none)."""
        band = self.core.band is not None
        self.speed_sigma_out = self.scalar_output_if(
            band, self.speed_sigma_out, contract.TOPIC_PREDICTED_SPEED_SIGMA)
        self.thrust_sigma_out = self.scalar_output_if(
            band and self.core.thrust_coefficient is not None, self.thrust_sigma_out,
            contract.TOPIC_PREDICTED_THRUST_SIGMA)

    def scalar_output_if(self, wanted: bool, out: ScalarOutput | None, topic: str) -> ScalarOutput | None:
        """``out`` kept, made or destroyed so that it exists exactly when ``wanted``."""
        if wanted and out is None:
            return ScalarOutput(self, topic)
        if not wanted and out is not None:
            self.destroy_publisher(out.publisher)
            return None
        return out

    def on_timer(self) -> None:
        self.publish_until(self.now_s() - self.output_delay_s)

    def count_late(self, t: float) -> None:
        """Count an input timed at or before a grid time already published (it arrived more
        than output_delay_s after its time): that prediction used the previous value, where
        ``replay`` uses this one."""
        if t <= self.ticks.next_s - self.ticks.period_s:
            self.late_inputs += 1

    def command_stale(self, t: float) -> bool:
        return (self.pwm_timeout_s > 0.0 and self.last_pwm_s is not None
                and t - self.last_pwm_s > self.pwm_timeout_s)

    def publish_until(self, t: float) -> None:
        """Predict and publish every output grid time up to ``t``."""
        if t < self.ticks.next_s:  # nothing due (most inputs): no list built
            return
        for tick in self.ticks.due(t):
            if self.command_stale(tick):
                self.stale_ticks += 1
                continue
            p = self.core.predict(tick)
            if p.ready:
                w = float(p.speed_rad_s)
                self.speed_out.publish(w)
                self.state_out.publish(tick, w)  # stamped with the grid time it answers
                if self.speed_sigma_out is not None and p.speed_sigma_rad_s is not None:
                    self.speed_sigma_out.publish(float(p.speed_sigma_rad_s))
                    if self.thrust_sigma_out is not None and p.thrust_sigma_n is not None:
                        self.thrust_sigma_out.publish(float(p.thrust_sigma_n))
                if self.thrust_out is not None and self.wrench_out is not None and p.thrust_n is not None:
                    thrust = float(p.thrust_n)
                    self.thrust_out.publish(thrust)
                    if self.wrench_out.listened:  # the torque only for someone who reads it
                        self.wrench_out.publish(tick, thrust, reaction_torque_nm(
                            self.torque_coefficient, w, self.spin_direction))

    def publish_diagnostics(self) -> None:
        statuses = list(self.core.status())
        statuses += wrench_status(self.torque_coefficient, self.wrench_out is not None)
        if self.health is not None:
            statuses.append(self.health.status())
        timing = counters(pwm_lost=self.pwm_stream.lost_messages,
                          pwm_publisher_restarts=self.pwm_stream.publisher_restarts,
                          stale_command_ticks=self.stale_ticks,
                          output_ticks_skipped=self.ticks.skipped,
                          inputs_after_their_grid_time=self.late_inputs)
        now = self.now_s()
        if self.command_stale(now) and self.last_pwm_s is not None:  # stale implies a pwm came once
            statuses.append(CoreStatus(
                'input', ERROR, f'no pwm for {now - self.last_pwm_s:.2f} s '
                f'(pwm_timeout_s {self.pwm_timeout_s:g}): not predicting', timing))
        elif self.pwm_stream.lost_messages:
            statuses.append(CoreStatus(
                'input', WARN, f'{self.pwm_stream.lost_messages} pwm commands lost in '
                'transport (the latest received is used)', timing))
        else:
            statuses.append(CoreStatus('input', OK, 'ok', timing))
        if not self.model_path:
            statuses.append(CoreStatus(
                'model', WARN, 'model missing, using first-principles fallback',
                {'model_path': ''}))
        if self.reload_error:
            statuses.append(CoreStatus(
                'model reload', WARN, self.reload_error, {'model_path': self.model_path}))
        self.diagnostics_pub.publish(diagnostic_array(self, statuses))

    def on_set_parameters(self, parameters: list[Parameter]) -> SetParametersResult:
        """Load a new model_path before accepting it; keep the last good model otherwise."""
        for p in parameters:
            if p.name != 'model_path':
                continue
            try:
                core = make_estimator(p.value, self.thrust_coefficient, self.adapt,
                                      self.get_fully_qualified_name())
                health = make_health(core, p.value, self.get_fully_qualified_name()) if self.health_on else None
            except BadInputError as e:
                self.reload_error = f'kept {self.model_path or "the fallback"}: {e}'
                self.get_logger().error(str(e))
                return SetParametersResult(successful=False, reason=str(e))
            self.core, self.model_path, self.reload_error = core, p.value, ''
            self.health = health  # a new model, a new monitor: what the old one named is forgotten
            self.match_thrust_output()
            self.match_band_output()
            self.get_logger().info(f'model: {p.value or "first-principles fallback"}')
        return SetParametersResult(successful=True)


def make_estimator(model_path: str, thrust_coefficient: float | None, adapt: bool = False,
                   node_name: str = THRUST_ESTIMATOR) -> ThrustEstimator:
    """The estimator core for a model file, or for the fallback when the path is empty; with
    ``adapt``, adapting (BadInputError naming the parameter for a model without physics)."""
    model = load_model(model_path) if model_path else fallback_model()
    adapter = None
    if adapt:
        from bldc_propulsion.core.adaptation import adapter_for
        from bldc_propulsion.core.health import require_physics

        require_physics(model, "adaptation", f"{node_name}: parameter adapt: model_path {model_path or '(empty)'}")

        try:
            adapter = adapter_for(model)
        except BadInputError as e:
            raise BadInputError(f"{node_name}: parameter adapt: model_path {model_path}: {e}") from None
    return ThrustEstimator(model, thrust_coefficient=thrust_coefficient, adapter=adapter)


def make_health(core: ThrustEstimator, model_path: str, node_name: str = THRUST_ESTIMATOR) -> HealthStream:
    """The health monitor on ``core``'s inputs; BadInputError naming the parameter for a model
    without physics (the fallback, a network)."""
    from bldc_propulsion.core.health import HealthStream, require_physics

    require_physics(core.model, "the health monitor",
                    f"{node_name}: parameter health: model_path {model_path or '(empty)'}")

    try:
        return HealthStream(core)
    except BadInputError as e:
        raise BadInputError(f"{node_name}: parameter health: model_path {model_path}: {e}") from None


def main(args: list[str] | None = None) -> int:
    return run_node(THRUST_ESTIMATOR, ThrustEstimatorNode, args)


if __name__ == '__main__':
    sys.exit(main())
