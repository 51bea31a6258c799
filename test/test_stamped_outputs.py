"""The stamped outputs (rotor/state, predicted/state, predicted/wrench) on a simulated chirp.

The nodes run in-process on real rclpy; a helper node publishes the recording's messages to them
over DDS in time order, driving /clock (use_sim_time) and waiting until the node has taken each
message, with stamp-less inputs timed on receipt (use_source_timestamps false), so the nodes see
exactly the recording's times (shifted by T0) and nothing depends on the machine's speed.

- rotor/state against the simulator's truth at each stamp: as good as the offline loader
  (``load_signals``), and far better than the same speeds at the time they were published;
- predicted/state equal to ``replay``'s at the same stamps (1e-6 rad/s) from the same inputs;
- names, frame and the reaction torque's size and sign; a model that does not know its torque
  says so, one without a thrust coefficient advertises no wrench.
"""

from __future__ import annotations

import array
import math

import numpy as np
import pytest

from _ros import require_rclpy

rclpy = require_rclpy()

from builtin_interfaces.msg import Time as TimeMsg  # noqa: E402
from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from geometry_msgs.msg import WrenchStamped  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from sensor_msgs.msg import BatteryState, JointState  # noqa: E402
from std_msgs.msg import Float32MultiArray, Float64  # noqa: E402

from _models import good_model  # noqa: E402
from bldc_propulsion import contract as c  # noqa: E402
from bldc_propulsion.bagio import TYPESTORE, open_recording  # noqa: E402
from bldc_propulsion.core.tach_output import revolution_middle  # noqa: E402
from bldc_propulsion.errors import BadInputError  # noqa: E402
from bldc_propulsion.model import save_model  # noqa: E402
from bldc_propulsion.nodes.tachometer_node import TachometerNode  # noqa: E402
from bldc_propulsion.nodes.thrust_estimator_node import ThrustEstimatorNode  # noqa: E402
from bldc_propulsion.physics.fallback import fallback_model  # noqa: E402
from bldc_propulsion.recordings import load_signals  # noqa: E402
from bldc_propulsion.replay import replay_bag  # noqa: E402
from bldc_propulsion.sim import simulate  # noqa: E402
from bldc_propulsion.sim.record import write_sim_bag  # noqa: E402
from bldc_propulsion.stamped_writer import StampedWriter, joint_state, wrench_stamped  # noqa: E402

T0_NS = 100 * 10**9  #: node clock at the recording's start (s = 100): recording times + T0
DURATION_S = 7.0


@pytest.fixture(scope="module")
def chirp(tmp_path_factory):
    """A chirp recording (1 s at rest, then the paper's noisy chirp) and its replay."""
    d = tmp_path_factory.mktemp("stamped")
    write_sim_bag(simulate("chirp", DURATION_S, seed=11), d / "chirp")
    replay_bag(d / "chirp", d / "replay")
    return d


def ns_of(stamp: TimeMsg) -> int:
    return stamp.sec * 10**9 + stamp.nanosec


