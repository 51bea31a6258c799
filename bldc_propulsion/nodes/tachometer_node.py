"""tachometer: tachometer/adc batches (Float32MultiArray) -> rotor/speed, rotor/rpm.

Float32MultiArray has no header, so a batch's time (the time of its last sample) is the node
clock when the batch is received, which under ``use_sim_time`` follows the recording's /clock;
``ReceiptClock`` smooths receipt jitter and /clock steps onto the batches' nominal duration
(n samples / sample_rate_hz; parameter clock_tolerance_s). rotor/speed and rotor/rpm are
published once per batch with the core's latest estimate. A timer also asks the core whether
batches stopped coming altogether, so that a dead input still reports speed 0 (published once,
when the loss is declared) and signal loss on diagnostics.
"""

import sys

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data

from diagnostic_msgs.msg import DiagnosticArray
from std_msgs.msg import Float32MultiArray, Float64

from bldc_propulsion import contract
from bldc_propulsion.core.tachometer import TachometerConfig, TachometerDecoder
from bldc_propulsion.errors import BadInputError
from bldc_propulsion.nodes.common import declare_parameters, diagnostic_array, now_s
from bldc_propulsion.nodes.params import (
    DIAGNOSTICS_PERIOD_S, TACH_TIMEOUT_CHECK_PERIOD_S, TACHOMETER, TACHOMETER_PARAMS,
    ReceiptClock, core_kwargs)


class TachometerNode(Node):

    def __init__(self, **kwargs):
        super().__init__(TACHOMETER, **kwargs)
        params = declare_parameters(self, TACHOMETER_PARAMS)
        config = TachometerConfig(**core_kwargs(TACHOMETER_PARAMS, params))
        self.core = TachometerDecoder(config)  # BadInputError if the core refuses a value
        self.sample_period_s = 1.0 / params['sample_rate_hz']
        self.batch_time = ReceiptClock(params['clock_tolerance_s'])

        self.speed_pub = self.create_publisher(Float64, contract.TOPIC_ROTOR_SPEED, 10)
        self.rpm_pub = self.create_publisher(Float64, contract.TOPIC_ROTOR_RPM, 10)
        self.diagnostics_pub = self.create_publisher(
            DiagnosticArray, contract.TOPIC_DIAGNOSTICS, 10)
        self.adc_sub = self.create_subscription(
            Float32MultiArray, contract.TOPIC_TACH_ADC, self.on_batch, qos_profile_sensor_data)
        self.timeout_timer = self.create_timer(TACH_TIMEOUT_CHECK_PERIOD_S, self.check_signal)
        self.diagnostics_timer = self.create_timer(DIAGNOSTICS_PERIOD_S, self.publish_diagnostics)

    def on_batch(self, msg):
        t_last = self.batch_time(now_s(self), len(msg.data) * self.sample_period_s)
        out = self.core.process_batch(t_last, msg.data)
        self.publish_speed(out.speed_now)

    def check_signal(self):
        if self.core.check_timeout(now_s(self)):  # True once, when the input has gone silent
            self.publish_speed(0.0)

    def publish_speed(self, speed_rad_s):
        self.speed_pub.publish(Float64(data=float(speed_rad_s)))
        self.rpm_pub.publish(Float64(data=float(speed_rad_s) * contract.RAD_S_TO_RPM))

    def publish_diagnostics(self):
        self.diagnostics_pub.publish(diagnostic_array(self, self.core.status()))


def main(args=None):
    rclpy.init(args=args)
    node = None
    try:
        node = TachometerNode()
        rclpy.spin(node)
    except BadInputError as e:  # a parameter the core refuses
        print(f'tachometer: {e}', file=sys.stderr)
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
