"""The rclpy nodes in-process on ROS 2 Jazzy (CI fails without rclpy; elsewhere skipped).

Every test drives time through /clock (use_sim_time), as ``ros2 bag play --clock`` does, and
times stamp-less inputs on receipt (use_source_timestamps false: the helper publishes whenever
the node has answered, not at the data's rate), so the nodes see exactly the synthetic times and
nothing depends on the machine's speed (the ``start_node`` fixture: conftest.py, _ros.NodeHarness).
test_nodes_live.py runs them as processes in real time.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from _ros import require_rclpy

rclpy = require_rclpy()

from builtin_interfaces.msg import Time as TimeMsg  # noqa: E402
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from sensor_msgs.msg import BatteryState  # noqa: E402
from std_msgs.msg import Float32MultiArray, Float64  # noqa: E402

from bldc_propulsion import contract  # noqa: E402
from bldc_propulsion.errors import BadInputError  # noqa: E402
from bldc_propulsion.nodes.all_in_one import build_nodes  # noqa: E402
from bldc_propulsion.nodes.battery_filter_node import BatteryFilterNode  # noqa: E402
from bldc_propulsion.nodes.tachometer_node import TachometerNode  # noqa: E402
from bldc_propulsion.nodes.thrust_estimator_node import ThrustEstimatorNode, main  # noqa: E402

T0 = 100.0  # s, start of the synthetic recording


def statuses(harness):
    return [s for msg in harness.received[contract.TOPIC_DIAGNOSTICS] for s in msg.status]


def estimator_inputs(h, voltage_v=12.0):
    """The estimator's input publishers, and the pack's voltage at T0 (before any command)."""
    h.publisher(Float64, contract.TOPIC_PWM)
    h.publisher(BatteryState, contract.TOPIC_BATTERY_VOLTAGE)
    voltage = BatteryState(voltage=voltage_v, present=True)
    voltage.header.stamp = TimeMsg(sec=int(T0), nanosec=0)
    h.send(contract.TOPIC_BATTERY_VOLTAGE, voltage, T0)


# --- tachometer ---

def tach_signal(speed_rad_s, rate_hz, n, t0, blades=2, high=3.0, low=0.2, duty=0.15):
    """Phototransistor voltage: high, low while a blade cuts the beam (duty of each passage)."""
    t = t0 + np.arange(n) / rate_hz
    phase = (t * speed_rad_s / (2 * math.pi) * blades) % 1.0  # blade passages
    return np.where(phase < duty, low, high).astype(np.float32)


def test_tachometer_measures_a_known_speed_and_reports_loss(start_node):
    h = start_node(TachometerNode)
    h.record(Float64, contract.TOPIC_ROTOR_SPEED)
    h.record(Float64, contract.TOPIC_ROTOR_RPM)
    h.record(DiagnosticArray, contract.TOPIC_DIAGNOSTICS)
    h.publisher(Float32MultiArray, contract.TOPIC_TACH_ADC)
    rate, batch, speed = 20000.0, 200, 600.0
    signal = tach_signal(speed, rate, 60 * batch, T0)
    first_revolution = 2  # 5 edges (a revolution, 10.5 ms at 600 rad/s) need 2 batches
    for k in range(60):  # 0.6 s of batches, time of the last sample of each
        t_last = T0 + ((k + 1) * batch - 1) / rate
        msg = Float32MultiArray(data=signal[k * batch:(k + 1) * batch].tolist())
        expect = (contract.TOPIC_ROTOR_SPEED, contract.TOPIC_ROTOR_RPM) \
            if k >= first_revolution else ()
        h.send(contract.TOPIC_TACH_ADC, msg, t_last, expect=expect)
    speeds = [m.data for m in h.received[contract.TOPIC_ROTOR_SPEED]]
    rpms = [m.data for m in h.received[contract.TOPIC_ROTOR_RPM]]
    assert 60 - first_revolution <= len(speeds) == len(rpms) <= 60 - 1
    assert all(s == pytest.approx(speed, rel=0.01) for s in speeds)
    assert rpms == pytest.approx([s * 60.0 / (2.0 * math.pi) for s in speeds], rel=1e-9)

    # no more batches: nothing more is published (nothing to stand behind), and
    # diagnostics say the input is lost
    n_out = len(speeds)
    t_end = T0 + 60 * batch / rate
    for step in range(1, 31):
        h.set_time(t_end + 0.1 * step)
        for _ in range(3):
            h.executor.spin_once(timeout_sec=0.005)
    assert len(h.received[contract.TOPIC_ROTOR_SPEED]) == n_out
    last = statuses(h)[-2:]
    assert any(s.level == DiagnosticStatus.ERROR and "no tachometer/adc batch" in s.message
               for s in last), last
    assert all(s.name.startswith("tachometer: ") for s in statuses(h))
    assert all(s.hardware_id == "motor" for s in statuses(h))


# --- battery filter ---

def test_battery_filter_undoes_the_divider_and_reports_rejected_samples(start_node):
    h = start_node(BatteryFilterNode, publish_rate_hz=1000.0)
    h.record(BatteryState, contract.TOPIC_BATTERY_VOLTAGE)
    h.record(DiagnosticArray, contract.TOPIC_DIAGNOSTICS)
    h.publisher(Float64, contract.TOPIC_BATTERY_ADC)
    adc = 6.2
    t = T0
    for _ in range(300):
        t += 0.001
        h.send(contract.TOPIC_BATTERY_ADC, Float64(data=adc), t,
               expect=contract.TOPIC_BATTERY_VOLTAGE)
    last = h.received[contract.TOPIC_BATTERY_VOLTAGE][-1]
    assert last.voltage == pytest.approx(1.999 * adc, rel=0.01)
    assert last.present is True
    assert math.isnan(last.current) and math.isnan(last.percentage)
    assert last.power_supply_status == BatteryState.POWER_SUPPLY_STATUS_UNKNOWN
    stamp = last.header.stamp.sec + last.header.stamp.nanosec * 1e-9
    assert stamp == pytest.approx(t, abs=1e-6)  # time of the sample, on the node clock

    n_out = len(h.received[contract.TOPIC_BATTERY_VOLTAGE])
    t += 0.001
    h.send(contract.TOPIC_BATTERY_ADC, Float64(data=math.nan), t)
    assert len(h.received[contract.TOPIC_BATTERY_VOLTAGE]) == n_out  # rejected, not published
    for _ in range(20):  # later samples are filtered as before
        t += 0.001
        h.send(contract.TOPIC_BATTERY_ADC, Float64(data=adc), t,
               expect=contract.TOPIC_BATTERY_VOLTAGE)
    assert h.received[contract.TOPIC_BATTERY_VOLTAGE][-1].voltage == pytest.approx(
        1.999 * adc, rel=0.01)

    diagnostics = h.received[contract.TOPIC_DIAGNOSTICS]
    n_diag = len(diagnostics)
    h.set_time(t + 1.5)  # the 1 Hz diagnostics timer fires once more
    h.spin_until(lambda: len(diagnostics) > n_diag)
    status = diagnostics[-1].status[0]
    assert status.level == DiagnosticStatus.WARN, status
    assert status.name.startswith("battery_filter: ")
    rejected = {kv.key: kv.value for kv in status.values if "reject" in kv.key}
    assert any(v not in ("0", "") for v in rejected.values()), status


def battery_reference(node, samples):
    """What the battery filter published when it placed and filtered every sample in its own
    callback: (index of the input after which it was published, stamp in ns, volts)."""
    from bldc_propulsion.core.battery_filter import BatteryFilter
    from bldc_propulsion.core.ticker import Ticker
    from bldc_propulsion.nodes.stream_time import NEW_STREAM, SampleStream, arrival

    stream = SampleStream(1000.0, node.stream.tolerance_s, node.stream.use_source)
    core, ticker, out = BatteryFilter(node.core.config), Ticker(20.0), []
    for i, (received, info, value) in enumerate(samples):
        t = stream.follow(received, info, 1)
        if t is not None:
            settled = [(t, value)]
        else:
            settled = []
            for place, v in stream.push(arrival(received, info), 1, value):
                if place.event == NEW_STREAM and stream.streams > 1:
                    core.reset()
                settled.append((place.t_last, v))
        for t_s, v in settled:
            volts = core.update(t_s, v)
            if volts is not None and ticker.take(t_s):
                out.append((i, round(t_s * 1e9), volts))
    return out


def test_battery_filter_queue_publishes_what_one_sample_per_callback_did(start_node):
    """The node queues samples until an output may fall due (on_adc): every output, its stamp
    and value, and the input after which it is published are those of placing each sample in
    its own callback, through a transport loss, late messages, rejected samples and a
    publisher restart."""
    h = start_node(BatteryFilterNode)  # 1 kHz samples, 20 Hz output
    node = h.node
    published, fed = [], []
    node.voltage_pub.publish = lambda msg: published.append(
        (len(fed) - 1, msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec, msg.voltage))
    rng = np.random.default_rng(4)
    samples, seq, t = [], 0, T0
    for i in range(900):
        seq = 1 if i == 700 else seq + 1  # a publisher restart at 700
        if i in (130, 131, 132):  # lost in transport: the count jumps
            continue
        t += 1e-3
        # late beyond clock_tolerance_s (0.5 s): one alone (forgiven), then two (a break)
        receipt = t + 0.002 + (0.6 if i in (300, 520, 521) else 0.0)
        value = 4.0 + 0.01 * rng.standard_normal()
        if i in (200, 201, 450):
            value = math.nan if i != 450 else 99.0  # rejected by the core
        samples.append((receipt, {"source_timestamp": 0, "publication_sequence_number": seq}, value))
    clock = [0.0]
    node.now_s = lambda: clock[0]
    for received, info, value in samples:
        clock[0] = received
        fed.append(value)
        node.on_adc(Float64(data=value), info)
    assert len(node.queue) > 0  # the samples after the last output wait
    node.place_queue()
    expected = battery_reference(node, samples)
    assert len(expected) >= 10
    assert [(i, s) for i, s, _ in published] == [(i, s) for i, s, _ in expected]
    assert [v for *_, v in published] == [v for *_, v in expected]
    assert node.stream.lost_messages == 3 and node.stream.publisher_restarts == 1
    assert node.stream.late_forgiven == 1 and node.stream.late_breaks == 1
    assert node.core.rejected == 3


# --- thrust estimator ---

def test_thrust_estimator_predicts_with_the_fallback_and_warns(start_node):
    h = start_node(ThrustEstimatorNode)
    h.record(Float64, contract.TOPIC_PREDICTED_SPEED)
    h.record(Float64, contract.TOPIC_PREDICTED_THRUST)
    h.record(DiagnosticArray, contract.TOPIC_DIAGNOSTICS)
    estimator_inputs(h)
    h.send(contract.TOPIC_PWM, Float64(data=0.075), T0)
    for k in range(1, 50):
        h.set_time(T0 + 0.01 * k)
        h.executor.spin_once(timeout_sec=0.005)
    h.set_time(T0 + 1.5)
    h.spin_until(lambda: len(h.received[contract.TOPIC_PREDICTED_SPEED]) > 5
                 and statuses(h))
    speeds = [m.data for m in h.received[contract.TOPIC_PREDICTED_SPEED]]
    thrusts = [m.data for m in h.received[contract.TOPIC_PREDICTED_THRUST]]
    assert all(math.isfinite(s) and s >= 0.0 for s in speeds)
    assert all(math.isfinite(f) and f >= 0.0 for f in thrusts)
    assert any(s.level == DiagnosticStatus.WARN and "fallback" in s.message.lower()
               for s in statuses(h))


def test_thrust_estimator_refuses_a_bad_model(context, tmp_path):
    bad = tmp_path / "broken.npz"
    bad.write_bytes(b"not a model")
    with pytest.raises(BadInputError, match="broken.npz"):
        ThrustEstimatorNode(context=context,
                            parameter_overrides=[Parameter("model_path", value=str(bad))])


def test_thrust_estimator_main_exits_2_on_a_bad_model(tmp_path, capsys):
    missing = tmp_path / "missing.npz"
    status = main(["thrust_estimator", "--ros-args", "-p", f"model_path:={missing}"])
    assert status == 2
    assert "missing.npz" in capsys.readouterr().err


def test_thrust_estimator_keeps_the_last_good_model_on_a_bad_reload(context, tmp_path):
    node = ThrustEstimatorNode(context=context)
    try:
        bad = tmp_path / "broken.npz"
        bad.write_bytes(b"not a model")
        result = node.set_parameters([Parameter("model_path", value=str(bad))])[0]
        assert not result.successful and "broken.npz" in result.reason
        assert node.get_parameter("model_path").value == ""
    finally:
        node.destroy_node()


# --- all in one ---

def test_thrust_estimator_keeps_its_rate_under_a_40_hz_clock(start_node):
    """`ros2 bag play --clock` steps /clock at 40 Hz: every 10 ms grid time is still predicted."""
    h = start_node(ThrustEstimatorNode)
    h.record(Float64, contract.TOPIC_PREDICTED_SPEED)
    estimator_inputs(h)
    h.send(contract.TOPIC_PWM, Float64(data=0.075), T0)
    for k in range(1, 81):  # 2 s of /clock in 25 ms steps
        h.set_time(T0 + 0.025 * k)
        for _ in range(3):
            h.executor.spin_once(timeout_sec=0.002)
    received = h.received[contract.TOPIC_PREDICTED_SPEED]
    h.spin_until(lambda: len(received) >= 199)  # 100 Hz over 2 s, not 40 Hz (80)
    for _ in range(10):
        h.executor.spin_once(timeout_sec=0.005)
    assert len(received) <= 201


def test_thrust_estimator_stops_predicting_from_a_stale_command(start_node):
    """pwm_timeout_s: a fixed-rate pwm that falls silent stops the predictions, and says so."""
    h = start_node(ThrustEstimatorNode, pwm_timeout_s=0.2)
    h.record(Float64, contract.TOPIC_PREDICTED_SPEED)
    h.record(DiagnosticArray, contract.TOPIC_DIAGNOSTICS)
    estimator_inputs(h)
    for k in range(25):  # 0.5 s of pwm at 50 Hz
        h.send(contract.TOPIC_PWM, Float64(data=0.075), T0 + 0.02 * k)
    received = h.received[contract.TOPIC_PREDICTED_SPEED]
    for k in range(1, 61):  # then 1.5 s without pwm
        h.set_time(T0 + 0.48 + 0.025 * k)
        h.executor.spin_once(timeout_sec=0.002)
    h.spin_until(lambda: any("no pwm for" in s.message for s in statuses(h)))
    # predictions up to 0.2 s after the last command (0.48 s), none after
    assert 65 <= len(received) <= 70, len(received)
    assert any(s.level == DiagnosticStatus.ERROR and "not predicting" in s.message
               for s in statuses(h))


@pytest.mark.parametrize("node_main, argument, words", [
    ("tachometer", "blades:=0", ["parameter blades", "[1, 12]"]),
    ("tachometer", "sample_rate_hz:=1000", ["parameter sample_rate_hz", "double"]),
    ("battery_filter", "publish_rate_hz:=fast", ["parameter publish_rate_hz", "double"]),
    ("thrust_estimator", "output_rate_hz:=0.0", ["parameter output_rate_hz"]),
])
def test_bad_parameters_exit_2_with_one_line_naming_the_parameter(node_main, argument, words):
    import subprocess
    import sys
    module = {"tachometer": "tachometer_node", "battery_filter": "battery_filter_node",
              "thrust_estimator": "thrust_estimator_node"}[node_main]
    proc = subprocess.run(
        [sys.executable, "-m", f"bldc_propulsion.nodes.{module}", "--ros-args", "-p", argument],
        capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    for w in words:
        assert w in lines[0], lines[0]


# --- all in one ---

def test_all_in_one_is_one_pack_and_four_motors(context):
    nodes = build_nodes(4, context=context)
    try:
        names = sorted(n.get_fully_qualified_name() for n in nodes)
        assert names == sorted(["/battery_filter"] + [
            f"/motor{i}/{name}" for i in range(4) for name in ("tachometer", "thrust_estimator")])
        for n in nodes:
            topics = {s.topic_name for s in n.subscriptions}
            if n.get_name() == "thrust_estimator":
                assert "/battery/voltage" in topics, topics  # the shared pack
                assert f"{n.get_namespace()}/pwm" in topics
            if n.get_name() == "battery_filter":
                assert "/battery/adc" in topics
            else:  # each rotor its own joint (and frame) name
                assert n.get_parameter("joint_name").value == f"{n.get_namespace().strip('/')}_rotor"
            if n.get_name() == "thrust_estimator":
                assert n.get_parameter("frame_id").value == f"{n.get_namespace().strip('/')}_rotor"
        executor = SingleThreadedExecutor(context=context)
        for n in nodes:
            executor.add_node(n)
        executor.spin_once(timeout_sec=0.01)
        executor.shutdown()
    finally:
        for n in nodes:
            n.destroy_node()
    one = build_nodes(1, context=context)
    try:
        assert sorted(n.get_fully_qualified_name() for n in one) == [
            "/battery_filter", "/tachometer", "/thrust_estimator"]
        assert {n.get_parameter("joint_name").value for n in one if n.get_name() != "battery_filter"} == {"rotor"}
    finally:
        for n in one:
            n.destroy_node()
