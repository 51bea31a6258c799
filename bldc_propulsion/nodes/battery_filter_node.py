"""battery_filter: battery/adc (Float64, volts at the ADC pin) -> battery/voltage (BatteryState).

The samples carry no stamp: they are timed by counting at sample_rate_hz from the stream's
first sample (``stream_time.SampleStream``); lost samples (sequence numbers) advance the count,
and a publisher that restarts or drifts from the node clock by more than a second starts the
count over. The filter's time constant is 2 s, so a sample timed a few milliseconds off changes
nothing; what matters is that a gap is not bridged as if it were one step. The core rejects
implausible samples (NaN, out of [min_adc_v, max_adc_v]) and counts them; diagnostics say so.
battery/voltage is published at publish_rate_hz (sample time); header.stamp is the time of the
sample. Samples that cannot make an output due wait in a queue and are filtered together when
one can (``BatteryFilterNode.on_adc``: the same outputs, less CPU). Runs on rclpy's
EventsExecutor (cheapest), like the other nodes.
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
        #: samples received and not yet placed: (receipt time, message info, volts)
        self.queue: list[tuple[float, dict | None, float]] = []
        self.next_seq: int | None = None  #: the sequence number that follows the queue

        self.voltage_pub = self.create_publisher(BatteryState, contract.TOPIC_BATTERY_VOLTAGE, 10)
        self.diagnostics_pub = self.create_publisher(
            DiagnosticArray, contract.TOPIC_DIAGNOSTICS_ABSOLUTE, 10)
        self.adc_sub = self.create_subscription(
            Float64, contract.TOPIC_BATTERY_ADC, WithInfo(self.on_adc),
            input_qos(params['queue_depth']))
        self.diagnostics_timer = self.create_timer(DIAGNOSTICS_PERIOD_S, self.publish_diagnostics)

    def on_adc(self, msg: Float64, info: dict | None) -> None:
        """Queue the sample; place and filter the queue when an output may fall due.

        Why a queue: at 1 kHz, placing and filtering each sample in its own callback, which
        wakes with cold caches, costs about three times the same work done in a loop. A sample
        that follows the queue (the next sequence number), whose counted time if it follows
        (``SampleStream.counted_t``) and whose receipt are both before the next output time,
        cannot make an output due: it waits. (Receipt too: a message placed as late goes where
        it was observed less the latency floor, on the receipt clock not after its receipt.)
        Any other sample (a jump in sequence numbers, no message info, a stream not yet placed
        or holding a late message, an output time reached) places the whole queue in order,
        with exactly the calls each sample would have had alone: what is published, with which
        stamp and value, and after which input, is unchanged. Diagnostics place the queue
        first, so their counters are current."""
        received = self.now_s()
        queue = self.queue
        queue.append((received, info, msg.data))
        seq = info.get('publication_sequence_number') if info else None
        follows = seq is not None and seq == self.next_seq
        self.next_seq = None if seq is None else seq + 1
        if follows:
            due_s = self.output.next_s
            t = self.stream.counted_t(len(queue), 1)
            if t is not None and t < due_s and received < due_s:
                return
        self.place_queue()

    def place_queue(self) -> None:
        """Place and filter the queued samples in order (see :meth:`on_adc`)."""
        queue, self.queue = self.queue, []
        stream = self.stream
        for received, info, value in queue:
            t = stream.follow(received, info, 1)  # the usual sample, cheaply
            if t is not None:
                self.filter_sample(t, value)
            else:
                self.filter(stream.push(arrival(received, info), 1, value))

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
        self.place_queue()
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
