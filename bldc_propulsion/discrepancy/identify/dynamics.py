"""Which of the dynamic family changed: rotor lag, dead time, spin-down, or the ESC start level.

A residual explained by one of them is partly explained by the others, so which one CHANGED is
decided from command -> measured speed on the measured and on the reference recordings, by what
physically identifies each: a dead time moves the onset of the response to a rising command step
and leaves its shape; a heavier rotor slows the rising steps at the same speed; an ESC that does
not brake slows only the falling steps (``steps.py``, compared by ``compare_steps``); a raised
start level leaves the rotor without drive at held levels where the reference's spins, and
compresses the throttle map above it (``static_shape.py``). ``which_dynamic`` names the one that
changed, the fit of the whole recordings (``recording_fit.py``) standing in where the steps and
holds cannot say.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ...recordings import Signals
from .recording_fit import START_LEVEL_MARGIN, Dynamics
from .static_shape import (
    StartLevelShift,
    holds,
    lowest_spinning_level,
    no_drive_bounds,
    start_level_rose,
    start_level_shift,
)
from .steps import (
    TAU_MIN_RATIO,
    StepChange,
    StepResponse,
    ends_at_stop,
    from_rest,
    relative_tau,
    step_change,
    step_responses,
)

#: The dynamic family: effects on the path from a command change to the speed.
DYNAMIC_EFFECTS = ("rotor_lag", "input_delay", "spin_down_asymmetry")
#: Least change of the rising steps' onset that counts as a dead time, in grid steps of the
#: recordings. The onset is a line through the rise, read finer than the grid: on the benches
#: looked at (own and foreign, 100 Hz), where no dead time was added the medians moved by 0.12
#: of a step at most (controls, spin-down, battery, heating), 0.51 with a raised start level
#: (p 0.04) and 0.54 with a lag added in series with the rotor (which comes first:
#: ``_precedence``); a dead time of 5.6 ms added read as 0.84.
DEAD_TIME_MIN_STEPS = 0.75
#: The effects ``which_dynamic`` tells apart: the dynamic family and the ESC start level, whose
#: residual features overlap (a start level moved up looks like a slower spin-up near it; a
#: slower rotor leaves a residual below the start level). A proposal of any of them from the
#: residual scores is checked against the identified response before it is made.
RESPONSE_EFFECTS = (*DYNAMIC_EFFECTS, "esc_deadband")


@dataclass
class StepDynamics:
    """Which dynamic quantity changed from the reference to the measured step responses (None:
    too few clean steps on one of the sets to say)."""

    dead_time: StepChange | None  #: rising steps' onset (s)
    spin_up: StepChange | None  #: rising steps' time constant / the reference's at similar speeds
    spin_down: StepChange | None  #: falling steps' time constant / the reference's at similar speeds
    start_level: tuple[bool, str] = (False, "")  #: ``start_level_rose`` on the holds
    #: ``spin_down`` from the measured falling steps that end where the ESC still drives (above
    #: the fitted start level): None when not asked for or too few such steps
    spin_down_driven: StepChange | None = None
    #: ``start_level_shift`` on the settled holds: None when too few on a set
    start_level_shift: StartLevelShift | None = None
    #: ``no_drive_bounds``: the measured start level lies above the first, at or below the second
    start_level_bounds: tuple[float, float] | None = None

    def as_dict(self) -> dict[str, object]:
        out: dict[str, object] = {k: (v.as_dict() if v is not None else None) for k, v in
                               (("dead_time_s", self.dead_time), ("spin_up_time_constant_ratio", self.spin_up),
                                ("spin_down_time_constant_ratio", self.spin_down),
                                ("spin_down_driven_time_constant_ratio", self.spin_down_driven))}
        out["start_level_rose"] = {"changed": self.start_level[0], "because": self.start_level[1],
                                   "bounds_pwm": list(self.start_level_bounds) if self.start_level_bounds else None}
        out["start_level_shift"] = self.start_level_shift.as_dict() if self.start_level_shift is not None else None
        return out


def compare_steps(measured: Sequence[StepResponse], reference: Sequence[StepResponse],
                  resolution_s: float = 0.01, driven_above: float | None = None,
                  spinning_from: float | None = None) -> StepDynamics:
    """The step responses of the two sets compared quantity by quantity:

    - dead time: the onsets of the rising steps that start spinning (a falling step's onset
      depends on braking, a start from rest's on the ESC's start-up: ``from_rest``), a change
      of at least DEAD_TIME_MIN_STEPS x ``resolution_s`` (the recordings' grid step);
    - spin-up: the rising steps' time constants relative to the reference's rising steps
      at similar speeds (1 = unchanged; the reference's own: leave-one-out), up by
      TAU_MIN_RATIO;
    - spin-down: the same for the falling steps. A heavier rotor slows both; an ESC that does
      not brake only the falling ones (``which_dynamic`` takes a lag first);
    - with ``driven_above`` (a PWM level), the spin-down again from the measured falling steps
      that end above it: an ESC that does not brake coasts there too, a raised start level only
      below it.

    With ``spinning_from`` (the lowest level the measured rotor is held spinning at), the
    measured falls that end above the stop level and below it are left out of the spin-down: they
    may end where the ESC gives no drive (a start level that rose), and the rotor then coasts
    whether the ESC brakes or not. Falls to the stop level (no drive on either set) and to levels
    where the rotor is held spinning (drive on both) tell braking from coasting."""
    mu = [x for x in measured if x.rising]
    md = [x for x in measured if not x.rising]
    md_judged = [x for x in md if spinning_from is None or ends_at_stop(x) or x.pwm_to >= spinning_from]
    ru = [x for x in reference if x.rising]
    rd = [x for x in reference if not x.rising]
    dead = step_change(np.array([x.dead_time_s for x in mu if not from_rest(x)]),
                       np.array([x.dead_time_s for x in ru if not from_rest(x)]), False,
                       DEAD_TIME_MIN_STEPS * resolution_s)
    up = step_change(relative_tau(mu, ru), relative_tau(ru, ru, True), True, TAU_MIN_RATIO)
    ref_down = relative_tau(rd, rd, True, by_depth=True)
    down = step_change(relative_tau(md_judged, rd, by_depth=True), ref_down, True, TAU_MIN_RATIO)
    driven = None
    if driven_above is not None:
        md_driven = [x for x in md if x.pwm_to >= driven_above]
        driven = step_change(relative_tau(md_driven, rd, by_depth=True), ref_down, True, TAU_MIN_RATIO)
    return StepDynamics(dead, up, down, spin_down_driven=driven)


def step_dynamics(measured: Sequence[Signals], reference: Sequence[Signals],
                  start_level: float | None = None) -> StepDynamics:
    """What changed from the reference to the measured recordings, read from their command steps
    and holds (``compare_steps`` at the recordings' grid step, ``start_level_rose``,
    ``start_level_shift``). With the measured data's fitted ``start_level``, the spin-down is
    compared again on the falling steps that end where the ESC still drives: START_LEVEL_MARGIN
    above it. The spin-down leaves out the falls that end below the lowest level the measured
    rotor is held spinning at (``lowest_spinning_level``), other than those to the stop level."""
    dts = [np.diff(s.t) for s in measured if len(s.t) > 1]
    grid = float(np.median(np.concatenate(dts))) if dts else 0.01
    driven = start_level + START_LEVEL_MARGIN if start_level is not None else None
    hm, hr = holds(measured), holds(reference)
    out = compare_steps(step_responses(measured), step_responses(reference), resolution_s=grid,
                        driven_above=driven, spinning_from=lowest_spinning_level(hm))
    out.start_level = start_level_rose(hm, hr)
    out.start_level_bounds = no_drive_bounds(hm, hr)
    out.start_level_shift = start_level_shift(hm, hr)
    return out


#: (change, margin, why): an effect of the family is named when its change reaches its margin
Change = tuple[float, float, str]
#: a quantity the step responses do not show changed (or cannot say: too few steps)
_NOT_SHOWN: Change = (-1.0, 0.0, "")


def which_dynamic(meas: Dynamics, ref: Dynamics | None, exclude: Sequence[str] = (),
                  steps: StepDynamics | None = None) -> tuple[str | None, str]:
    """The dynamic effect whose parameter changed from reference to measured, and why.

    With ``steps`` (``compare_steps``), lag, dead time and spin-down are decided from the step
    responses: the spin-up time constant at the same speed, the rising steps' onset and the
    falling steps' time constant, each compared with the reference's steps at similar speeds and
    changed significantly and by its margin; a quantity with too few such steps is not named.
    Without ``steps``, the fit of the whole recordings (``identify_dynamics``) decides: spin-up
    time constant up by 50 % and at least 50 ms; dead time up by 15 ms; spin-down time constant
    up by 0.1 s more than the spin-up one.
    ESC start level: the measured rotor gets no drive at a held level where the reference's
    spins (``start_level_rose``), else the settled speeds at held levels show a higher start
    level (``start_level_shift``); only when a set has too few settled holds for that, the fitted
    start level (when identified, else PWM_STOP on both) up by START_LEVEL_MARGIN, and with
    ``steps`` only after a lag and a dead time (it stands in for either: all three delay the
    rotor leaving rest), and after the spin-down when the falling steps that end where the ESC
    still drives are slower too. With ``steps``, no spin-down where the rising steps are slower
    too (a heavier rotor slows its falls as well)."""
    if ref is None:
        return None, "no reference data to compare the identified dynamics with"
    changes = _fit_changes(meas, ref)
    held = None
    if steps is not None:
        changes.update(_step_changes(steps))
        held = _held_start_level(steps)
        if held is not None:
            changes["esc_deadband"] = held
    for name in _precedence(steps, held):
        if name in exclude:
            continue
        change, margin, why = changes[name]
        if change >= margin:
            return name, why
    why = "the identified dead time and time constants did not change beyond their margins"
    if steps is not None and steps.start_level[1] and "esc_deadband" not in exclude:
        # what the holds could judge of the start level, and where they could not
        why += f"; the ESC start level: {steps.start_level[1]}"
    return None, why


def _fit_changes(meas: Dynamics, ref: Dynamics) -> dict[str, Change]:
    """Each effect's change on the fit of the whole recordings (``identify_dynamics``,
    ``identify_start_level``), with its margin and the sentence that names it."""
    return {
        "rotor_lag": (meas.tau_up_s - max(1.5 * ref.tau_up_s, ref.tau_up_s + 0.05), 0.0,
                      f"the spin-up time constant is {meas.tau_up_s:.2f} s on the measured data vs "
                      f"{ref.tau_up_s:.2f} s on the reference"),
        "spin_down_asymmetry": (meas.tau_down_s - ref.tau_down_s - max(meas.tau_up_s - ref.tau_up_s, 0.0), 0.1,
                                f"the spin-down time constant is {meas.tau_down_s:.2f} s on the measured data "
                                f"vs {ref.tau_down_s:.2f} s on the reference while the spin-up one is "
                                f"{meas.tau_up_s:.2f} s vs {ref.tau_up_s:.2f} s"),
        "input_delay": (meas.delay_s - ref.delay_s, 0.015,
                        f"the dead time is {1000 * meas.delay_s:.0f} ms on the measured data vs "
                        f"{1000 * ref.delay_s:.0f} ms on the reference"),
        "esc_deadband": (meas.start_level - ref.start_level, START_LEVEL_MARGIN - 1e-9,
                         f"the rotor gets no drive below PWM {meas.start_level:.3f} on the measured data vs "
                         f"{ref.start_level:.3f} on the reference (with the identified dead time and "
                         f"spin-up/spin-down time constants)"),
    }


def _step_changes(steps: StepDynamics) -> dict[str, Change]:
    """Lag, dead time and spin-down as the step responses show them: these replace the fit of
    the whole recordings' for the three."""
    from_steps = {
        "rotor_lag": (steps.spin_up, lambda x: (
            f"on rising command steps the rotor's time constant at the same speed is {x.change:.2f}x "
            f"the reference's (p = {x.p_value:.2g}; {x.n_measured} vs {x.n_reference} steps)")),
        "input_delay": (steps.dead_time, lambda x: (
            f"on rising command steps the response starts {1000 * x.measured:.0f} ms after the command on "
            f"the measured data vs {1000 * x.reference:.0f} ms on the reference, the time constant at the "
            f"same speed unchanged (p = {x.p_value:.2g}; {x.n_measured} vs {x.n_reference} steps)")),
        "spin_down_asymmetry": (steps.spin_down, lambda x: (
            f"on falling command steps the rotor slows down with a time constant {x.change:.2f}x the "
            f"reference's at similar speeds while its rising steps are unchanged: it is not braked "
            f"(p = {x.p_value:.2g}; {x.n_measured} vs {x.n_reference} steps)")),
    }
    out: dict[str, Change] = {}
    for name, (chg, because) in from_steps.items():
        # too few steps at speeds the reference also has is no evidence: the fit of the whole
        # recordings is not asked instead (its spin-down time constant takes a rotor running
        # down with no drive below a raised start level, or other speeds, for a change)
        out[name] = (chg.change - chg.margin if chg.changed else -1.0, 0.0, because(chg)) if chg is not None \
            else _NOT_SHOWN
    if steps.spin_up is not None and steps.spin_up.changed:
        # a heavier rotor slows the falling steps too, and not by the same factor (braking and
        # driving currents differ): with the rising steps slower, slower falling ones are no
        # evidence of an ESC that does not brake (on the simulated benches a lag's falls are
        # 1.2-2.5x its rises, a coasting ESC's 1.5-3x), so the spin-down is not named after a lag
        out["spin_down_asymmetry"] = _NOT_SHOWN
    return out


def judged(steps: StepDynamics) -> frozenset[str]:
    """The members of the family whose quantity the step responses and holds could judge (enough
    steps or settled holds on both sets): where none changed, only these are shown unchanged; of
    the others nothing is known (``_step_changes`` does not ask the whole recordings' fit)."""
    out = {name for name, chg in (("rotor_lag", steps.spin_up), ("input_delay", steps.dead_time),
                                  ("spin_down_asymmetry", steps.spin_down)) if chg is not None}
    if steps.spin_up is not None and steps.spin_up.changed:
        out.discard("spin_down_asymmetry")  # not judged after a lag (``_step_changes``)
    if _held_start_level(steps) is not None:
        out.add("esc_deadband")
    return frozenset(out)


def _held_start_level(steps: StepDynamics) -> Change | None:
    """The start level as the holds show it, None when a set has too few settled holds to say."""
    if steps.start_level[0]:
        # the direct evidence: no drive where the reference's rotor has it
        return (1.0, 0.0, steps.start_level[1])
    shift = steps.start_level_shift
    if shift is not None:
        # the settled speeds at held levels, which none of the three time quantities moves,
        # decide whether the start level rose; it is not read from how late the rotor leaves
        # rest (which a lag or a dead time also delays) nor from the fitted start level
        # (which takes a hotter winding's lost speed for a compressed throttle map)
        return (1.0 if shift.changed else -1.0, 0.0, shift.describe())
    return None


def _precedence(steps: StepDynamics | None, held: Change | None) -> list[str]:
    """The order the family is named in: the first whose change reaches its margin.

    By default a start level that rose explains a coast to zero (no drive) and a compressed
    throttle map, which the lags would otherwise take for a slower spin-down; a heavier rotor also
    delays the step response's apparent onset, so a lag comes before a dead time; the asymmetry is
    measured against the set's own rising steps."""
    if steps is None or held is not None:
        return ["esc_deadband", "rotor_lag", "input_delay", "spin_down_asymmetry"]
    # the fitted start level is read from how late the rotor leaves rest, which a dead time or a
    # lag between the fit's grid points also delays: where the step responses show a longer time
    # constant at the same speed or a later onset, those decide first. A rotor that coasts also
    # where the ESC drives (falling steps ending above the fitted start level) does not brake:
    # that is no start level either
    if steps.spin_down_driven is not None and steps.spin_down_driven.changed:
        return ["rotor_lag", "input_delay", "spin_down_asymmetry", "esc_deadband"]
    return ["rotor_lag", "input_delay", "esc_deadband", "spin_down_asymmetry"]