def stamp_of(ns: int) -> TimeMsg:
    return TimeMsg(sec=ns // 10**9, nanosec=ns % 10**9)


def rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


# --- rotor/state -----------------------------------------------------------------------------

def test_revolution_middle_is_half_a_revolution_before_its_end():
    assert revolution_middle(1.0, math.pi) == pytest.approx(0.0)  # 2 s revolution ending at 1 s
    np.testing.assert_allclose(revolution_middle(np.array([2.0, 3.0]), np.array([100.0, 50.0])),
                               [2.0 - math.pi / 100.0, 3.0 - math.pi / 50.0])


def test_rotor_state_is_stamped_at_the_instant_it_describes(chirp, start_node):
    d = chirp
    f = start_node(TachometerNode, joint_name="motor0_rotor")
    f.record(JointState, c.TOPIC_ROTOR_STATE)
    f.record(Float64, c.TOPIC_ROTOR_SPEED)
    f.publisher(Float32MultiArray, c.TOPIC_TACH_ADC)
    with open_recording(d / "chirp") as rec:
        batches = [(ns, msg.data) for _, ns, _, msg in _raw_messages(rec, c.TOPIC_TACH_ADC)]
        t0_ns = rec.t0_ns
        truth_t, truth = rec.scalars(c.TOPIC_TRUTH_SPEED)
    for ns, data in batches:
        t = T0_NS + ns - t0_ns
        msg = Float32MultiArray(data=array.array("f", np.asarray(data, np.float32).tobytes()))
        f.send(c.TOPIC_TACH_ADC, msg, t * 1e-9,
               taken=lambda t=t: f.node.last_receipt_s is not None
               and f.node.last_receipt_s >= t * 1e-9 - 1e-9)
    f.drain()
    f.close()
    states = f.received[c.TOPIC_ROTOR_STATE]
    assert states and all(list(m.name) == ["motor0_rotor"] for m in states)
    assert all(len(m.velocity) == 1 and not len(m.position) and not len(m.effort) for m in states)
    stamp = np.array([(ns_of(m.header.stamp) - T0_NS) * 1e-9 for m in states])
    live = np.array([m.velocity[0] for m in states])
    assert np.all(np.diff(stamp) > 0), "each measurement once, in time order"
    assert np.max(live) > 300.0  # the chirp spun the rotor up

    # the same measurements replay writes (the node's placement = the recording's times)
    with open_recording(d / "replay") as rec:
        ref = [(ns_of(m.header.stamp) - rec.t0_ns, m.velocity[0])
               for _, _, m in rec.messages([c.TOPIC_ROTOR_STATE])]
        speed_t, speed = rec.scalars(c.TOPIC_ROTOR_SPEED)  # bag time = when it was published
    assert len(ref) == len(states)
    np.testing.assert_allclose(stamp, [r[0] * 1e-9 for r in ref], atol=1e-6)
    np.testing.assert_allclose(live, [r[1] for r in ref], rtol=1e-6)

    # against the truth: as good as the offline loader's placement, better than at receipt
    live_err = rms(live - np.interp(stamp, truth_t, truth))
    sig = load_signals(d / "chirp")
    offline_err = rms(sig.speed - np.interp(sig.t, truth_t, truth))
    receipt_err = rms(speed - np.interp(speed_t, truth_t, truth))
    print(f"rotor speed RMS error vs truth: rotor/state at its stamp {live_err:.2f} rad/s, "
          f"offline loader {offline_err:.2f}, rotor/speed at its publication {receipt_err:.2f}")
    assert live_err <= 1.1 * offline_err
    assert live_err < 0.7 * receipt_err


def _raw_messages(rec, topic):
    """(topic, bag ns, connection, decoded message) of one topic, in time order."""
    for name, ns, conn, data in rec.raw([topic]):
        yield name, ns, conn, TYPESTORE.deserialize_cdr(data, conn.msgtype)


# --- predicted/state, predicted/wrench -------------------------------------------------------

def feed_estimator(d, start_node, until_s: float = math.inf, **params):
    """The estimator node fed the chirp's pwm and the battery/voltage replay published for it;
    returns its harness (closed) with predicted/state, predicted/wrench and diagnostics."""
    f = start_node(ThrustEstimatorNode, **params)
    f.record(JointState, c.TOPIC_PREDICTED_STATE)
    f.record(WrenchStamped, c.TOPIC_PREDICTED_WRENCH)
    f.record(DiagnosticArray, c.TOPIC_DIAGNOSTICS_ABSOLUTE)
    f.publisher(Float64, c.TOPIC_PWM)
    f.publisher(BatteryState, c.TOPIC_BATTERY_VOLTAGE)
    events = []
    with open_recording(d / "chirp") as rec:
        events += [(ns - rec.t0_ns, 0, msg.data) for _, ns, _, msg in _raw_messages(rec, c.TOPIC_PWM)]
    with open_recording(d / "replay") as rec:
        events += [(ns - rec.t0_ns, 1, msg.voltage)
                   for _, ns, _, msg in _raw_messages(rec, c.TOPIC_BATTERY_VOLTAGE)]
    events.sort(key=lambda e: e[:2])
    core = lambda: f.node.core  # noqa: E731 - the node may swap its core
    for rel_ns, kind, value in events:
        if rel_ns * 1e-9 > until_s:
            break
        t = T0_NS + rel_ns
        if kind == 0:
            n = f.node.pwm_stream.messages
            f.send(c.TOPIC_PWM, Float64(data=float(value)), t * 1e-9,
                   taken=lambda n=n: f.node.pwm_stream.messages > n)
        else:
            n = core().voltage_accepted + core().voltage_rejected_time
            msg = BatteryState(voltage=float(value))
            msg.header.stamp = stamp_of(t)
            f.send(c.TOPIC_BATTERY_VOLTAGE, msg, t * 1e-9,
                   taken=lambda n=n: core().voltage_accepted + core().voltage_rejected_time > n)
    last = f.node.get_clock().now().nanoseconds
    for k in range(1, 12):  # the output timer's last grid times, and a diagnostics message
        f.set_time((last + k * 100_000_000) * 1e-9)  # steps under the ticker's 1 s backlog limit
    f.spin_until(lambda: bool(f.received[c.TOPIC_DIAGNOSTICS_ABSOLUTE]))
    f.drain()
    f.close()
    return f


def test_predicted_state_equals_replay_at_the_same_stamps(chirp, start_node):
    d = chirp
    f = feed_estimator(d, start_node)
    with open_recording(d / "replay") as rec:
        ref = {ns_of(m.header.stamp) - rec.t0_ns: m.velocity[0]
               for _, _, m in rec.messages([c.TOPIC_PREDICTED_STATE])}
        ref_wrench = {ns_of(m.header.stamp) - rec.t0_ns: m.wrench
                      for _, _, m in rec.messages([c.TOPIC_PREDICTED_WRENCH])}
    end = max(ref) + 1000  # the node goes on predicting after the recording ends; replay stops
    live = {k: m for m in f.received[c.TOPIC_PREDICTED_STATE] if (k := ns_of(m.header.stamp) - T0_NS) <= end}
    by_us = {round(k * 1e-3): v for k, v in ref.items()}  # the same grid time within 1 us
    common = [k for k in live if round(k * 1e-3) in by_us]
    assert len(common) == len(live), "every live stamp is a grid time replay predicted"
    assert len(common) >= 0.99 * len(ref), (len(common), len(ref))
    err = np.array([live[k].velocity[0] - by_us[round(k * 1e-3)] for k in common])
    print(f"predicted/state live - replay over {len(common)} stamps: max {np.abs(err).max():.2e} rad/s")
    assert np.abs(err).max() <= 1e-6
    assert all(list(m.name) == [c.DEFAULT_JOINT_NAME] for m in live.values())
    assert max(m.velocity[0] for m in live.values()) > 300.0

    # the wrench: thrust b w^2 and the fallback's propeller torque, against the rotor's spin
    wrenches = [m for m in f.received[c.TOPIC_PREDICTED_WRENCH] if ns_of(m.header.stamp) - T0_NS <= end]
    assert len(wrenches) == len(live)
    model = fallback_model()
    w = np.array([live[ns_of(m.header.stamp) - T0_NS].velocity[0] for m in wrenches])
    np.testing.assert_allclose([m.wrench.force.z for m in wrenches], model.thrust_coefficient * w * w,
                               rtol=1e-9)
    np.testing.assert_allclose([m.wrench.torque.z for m in wrenches], -model.torque_coefficient * w * w,
                               rtol=1e-9, atol=1e-15)
    assert all(m.header.frame_id == c.DEFAULT_FRAME_ID for m in wrenches)
    by_us_w = {round(k * 1e-3): v for k, v in ref_wrench.items()}
    for m in wrenches[::50]:
        r = by_us_w[round((ns_of(m.header.stamp) - T0_NS) * 1e-3)]
        assert m.wrench.torque.z == pytest.approx(r.torque.z, rel=1e-6, abs=1e-12)
        assert m.wrench.force.z == pytest.approx(r.force.z, rel=1e-6)


def test_names_frame_and_spin_direction(chirp, start_node):
    until = 2.5  # s of recording: the rotor is turning from ~1.1 s
    f = feed_estimator(chirp, start_node, until_s=until, joint_name="motor3_rotor",
                       frame_id="motor3/rotor", spin_direction=-1)
    states = f.received[c.TOPIC_PREDICTED_STATE]
    wrenches = f.received[c.TOPIC_PREDICTED_WRENCH]
    assert states and all(list(m.name) == ["motor3_rotor"] for m in states)
    assert wrenches and all(m.header.frame_id == "motor3/rotor" for m in wrenches)
    w = {ns_of(m.header.stamp): m.velocity[0] for m in states}
    kq = fallback_model().torque_coefficient
    turning = [m for m in wrenches if w[ns_of(m.header.stamp)] > 100.0]
    assert turning
    # clockwise seen from above: the body is pushed counter-clockwise, torque.z > 0
    for m in turning:
        assert m.wrench.torque.z == pytest.approx(kq * w[ns_of(m.header.stamp)] ** 2, rel=1e-9)
    # the diagnostics raise nothing about the torque: the fallback knows it
    assert not any("wrench" in s.name for m in f.received[c.TOPIC_DIAGNOSTICS_ABSOLUTE] for s in m.status)


def test_a_network_model_publishes_torque_0_and_says_so(chirp, start_node, tmp_path):
    path = tmp_path / "net.npz"
    save_model(good_model(), path)  # a network with a thrust coefficient: no torque known
    f = feed_estimator(chirp, start_node, until_s=2.0, model_path=str(path))
    wrenches = f.received[c.TOPIC_PREDICTED_WRENCH]
    assert wrenches and all(m.wrench.torque.z == 0.0 for m in wrenches)
    assert any(m.wrench.force.z > 0.0 for m in wrenches)
    notes = [s for m in f.received[c.TOPIC_DIAGNOSTICS_ABSOLUTE] for s in m.status if s.name.endswith(": wrench")]
    assert notes and notes[-1].level == b"\x01" and "torque" in notes[-1].message


def test_no_wrench_without_a_thrust_coefficient_and_a_bad_spin_direction_is_refused(context, tmp_path):
    path = tmp_path / "no_b.npz"
    model = good_model()
    model.thrust_coefficient = None
    save_model(model, path)
    node = ThrustEstimatorNode(context=context, parameter_overrides=[
        Parameter("model_path", value=str(path))])
    try:
        assert node.wrench_out is None and node.thrust_out is None
        topics = dict(node.get_publisher_names_and_types_by_node(node.get_name(), node.get_namespace()))
        assert "/" + c.TOPIC_PREDICTED_STATE in topics
        assert "/" + c.TOPIC_PREDICTED_WRENCH not in topics
    finally:
        node.destroy_node()
    with pytest.raises(BadInputError, match="spin_direction must be 1 .* or -1"):
        ThrustEstimatorNode(context=context, parameter_overrides=[Parameter("spin_direction", value=0)])
    with pytest.raises(BadInputError, match="parameter joint_name: must not be empty"):
        TachometerNode(context=context, parameter_overrides=[Parameter("joint_name", value=" ")])


# --- replay's bytes ----------------------------------------------------------------------------

def test_replay_writes_the_bytes_the_typestore_makes(tmp_path):
    """StampedWriter patches templates: each message must be what serialize_cdr makes."""

    class Bag:
        t0_ns = 1_767_225_600 * 10**9

        def __init__(self):
            self.out = []

        def write_raw(self, topic, msgtype, t, data):
            self.out.append((topic, msgtype, t, data))

    bag = Bag()
    writer = StampedWriter(bag, "motor1/rotor/state", "motor1/predicted/state", "motor1/predicted/wrench",
                           joint_name="motor1_rotor", frame_id="motor1/rotor")
    writer.rotor_state(2.0, 1.987654321, 412.5)
    writer.prediction(2.01, 400.25, 4.5, -0.0875)
    writer.prediction(2.02, 0.0, None, 0.0)
    ns = lambda t: bag.t0_ns + int(round(t * 1e9))  # noqa: E731
    ser = TYPESTORE.serialize_cdr
    expected = [
        ("motor1/rotor/state", c.JOINT_STATE, 2.0,
         ser(joint_state("motor1_rotor", *divmod(ns(1.987654321), 10**9), 412.5), c.JOINT_STATE)),
        ("motor1/predicted/state", c.JOINT_STATE, 2.01,
         ser(joint_state("motor1_rotor", *divmod(ns(2.01), 10**9), 400.25), c.JOINT_STATE)),
        ("motor1/predicted/wrench", c.WRENCH_STAMPED, 2.01,
         ser(wrench_stamped("motor1/rotor", *divmod(ns(2.01), 10**9), 4.5, -0.0875), c.WRENCH_STAMPED)),
        ("motor1/predicted/state", c.JOINT_STATE, 2.02,
         ser(joint_state("motor1_rotor", *divmod(ns(2.02), 10**9), 0.0), c.JOINT_STATE)),
    ]
    assert [(a, b, t, bytes(x)) for a, b, t, x in expected] == bag.out
