"""Write a simulated bench run as the recording a real bench makes (plus ground truth)."""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import TypedDict

import numpy as np

from .. import contract as c
from ..atomic import RECORDING, check_output
from ..bagio import SIM_EPOCH_NS, BagWriter, check_namespace, vehicle_topic
from ..errors import BadInputError
from ..physics.params import BenchParams, params_with_overrides
from .bench import SimResult, simulate
from .faults import FAULTS_KEY, Fault, format_faults

#: Tachometer batch size and ground-truth rate written to bags. 200 samples at 20 kHz is the
#: contract's default batch (100 Hz); truth at 200 Hz keeps sample bags small while resolving
#: the rotor's ~0.1 s time constant.
TACH_BATCH = 200
TRUTH_RATE_HZ = 200.0
#: The load cell of a bench is read at 100 Hz (typical HX711-class amplifier rate).
THRUST_RATE_HZ = 100.0


def _streams(res: SimResult) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """(topic, times, values) of every stream, values indexable per message."""
    n_batches = len(res.tach) // TACH_BATCH
    batches = res.tach[: n_batches * TACH_BATCH].reshape(n_batches, TACH_BATCH)
    # contract: a batch's time is the time of its last sample
    batch_t = res.tach_t0 + (np.arange(n_batches) * TACH_BATCH + TACH_BATCH - 1) / res.tach_rate_hz
    truth_step = max(1, int(round((1.0 / TRUTH_RATE_HZ) / np.median(np.diff(res.truth_t)))))
    thrust_step = max(1, int(round((1.0 / THRUST_RATE_HZ) / np.median(np.diff(res.truth_t)))))
    rng = np.random.default_rng(res.seed + 7919)  # load-cell noise, independent of the physics
    load_cell = res.truth_thrust[::thrust_step] + rng.normal(0.0, 0.02, len(res.truth_t[::thrust_step]))
    return [
        (c.TOPIC_PWM, res.pwm_t, res.pwm),
        (c.TOPIC_BATTERY_ADC, res.battery_t, res.battery_adc),
        (c.TOPIC_TACH_ADC, batch_t, batches),
        (c.TOPIC_THRUST_MEASURED, res.truth_t[::thrust_step], load_cell),
        (c.TOPIC_TRUTH_SPEED, res.truth_t[::truth_step], res.truth_speed[::truth_step]),
        (c.TOPIC_TRUTH_THRUST, res.truth_t[::truth_step], res.truth_thrust[::truth_step]),
    ]


def write_sim_bag(res: SimResult, path: str | os.PathLike[str], *, force: bool = False,
                  storage: str = "mcap", namespace: str | None = None) -> int:
    """Write ``res`` in message-time order (as ``ros2 bag record`` would); returns messages.

    With ``namespace`` (e.g. ``motor0``) the run is recorded as one motor of a vehicle: its
    topics under ``/motor0/``, ``/battery/adc`` at the root; the messages are the same. Its
    faults go into the metadata (custom_data ``faults: propeller_damage=0.1@20``), read back by
    ``Recording.faults``; a healthy run's metadata has no such key, so healthy recordings stay
    byte for byte what they were before faults existed."""
    ns = check_namespace(namespace)
    streams = [(vehicle_topic(topic, ns), t, values) for topic, t, values in _streams(res)]
    times = np.concatenate([s[1] for s in streams])
    which = np.concatenate([np.full(len(s[1]), k) for k, s in enumerate(streams)])
    index = np.concatenate([np.arange(len(s[1])) for s in streams])
    order = np.lexsort((which, times))  # stable: time, then stream order
    custom = {FAULTS_KEY: format_faults(res.faults)} if res.faults else None
    with BagWriter(path, force=force, t0_ns=SIM_EPOCH_NS, storage=storage, custom_data=custom) as bag:
        for k in order:
            topic, t, values = streams[which[k]]
            i = index[k]
            if topic == vehicle_topic(c.TOPIC_TACH_ADC, ns):
                bag.write_float32_array(topic, float(t[i]), values[i])
            else:
                bag.write_float64(topic, float(t[i]), float(values[i]))
        return bag.messages_written


class SimulationSummary(TypedDict):
    """``simulate_to_bag``: what ``simulate --json`` prints."""

    path: str
    namespace: str | None
    profile: str
    duration_s: float
    seed: int
    soc: float
    effects: dict[str, float]
    faults: list[str]  #: each as its spec (``sim.faults``)
    messages: int
    speed_min_rad_s: float
    speed_max_rad_s: float
    voltage_end_v: float
    soc_end: float


def simulate_to_bag(
    path: str | os.PathLike[str],
    *,
    profile: str,
    duration_s: float,
    seed: int = 0,
    soc: float = 1.0,
    effects: dict[str, float] | None = None,
    params: dict[str, float] | None = None,
    storage: str = "mcap",
    force: bool = False,
    namespace: str | None = None,
    faults: Sequence[Fault] = (),
) -> SimulationSummary:
    """Simulate and record (one motor of a vehicle under ``namespace``, ``faults`` injected
    from their onsets); returns what ``simulate --json`` prints."""
    namespace = check_namespace(namespace)
    check_output(path, RECORDING, force=force)
    if storage != "mcap" and str(path).lower().endswith(".mcap"):
        raise BadInputError(f"-o {path}: a single .mcap file holds MCAP storage only (give a "
                            f"directory name for --storage {storage})")
    bench = params_with_overrides(BenchParams(), params or {})
    res = simulate(profile=profile, duration_s=duration_s, seed=seed, effects=effects, soc=soc,
                   params=bench, faults=faults)
    n = write_sim_bag(res, path, force=force, storage=storage, namespace=namespace)
    return {
        "path": str(path),
        "namespace": namespace,
        "profile": profile,
        "duration_s": float(duration_s),
        "seed": int(seed),
        "soc": float(soc),
        "effects": {k: float(v) for k, v in res.effects.items()},
        "faults": [f.spec for f in res.faults],
        "messages": int(n),
        "speed_min_rad_s": float(np.min(res.truth_speed)),
        "speed_max_rad_s": float(np.max(res.truth_speed)),
        "voltage_end_v": float(res.truth_voltage[-1]),
        "soc_end": float(res.truth_soc[-1]),
    }
