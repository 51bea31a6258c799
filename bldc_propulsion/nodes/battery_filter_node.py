"""battery_filter: battery/adc (Float64, volts at the ADC pin) -> battery/voltage (BatteryState).

Each sample is timed by the node clock at receipt (the message has no header), which under
``use_sim_time`` follows the recording's /clock; ``ReceiptClock`` smooths receipt jitter and
/clock steps onto the nominal 1/sample_rate_hz grid (parameter clock_tolerance_s). The core rejects
implausible samples (NaN, out of [min_adc_v, max_adc_v]) and counts them; diagnostics say so.
"""

import math
import sys

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data

from diagnostic_msgs.msg import DiagnosticArray
from sensor_msgs.msg import BatteryState
from std_msgs.msg import Float64

from bldc_propulsion import contract
from bldc_propulsion.core.battery_filter import BatteryFilter, BatteryFilterConfig
from bldc_propulsion.errors import BadInputError
from bldc_propulsion.nodes.common import declare_parameters, diagnostic_array, now_s, to_stamp
from bldc_propulsion.nodes.params import (
    BATTERY_FILTER, BATTERY_FILTER_PARAMS, DIAGNOSTICS_PERIOD_S, ReceiptClock, core_kwargs)


class BatteryFilterNode(Node):

    def __init__(self, **kwargs):
        super().__init__(BATTERY_FILTER, **kwargs)
        params = declare_parameters(self, BATTERY_FILTER_PARAMS)
        config = BatteryFilterConfig(**core_kwargs(BATTERY_FILTER_PARAMS, params))
        self.core = BatteryFilter(config)  # BadInputError if the core refuses a value
        self.period_s = 1.0 / params['sample_rate_hz']
        self.sample_time = ReceiptClock(params['clock_tolerance_s'])
        self.decimation = params['publish_decimation']
        self.accepted = 0

        self.voltage_pub = self.create_publisher(BatteryState, contract.TOPIC_BATTERY_VOLTAGE, 10)
        self.diagnostics_pub = self.create_publisher(
            DiagnosticArray, contract.TOPIC_DIAGNOSTICS, 10)
        self.adc_sub = self.create_subscription(
            Float64, contract.TOPIC_BATTERY_ADC, self.on_adc, qos_profile_sensor_data)
        self.diagnostics_timer = self.create_timer(DIAGNOSTICS_PERIOD_S, self.publish_diagnostics)

    def on_adc(self, msg):
        t = self.sample_time(now_s(self), self.period_s)
        volts = self.core.update(t, msg.data)
        if volts is None:
            return
        self.accepted += 1
        if self.accepted % self.decimation == 0:
            self.voltage_pub.publish(battery_state(t, volts))

    def publish_diagnostics(self):
        self.diagnostics_pub.publish(diagnostic_array(self, self.core.status()))


def battery_state(t_s, volts):
    """BatteryState with the filtered voltage; every field we do not measure says 'unknown'."""
    msg = BatteryState()
    msg.header.stamp = to_stamp(t_s)
    msg.voltage = float(volts)
    msg.temperature = math.nan
    msg.current = math.nan
    msg.charge = math.nan
    msg.capacity = math.nan
    msg.design_capacity = math.nan
    msg.percentage = math.nan
    msg.power_supply_status = BatteryState.POWER_SUPPLY_STATUS_UNKNOWN
    msg.power_supply_health = BatteryState.POWER_SUPPLY_HEALTH_UNKNOWN
    msg.power_supply_technology = BatteryState.POWER_SUPPLY_TECHNOLOGY_UNKNOWN
    msg.present = True
    return msg


def main(args=None):
    rclpy.init(args=args)
    node = None
    try:
        node = BatteryFilterNode()
        rclpy.spin(node)
    except BadInputError as e:  # a parameter the core refuses
        print(f'battery_filter: {e}', file=sys.stderr)
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
