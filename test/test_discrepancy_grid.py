"""The physics path's start-level grid from the recordings' holds (discrepancy.physics.strength_grid),
on hand-made commands: the data place a start level only between two held levels."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pytest

from bldc_propulsion import contract as c
from bldc_propulsion.discrepancy import physics as ph
from bldc_propulsion.physics.config import load_config
from bldc_propulsion.physics.fit import Data

FRAME_S = 0.02


@dataclass
class Rec:
    """What held_levels reads of a recording: its time and its command events (one per 50 Hz frame)."""

    holds_us: list[tuple[float, float]]  #: (pulse in us, seconds held)
    t: np.ndarray = field(init=False)
    speed: np.ndarray = field(init=False)
    pwm_events: tuple[np.ndarray, np.ndarray] = field(init=False)

    def __post_init__(self) -> None:
        levels = np.concatenate([np.full(int(round(s / FRAME_S)), us / c.PWM_PERIOD_US) for us, s in self.holds_us])
        et = np.arange(len(levels)) * FRAME_S
        self.pwm_events = (et, levels)
        self.t = np.arange(0.0, len(levels) * FRAME_S, 0.01)
        self.speed = np.zeros_like(self.t)


def test_held_levels_merges_frames_and_drops_short_holds():
    r = Rec([(1000, 1.0), (1120, 0.3), (1150, 2.0), (1150.4, 1.0), (1300, 0.6)])
    us = ph.held_levels([r]) * c.PWM_PERIOD_US
    # 1120 us for 0.3 s is no hold; 1150.4 rounds to 1150 us and joins its run; the last hold
    # runs to the recording's end
    np.testing.assert_allclose(us, [1000.0, 1150.0, 1300.0])


def test_the_grid_gains_the_middle_of_each_gap_up_to_the_first_hold_beyond_its_top():
    model = load_config(None)
    dead = model.params.esc_deadband_pwm * c.PWM_PERIOD_US  # the nominal deadband, us
    top_us = 1000.0 + max(ph.STRENGTH_GRID["esc_deadband"]) * dead
    holds = [(1000, 1.0), (1040, 1.0), (1106, 1.0), (1142, 1.0), (top_us + 30, 1.0), (top_us + 200, 1.0)]
    grid = ph.strength_grid("esc_deadband", Data.of([Rec(holds)]), model.params)
    mids_us = [1020.0, 1073.0, 1124.0, (1142.0 + top_us + 30) / 2]
    want = {round((m - 1000.0) / dead, 4) for m in mids_us} | set(ph.STRENGTH_GRID["esc_deadband"])
    # nothing beyond the first hold past the grid's top
    assert list(grid) == pytest.approx(sorted(want), abs=1e-4)


def test_other_effects_and_a_command_without_holds_keep_the_fixed_grid():
    model = load_config(None)
    data = Data.of([Rec([(1000, 0.2), (1100, 0.2), (1200, 0.2)])])
    assert ph.strength_grid("esc_deadband", data, model.params) == ph.STRENGTH_GRID["esc_deadband"]
    held = Data.of([Rec([(1000, 1.0), (1100, 1.0)])])
    assert ph.strength_grid("input_delay", held, model.params) == ph.STRENGTH_GRID["input_delay"]
