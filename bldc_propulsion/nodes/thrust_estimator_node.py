"""thrust_estimator: pwm + battery/voltage -> predicted/speed, predicted/thrust on a timer.

The PWM command is timed by the node clock at receipt (Float64 has no header); the battery
voltage by its header stamp (the time of the filtered sample). The timer runs on the node clock
at output_rate_hz, so under ``use_sim_time`` it follows the recording.

model_path '' uses the first-principles fallback and says so on diagnostics (WARN). A model
file that does not load stops the node at start (one-line error, exit status 2); changed at run
time (``ros2 param set``), such a file is refused and the last good model kept.
"""

import sys

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data

from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import SetParametersResult
from sensor_msgs.msg import BatteryState
from std_msgs.msg import Float64

from bldc_propulsion import contract
from bldc_propulsion.core.estimator import ThrustEstimator, fallback_model
from bldc_propulsion.core.status import WARN, CoreStatus
from bldc_propulsion.errors import BadInputError
from bldc_propulsion.model import load_model
from bldc_propulsion.nodes.common import (
    declare_parameters, diagnostic_array, now_s, stamp_s)
from bldc_propulsion.nodes.params import (
    DIAGNOSTICS_PERIOD_S, THRUST_ESTIMATOR, THRUST_ESTIMATOR_PARAMS)


class ThrustEstimatorNode(Node):

    def __init__(self, **kwargs):
        super().__init__(THRUST_ESTIMATOR, **kwargs)
        params = declare_parameters(self, THRUST_ESTIMATOR_PARAMS)
        self.thrust_coefficient = params['thrust_coefficient'] or None
        self.model_path = params['model_path']
        self.core = make_estimator(self.model_path, self.thrust_coefficient)  # BadInputError
        self.reload_error = ''

        self.speed_pub = self.create_publisher(Float64, contract.TOPIC_PREDICTED_SPEED, 10)
        self.thrust_pub = self.create_publisher(Float64, contract.TOPIC_PREDICTED_THRUST, 10)
        self.diagnostics_pub = self.create_publisher(
            DiagnosticArray, contract.TOPIC_DIAGNOSTICS, 10)
        self.pwm_sub = self.create_subscription(
            Float64, contract.TOPIC_PWM, self.on_pwm, qos_profile_sensor_data)
        self.voltage_sub = self.create_subscription(
            BatteryState, contract.TOPIC_BATTERY_VOLTAGE, self.on_voltage,
            qos_profile_sensor_data)
        self.output_timer = self.create_timer(
            1.0 / params['output_rate_hz'], self.publish_prediction)
        self.diagnostics_timer = self.create_timer(DIAGNOSTICS_PERIOD_S, self.publish_diagnostics)
        self.add_on_set_parameters_callback(self.on_set_parameters)

    def on_pwm(self, msg):
        self.core.update_pwm(now_s(self), msg.data)

    def on_voltage(self, msg):
        self.core.update_voltage(stamp_s(msg.header.stamp), msg.voltage)

    def publish_prediction(self):
        p = self.core.predict(now_s(self))
        if not p.ready:
            return  # no PWM command yet: nothing to predict from
        self.speed_pub.publish(Float64(data=float(p.speed_rad_s)))
        self.thrust_pub.publish(Float64(data=float(p.thrust_n)))

    def publish_diagnostics(self):
        statuses = list(self.core.status())
        if not self.model_path:
            statuses.append(CoreStatus(
                'model', WARN, 'model missing, using first-principles fallback',
                {'model_path': ''}))
        if self.reload_error:
            statuses.append(CoreStatus(
                'model reload', WARN, self.reload_error, {'model_path': self.model_path}))
        self.diagnostics_pub.publish(diagnostic_array(self, statuses))

    def on_set_parameters(self, parameters):
        """Load a new model_path before accepting it; keep the last good model otherwise."""
        for p in parameters:
            if p.name != 'model_path':
                continue
            try:
                core = make_estimator(p.value, self.thrust_coefficient)
            except BadInputError as e:
                self.reload_error = f'kept {self.model_path or "the fallback"}: {e}'
                self.get_logger().error(str(e))
                return SetParametersResult(successful=False, reason=str(e))
            self.core, self.model_path, self.reload_error = core, p.value, ''
            self.get_logger().info(f'model: {p.value or "first-principles fallback"}')
        return SetParametersResult(successful=True)


def make_estimator(model_path, thrust_coefficient):
    """The estimator core for a model file, or for the fallback when the path is empty."""
    model = load_model(model_path) if model_path else fallback_model()
    return ThrustEstimator(model, thrust_coefficient=thrust_coefficient)


def main(args=None):
    rclpy.init(args=args)
    node = None
    try:
        node = ThrustEstimatorNode()
        rclpy.spin(node)
    except BadInputError as e:
        print(f'thrust_estimator: {e}', file=sys.stderr)
        return 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
