"""battery_filter: battery/adc (Float64, volts at the ADC pin) -> battery/voltage (BatteryState).

The samples carry no stamp: they are timed by counting at sample_rate_hz from the stream's
first sample (``stream_time.SampleStream``); lost samples (sequence numbers) advance the count,
and a publisher that restarts or drifts from the node clock by more than a second starts the
count over. The filter's time constant is 2 s, so a sample timed a few milliseconds off changes
nothing; what matters is that a gap is not bridged as if it were one step. The core rejects
implausible samples (NaN, out of [min_adc_v, max_adc_v]) and counts them; diagnostics say so.
battery/voltage is published at publish_rate_hz (sample time); header.stamp is the time of the
sample. Runs on rclpy's EventsExecutor (cheapest), like the other nodes.
"""

from __future__ import annotations

import math
import sys
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from sensor_msgs.msg import BatteryState
from std_msgs.msg import Float64

from bldc_propulsion import contract
from bldc_propulsion.core.battery_filter import BatteryFilter, BatteryFilterConfig
from bldc_propulsion.core.status import counters
from bldc_propulsion.core.ticker import Ticker
from bldc_propulsion.nodes.common import (
    NodeClock,
    WithInfo,
    declare_parameters,
    diagnostic_array,
    input_qos,
    run_node,
    to_stamp,
)
from bldc_propulsion.nodes.params import BATTERY_FILTER, BATTERY_FILTER_PARAMS, DIAGNOSTICS_PERIOD_S, core_kwargs
from bldc_propulsion.nodes.stream_time import NEW_STREAM, Placement, SampleStream, arrival


class BatteryFilterNode(Node):

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(BATTERY_FILTER, **kwargs)
        self.now_s = NodeClock(self)
        params = declare_parameters(self, BATTERY_FILTER_PARAMS)
        config = BatteryFilterConfig(**core_kwargs(BATTERY_FILTER_PARAMS, params))
        self.core = BatteryFilter(config)  # BadInputError if the core refuses a value
        self.stream: SampleStream[float] = SampleStream(params['sample_rate_hz'], params['clock_tolerance_s'],
                                                        params['use_source_timestamps'])
        self.output = Ticker(params['publish_rate_hz'])

        self.voltage_pub = self.create_publisher(BatteryState, contract.TOPIC_BATTERY_VOLTAGE, 10)
        self.diagnostics_pub = self.create_publisher(
            DiagnosticArray, contract.TOPIC_DIAGNOSTICS_ABSOLUTE, 10)
        self.adc_sub = self.create_subscription(
            Float64, contract.TOPIC_BATTERY_ADC, WithInfo(self.on_adc),
            input_qos(params['queue_depth']))
        self.diagnostics_timer = self.create_timer(DIAGNOSTICS_PERIOD_S, self.publish_diagnostics)

    def on_adc(self, msg: Float64, info: dict | None) -> None:
        received = self.now_s()
        t = self.stream.follow(received, info, 1)  # the usual sample, cheaply (1 kHz)
        if t is not None:
            self.filter_sample(t, msg.data)
        else:
            self.filter(self.stream.push(arrival(received, info), 1, msg.data))

    def filter(self, settled: list[tuple[Placement, float]]) -> None:
        for place, value in settled:
            if place.event == NEW_STREAM and self.stream.streams > 1:
                self.core.reset()  # restarted publisher or resync: the count starts over
            self.filter_sample(place.t_last, value)

    def filter_sample(self, t: float, value: float) -> None:
        """Filter one sample placed at ``t`` (s, node clock); publish when the rate is due."""
        volts = self.core.update(t, value)
        if volts is not None and self.output.take(t):
            self.voltage_pub.publish(battery_state(t, volts))

    def publish_diagnostics(self) -> None:
        self.filter(self.stream.release_held())  # a last sample nobody followed
        statuses = self.core.status()
        statuses[0].values.update(counters(**self.stream.counters()))
        self.diagnostics_pub.publish(diagnostic_array(self, statuses))


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


def main(args: list[str] | None = None) -> int:
    return run_node(BATTERY_FILTER, BatteryFilterNode, args)


if __name__ == '__main__':
    sys.exit(main())
