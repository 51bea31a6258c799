"""The identification rules: which effect changed, decided from the response itself.

Two kinds of change cannot be told apart by a residual correction (``scoring.py``) alone, so the
network kind identifies them on command -> measured speed, on the measured and on the reference
recordings:

- the dynamic family (rotor lag, dead time, spin-down) and the ESC start level that goes with
  them: ``steps`` (the response to each command step: its onset and time constants),
  ``static_shape`` (held levels: no drive, and the start level that compresses the throttle
  map), ``recording_fit`` (the same quantities fitted over whole recordings, where steps and holds
  cannot say) and ``dynamics`` (``which_dynamic``: the one that changed);
- motor heating, a changed response to a thermal state both sets share (``heating``);
- ``refinement`` (``refine``): the rule that applies them to a round's proposal, the network
  kind's ``identify`` (the physics kind fits each effect's strength in the model itself, which is
  its identification).
"""

from .dynamics import DYNAMIC_EFFECTS, RESPONSE_EFFECTS, StepDynamics, compare_steps, step_dynamics, which_dynamic
from .heating import HEATING_TAU_S, Heating, identify_heating
from .recording_fit import START_LEVEL_MARGIN, Dynamics, identify_dynamics, identify_start_level
from .refinement import GAP_RATIO, Identification, Response, refine
from .static_shape import (
    SHIFT_MIN_HOLDS,
    Holds,
    StartLevelShift,
    holds,
    leaves_rest_at,
    no_drive_bounds,
    start_level_rose,
    start_level_shift,
    start_level_within,
)
from .steps import TAU_MIN_RATIO, StepChange, StepResponse, step_responses

__all__ = ["DYNAMIC_EFFECTS", "GAP_RATIO", "HEATING_TAU_S", "RESPONSE_EFFECTS", "SHIFT_MIN_HOLDS",
           "START_LEVEL_MARGIN", "TAU_MIN_RATIO", "Dynamics", "Heating", "Holds", "Identification", "Response",
           "StartLevelShift", "StepChange", "StepDynamics", "StepResponse", "compare_steps", "holds",
           "identify_dynamics", "identify_heating", "identify_start_level", "leaves_rest_at", "no_drive_bounds",
           "refine",
           "start_level_rose", "start_level_shift", "start_level_within", "step_dynamics", "step_responses",
           "which_dynamic"]
