"""Write a foreign-bench run as the recording a real bench makes (the contract's topics and
messages, through the package's bag writer), plus the ``truth/`` topics simulated recordings carry."""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from bldc_propulsion import contract as c
from bldc_propulsion.atomic import RECORDING, check_output
from bldc_propulsion.bagio import SIM_EPOCH_NS, BagWriter

from .model import STEP_S, TRUTH_RATE_HZ, Run

TACH_BATCH = 200  #: samples per tachometer message (contract default: 100 Hz at 20 kHz)


def _streams(run: Run) -> list[tuple[str, np.ndarray, Any]]:
    """(topic, times, values) of every stream; values indexable per message."""
    nb = len(run.tach_v) // TACH_BATCH
    batches = run.tach_v[: nb * TACH_BATCH].reshape(nb, TACH_BATCH)
    batch_t = run.tach_t[TACH_BATCH - 1: nb * TACH_BATCH: TACH_BATCH]  # a batch's time: its last sample
    step = max(1, int(round(1.0 / (TRUTH_RATE_HZ * STEP_S))))
    return [
        (c.TOPIC_PWM, run.cmd_t, run.cmd),
        (c.TOPIC_BATTERY_ADC, run.adc_t, run.adc_v),
        (c.TOPIC_TACH_ADC, batch_t, batches),
        (c.TOPIC_THRUST_MEASURED, run.load_t, run.load_n),
        (c.TOPIC_TRUTH_SPEED, run.t[::step], run.speed[::step]),
        (c.TOPIC_TRUTH_THRUST, run.t[::step], run.thrust[::step]),
    ]


def write_bag(run: Run, path: str | os.PathLike[str], *, force: bool = False) -> int:
    """Write ``run`` in message-time order, as ``ros2 bag record`` would; returns messages written."""
    check_output(path, RECORDING, force=force)
    streams = _streams(run)
    times = np.concatenate([s[1] for s in streams])
    which = np.concatenate([np.full(len(s[1]), k) for k, s in enumerate(streams)])
    index = np.concatenate([np.arange(len(s[1])) for s in streams])
    order = np.lexsort((which, times))
    with BagWriter(path, force=force, t0_ns=SIM_EPOCH_NS) as bag:
        for k in order:
            topic, t, values = streams[which[k]]
            i = index[k]
            if topic == c.TOPIC_TACH_ADC:
                bag.write_float32_array(topic, float(t[i]), values[i])
            else:
                bag.write_float64(topic, float(t[i]), float(values[i]))
        return bag.messages_written
