"""Play a recording's input topics into ROS 2 in real time, with faults on request.

For machines without rosbag2 (the pip-only install) and for the live tests and benchmarks:
run as a process of its own (``python -m bldc_propulsion.nodes.player SPEC.json``), so the
nodes are fed from another process, as on a vehicle. ``ros2 bag play`` does the same on a full
Jazzy. SPEC (JSON) keys:
  bag        the recording; topics: input topics to play (bare names; default all three)
  rate       playback speed (default 1.0)
  motors     namespaces to play the motor topics (pwm, tachometer/adc) into, each the same
             recording (default [""]: root names); battery/adc always goes to the root
  t0_wall    wall time (s since the epoch) at which bag time ``t_from`` is played; without
             it, ``delay`` (default 1.0) seconds after every subscriber was found
  t_from, t_to   the part of the recording to play (bag seconds)
  drop       [[a, b], ...]: tachometer batches with bag time in [a, b) are never published
  hold       [[a, b], ...]: such batches are held and published together at bag time b
  namespace  prefix of every topic ('' = root names)
It waits (up to 60 s) for a subscriber on every topic, prints "t0 <wall time>", plays, prints
"published N t_end <wall time>", stays LINGER_S for the last messages to be taken, and exits.
"""

from __future__ import annotations

import array
import json
import sys
import time

import numpy as np
import rclpy
from std_msgs.msg import Float32MultiArray, Float64

from bldc_propulsion import contract as c
from bldc_propulsion.bagio import open_recording

#: Seconds the player stays after its last message, so that every subscriber takes it.
LINGER_S = 1.0

TYPES = {c.TOPIC_PWM: Float64, c.TOPIC_BATTERY_ADC: Float64, c.TOPIC_TACH_ADC: Float32MultiArray}


def in_any(t: float, ranges: list[list[float]]) -> list[float] | None:
    return next((r for r in ranges if r[0] <= t < r[1]), None)


def main(spec_path: str) -> int:
    spec = json.loads(open(spec_path).read())
    topics = spec.get("topics", list(TYPES))
    motors = spec.get("motors", [""])
    rate = float(spec.get("rate", 1.0))
    t_from, t_to = spec.get("t_from", 0.0), spec.get("t_to", 1e9)
    with open_recording(spec["bag"]) as rec:
        items = []
        for topic, t, msg in rec.messages(topics):
            if t_from <= t < t_to:
                data = msg.data
                if topic == c.TOPIC_TACH_ADC:
                    data = array.array("f", np.asarray(data, dtype=np.float32).tobytes())
                items.append((t, topic, data))
    rclpy.init()
    node = rclpy.create_node("test_player")
    pubs: dict[str, list] = {}
    for t in topics:
        spaces = [""] if t == c.TOPIC_BATTERY_ADC else motors
        pubs[t] = [node.create_publisher(TYPES[t], f"{ns}/{t}" if ns else t, 1000)
                   for ns in spaces]
    deadline = time.monotonic() + 60.0
    while any(p.get_subscription_count() == 0 for ps in pubs.values() for p in ps):
        if time.monotonic() > deadline:
            print("no subscriber", file=sys.stderr)
            return 1
        time.sleep(0.05)
    held: list[tuple[float, str, object]] = []
    drop, hold = spec.get("drop", []), spec.get("hold", [])
    t0_wall = spec.get("t0_wall") or time.time() + spec.get("delay", 1.0)
    print(f"t0 {t0_wall!r}", flush=True)
    n = 0

    def publish(topic: str, data: object) -> None:
        nonlocal n
        msg = TYPES[topic]()
        msg.data = data
        for pub in pubs[topic]:
            pub.publish(msg)
            n += 1

    for t, topic, data in items:
        due = t0_wall + (t - t_from) / rate
        delay = due - time.time()
        if delay > 0:
            time.sleep(delay)
        if held and t >= held[0][0]:  # release a held burst
            for _, h_topic, h_data in held[1:]:
                publish(h_topic, h_data)
            held = []
        if topic == c.TOPIC_TACH_ADC:
            if in_any(t, drop):
                continue
            r = in_any(t, hold)
            if r is not None:
                if not held:
                    held.append((r[1], "", None))
                held.append((t, topic, data))
                continue
        publish(topic, data)
    print(f"published {n} t_end {time.time()!r}", flush=True)
    # Linger before leaving: a subscriber whose last messages were not yet taken when their
    # writer left lost them (3 of 4 tachometers lost the final batch in one benchmark run).
    time.sleep(LINGER_S)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
