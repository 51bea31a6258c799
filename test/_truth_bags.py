"""Small bench recordings with the simulator's true speed as rotor/speed, for tests of the
training, evaluation and reports that need no tachometer decoding."""

from __future__ import annotations

from pathlib import Path

from bldc_propulsion import contract as c
from bldc_propulsion.bagio import BagWriter
from bldc_propulsion.sim import simulate
from bldc_propulsion.sim.record import _streams


def write_bag(path: Path, profile: str, seed: int, *, thrust: bool, duration_s: float = 6.0,
              speed_gap: tuple[float, float] | None = None) -> Path:
    """A small bench recording: PWM, battery/adc, rotor/speed (the simulator's truth, so no
    tachometer to decode) and /thrust/measured only with ``thrust``; no rotor/speed in
    [``speed_gap``) (a telemetry dropout)."""
    res = simulate(profile, duration_s, seed)
    keep = {c.TOPIC_PWM, c.TOPIC_BATTERY_ADC, c.TOPIC_TRUTH_SPEED} | ({c.TOPIC_THRUST_MEASURED} if thrust else set())
    streams = [(c.TOPIC_ROTOR_SPEED if topic == c.TOPIC_TRUTH_SPEED else topic, t, v)
               for topic, t, v in _streams(res) if topic in keep]
    if speed_gap is not None:
        streams = [(topic, t[ok], v[ok]) if topic == c.TOPIC_ROTOR_SPEED else (topic, t, v)
                   for topic, t, v in streams
                   for ok in [~((t >= speed_gap[0]) & (t < speed_gap[1]))]]
    events = sorted((float(t[i]), k, i) for k, (_, t, _) in enumerate(streams) for i in range(len(t)))
    with BagWriter(path) as bag:
        for t, k, i in events:
            bag.write_float64(streams[k][0], t, float(streams[k][2][i]))
    return path
