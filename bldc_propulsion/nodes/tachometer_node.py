"""tachometer: tachometer/adc batches (Float32MultiArray) -> rotor/speed, rotor/rpm.

Float32MultiArray has no header. A batch's samples are timed by counting (n samples follow the
previous batch's), and whether a batch really follows the previous one is decided from its
message info: sequence numbers show batches lost in transport, the publisher's timestamp shows
a publisher that skipped data (``stream_time.py``). Across any break the decoder measures
nothing, and ``SpeedOutput`` publishes nothing until a full revolution after it: every speed
published was measured on contiguous samples. rotor/speed and rotor/rpm are published once per
batch when there is such a speed (0 only when the rotor is known to stand still). A timer
watches for batches that stop coming altogether: diagnostics then say the input is lost, and
nothing is published (there is nothing to stand behind).

rotor/state (JointState, name[0] = joint_name) carries the same speeds stamped with the instant
each describes: the middle of the revolution it is the mean over (``tach_output``), which is
half a revolution before the batch that completed it; a 0 at the batch's last sample. Each
measurement is published once there (a speed repeated on rotor/speed until the next edge is
not new evidence for a consumer that fuses by time).
"""

from __future__ import annotations

import sys
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from std_msgs.msg import Float32MultiArray

from bldc_propulsion import contract
from bldc_propulsion.core.status import ERROR, OK, CoreStatus, counters
from bldc_propulsion.core.tach_output import SpeedOutput
from bldc_propulsion.core.tachometer import Samples, TachometerConfig, TachometerDecoder
from bldc_propulsion.nodes.common import (
    JointStateOutput,
    NodeClock,
    ScalarOutput,
    WithInfo,
    declare_parameters,
    diagnostic_array,
    input_qos,
    run_node,
    stamped_name,
)
from bldc_propulsion.nodes.params import (
    DIAGNOSTICS_PERIOD_S,
    TACH_TIMEOUT_CHECK_PERIOD_S,
    TACHOMETER,
    TACHOMETER_PARAMS,
    core_kwargs,
)
from bldc_propulsion.nodes.stream_time import NEW_STREAM, Placement, SampleStream, arrival


class TachometerNode(Node):

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(TACHOMETER, **kwargs)
        self.now_s = NodeClock(self)
        params = declare_parameters(self, TACHOMETER_PARAMS)
        config = TachometerConfig(**core_kwargs(TACHOMETER_PARAMS, params))
        self.core = TachometerDecoder(config)  # BadInputError if the core refuses a value
        self.output = SpeedOutput(self.core)
        self.stream: SampleStream[Samples] = SampleStream(params['sample_rate_hz'], params['clock_tolerance_s'],
                                                          params['use_source_timestamps'])
        self.timeout_s = params['timeout_s']
        self.last_receipt_s: float | None = None

        self.speed_out = ScalarOutput(self, contract.TOPIC_ROTOR_SPEED)
        self.rpm_out = ScalarOutput(self, contract.TOPIC_ROTOR_RPM)
        self.state_out = JointStateOutput(
            self, contract.TOPIC_ROTOR_STATE, stamped_name(self, 'joint_name', params['joint_name']))
        self.diagnostics_pub = self.create_publisher(
            DiagnosticArray, contract.TOPIC_DIAGNOSTICS_ABSOLUTE, 10)
        self.adc_sub = self.create_subscription(
            Float32MultiArray, contract.TOPIC_TACH_ADC, WithInfo(self.on_batch),
            input_qos(params['queue_depth']))
        self.timeout_timer = self.create_timer(TACH_TIMEOUT_CHECK_PERIOD_S, self.check_signal)
        self.diagnostics_timer = self.create_timer(DIAGNOSTICS_PERIOD_S, self.publish_diagnostics)

    def on_batch(self, msg: Float32MultiArray, info: dict | None) -> None:
        received = self.now_s()
        self.last_receipt_s = received
        data = msg.data
        t = self.stream.follow(received, info, len(data))  # the usual batch, cheaply
        if t is not None:
            self.decode_batch(t, data)
        else:
            self.decode(self.stream.push(arrival(received, info), len(data), data))

    def decode(self, settled: list[tuple[Placement, Samples]]) -> None:
        """Decode the batches the timing rules have placed; publish what may be published."""
        for place, data in settled:
            if place.event == NEW_STREAM and self.stream.streams > 1:
                self.core.reset()  # a restarted publisher: its samples do not follow the old
            self.decode_batch(place.t_last, data)

    def decode_batch(self, t_last: float, data: Samples) -> None:
        """Decode one batch whose last sample is at ``t_last`` (s, node clock); publish."""
        self.core.process_batch(t_last, data, result=False)  # state is enough
        speed = self.output.after_batch(t_last)
        if speed is not None:
            w = float(speed)
            self.speed_out.publish(w)
            self.rpm_out.publish(w * contract.RAD_S_TO_RPM)
            if self.output.fresh:
                self.state_out.publish(self.output.stamp_s, w)

    def input_lost(self) -> bool:
        """No batch for timeout_s on the node clock (publisher dead, link down)."""
        return (self.last_receipt_s is not None
                and self.now_s() - self.last_receipt_s > self.timeout_s)

    def check_signal(self) -> None:
        held = self.stream.holding
        if held is not None and self.now_s() - held.receipt_s > TACH_TIMEOUT_CHECK_PERIOD_S / 2:
            self.decode(self.stream.release_held())  # no successor came to vouch for it
        if self.input_lost():  # publish nothing; the next batch must first measure a revolution
            self.output.valid = False

    def publish_diagnostics(self) -> None:
        statuses = list(self.core.status())
        timing = {**self.stream.counters(), "batches_withheld": self.output.withheld}
        if self.input_lost() and self.last_receipt_s is not None:  # lost implies a batch came once
            statuses.append(CoreStatus(
                'input', ERROR,
                f'no tachometer/adc batch for {self.now_s() - self.last_receipt_s:.2f} s: '
                'nothing published', counters(**timing)))
        else:
            statuses.append(CoreStatus('input', OK, 'ok', counters(**timing)))
        self.diagnostics_pub.publish(diagnostic_array(self, statuses))


def main(args: list[str] | None = None) -> int:
    return run_node(TACHOMETER, TachometerNode, args)


if __name__ == '__main__':
    sys.exit(main())
