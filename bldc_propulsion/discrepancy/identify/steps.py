"""Command steps and the rotor's response to each: what physically identifies each dynamic effect.

A pure dead time shifts the response's onset and leaves its shape; a lag (inertia) changes its
slope and not its onset; a rotor that coasts (no braking) has a longer time constant on falling
steps only. Read from the step responses themselves, these three do not trade off against each
other as they do in a fit of the whole recording (``recording_fit.py``). ``StepChange`` is how one
such quantity moved from the reference to the measured steps (``dynamics.compare_steps`` puts
them together).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import stats

from ... import contract as c
from ...recordings import Signals
from ..residuals import robust_sigma

#: A command step is analysed when the command was held STEP_HOLD_S before it and after it (the
#: rotor settles within a few ~0.1-0.3 s time constants) and changed by at least STEP_MIN_PWM (a
#: step, not a frame of a ramp); the speeds before and at the end of the hold are the medians of
#: the last STEP_SETTLE_S, and the step's speed change must exceed STEP_MIN_SIGMAS x their noise.
STEP_HOLD_S = 0.5
STEP_MIN_PWM = 0.005
STEP_SETTLE_S = 0.1
STEP_MIN_SIGMAS = 10.0
#: Least number of analysed steps of a kind (rising/falling) on each set for a comparison.
STEP_MIN_COUNT = 4
#: Least relative change of a time constant (at the same operating point) that counts, with
#: significance: the two-point estimate scatters ~5-10 % per step, so a shift of the median by
#: less than that is no physical change even when many steps make it significant.
TAU_MIN_RATIO = 1.1
#: One-sided significance of a change between the two sets' steps (Mann-Whitney U).
STEP_ALPHA = 0.01


#: The part of a rising step's response its onset is read from (fractions of the way): the
#: line fitted to it, extended back to the speed before the step, meets it at the onset.
ONSET_FROM, ONSET_TO = 0.1, 0.5


@dataclass
class StepResponse:
    """One command step and the rotor's response: its time constant by Smith's two-point method
    (tau = 1.5 (t63 - t28), times from the command step) and its dead time from the onset of the
    rise (``_onset``)."""

    rising: bool
    pwm_from: float
    pwm_to: float
    speed_from: float
    speed_to: float
    dead_time_s: float
    tau_s: float

    @property
    def speed_mid(self) -> float:
        """The speed halfway between the two crossings the time constant is read from (28 % and
        63 % of the way): the operating point it belongs to."""
        return self.speed_from + 0.46 * (self.speed_to - self.speed_from)


def _crossing(t: np.ndarray, y: np.ndarray, level: float) -> float:
    """First time y reaches ``level`` (linear interpolation between samples), NaN if never/at once."""
    j = np.flatnonzero(y >= level)
    if len(j) == 0 or j[0] == 0:
        return float("nan")
    k = int(j[0])
    return float(t[k - 1] + (level - y[k - 1]) / (y[k] - y[k - 1]) * (t[k] - t[k - 1]))


def _onset(t: np.ndarray, y: np.ndarray) -> float:
    """When the rise of ``y`` (0 before the step, 1 after) starts: where the line fitted to its
    rise from ONSET_FROM to ONSET_TO of the way meets 0 (NaN if it never gets there).

    Not Smith's t63 - tau: a rotor whose drag grows with speed rises more slowly at first than
    a first-order lag would, so that estimate puts the onset later in proportion to the time
    constant, and a heavier rotor's response read as a longer dead time (10-20 ms for a time
    constant of 0.1-0.25 s on the simulated benches; 0.066 tau on a rise with quadratic drag). The
    line through the early rise errs early for both shapes (0.06-0.08 tau on a first-order lag
    or a quadratic-drag rise): a slower rotor never looks like a later onset."""
    up = np.flatnonzero(y >= ONSET_TO)
    if len(up) == 0 or up[0] == 0:  # never there, or there at once: no rise to fit
        return float("nan")
    k = int(up[0])
    below = np.flatnonzero(y[:k] < ONSET_FROM)
    j = int(below[-1]) if len(below) else 0  # the last sample before the rise
    # the rise's samples, from its last sample below ONSET_FROM only when it has fewer than two
    # (a fast rotor on a 100 Hz grid crosses the band between two samples)
    sel = slice(j + 1, k + 1) if k - j >= 2 else slice(j, k + 1)
    slope, icpt = np.polyfit(t[sel], y[sel], 1)
    return float(-icpt / slope) if slope > 0 else float("nan")


def held_levels(s: Signals) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The recording's command as held levels: when each starts (s), its PWM level, and when it
    ends (the next level's start; the last at the end of the recording). One place for the
    steps and the holds, so both see the same levels."""
    pt, pv = s.pwm_events
    first = np.r_[0, np.flatnonzero(np.diff(pv) != 0) + 1]  # where the level changes
    tc, lv = pt[first], pv[first]
    return tc, lv, np.r_[tc[1:], min(pt[-1], s.t[-1])]


def step_responses(signals: Sequence[Signals]) -> list[StepResponse]:
    """Every clean command step of the recordings with its dead time and time constant.

    A pure dead time shifts the response's onset and leaves its shape; a lag (inertia) changes
    its slope and not its onset; a rotor that coasts (no braking) has a longer time constant on
    falling steps only. Read from the step responses themselves, these three do not trade off
    against each other as they do in a fit of the whole recording."""
    out: list[StepResponse] = []
    for s in signals:
        if len(s.pwm_events[0]) < 3:
            continue
        tc, lv, ends = held_levels(s)
        for k in range(1, len(tc)):
            t0, hold, before = tc[k], ends[k] - tc[k], tc[k] - tc[k - 1]
            if abs(lv[k] - lv[k - 1]) < STEP_MIN_PWM or before < STEP_HOLD_S or hold < STEP_HOLD_S:
                continue
            pre = (s.t >= t0 - STEP_SETTLE_S) & (s.t < t0) & np.isfinite(s.speed)
            post = (s.t >= t0 + hold - STEP_SETTLE_S) & (s.t < t0 + hold) & np.isfinite(s.speed)
            if pre.sum() < 3 or post.sum() < 3:
                continue
            w0, w1 = float(np.median(s.speed[pre])), float(np.median(s.speed[post]))
            noise = max(robust_sigma(np.r_[s.speed[pre] - w0, s.speed[post] - w1]), 0.5)
            if abs(w1 - w0) < STEP_MIN_SIGMAS * noise:
                continue
            seg = (s.t >= t0) & (s.t < t0 + hold) & np.isfinite(s.speed)
            tt, frac = s.t[seg] - t0, (s.speed[seg] - w0) / (w1 - w0)
            t28, t63, onset = _crossing(tt, frac, 0.283), _crossing(tt, frac, 0.632), _onset(tt, frac)
            if not (np.isfinite(t28) and np.isfinite(t63) and np.isfinite(onset)):
                continue
            out.append(StepResponse(bool(lv[k] > lv[k - 1]), float(lv[k - 1]), float(lv[k]), w0, w1,
                                    onset, float(1.5 * (t63 - t28))))
    return out


#: A step's time constant is compared only where the reference has steps: at least
#: STEP_NEIGHBOURS within STEP_NEAR of the reference's speed range in ``speed_mid``. The time
#: constant depends on the operating point (drag grows with speed; the tachometer averages over a
#: revolution, long at low speed), so only steps at similar speeds are compared.
STEP_NEIGHBOURS = 3
STEP_NEAR = 0.15
#: Least reference steps the plane of ``relative_tau`` (falls) is fitted to (three or four
#: coefficients and some to spare); with fewer, the median of the STEP_NEIGHBOURS nearest stands in for it.
STEP_PLANE_MIN = 6
#: A held level this close above PWM_STOP is the stop level (2 us of pulse: no ESC drives there)
STOP_TOLERANCE = 1e-4


def at_stop(level: float) -> bool:
    """Whether a held command level is the stop level, where no ESC drives the rotor."""
    return level <= c.PWM_STOP + STOP_TOLERANCE


def relative_tau(steps: Sequence[StepResponse], reference: Sequence[StepResponse],
                 leave_one_out: bool = False, by_depth: bool = False) -> np.ndarray:
    """Each step's time constant / the reference's at a similar step (same direction; steps with
    no reference step near are left out): the median of the STEP_NEIGHBOURS reference steps
    nearest in middle speed.

    ``by_depth`` (falling steps): the reference's time constant at the step is a plane in log tau
    over the speeds it starts and ends at, fitted to the reference steps (leave-one-out for the
    reference's own), with a term for the falls that end at the stop level (``ends_at_stop``;
    left out where all or none of the reference's do). A coasting rotor's fall is slower the
    deeper it goes, so a deep fall compared with shallow falls at the same middle speed reads as a
    slower rotor. Not for rises:
    across rises from rest and from speed the plane extrapolates, and the README walkthrough's 9
    reference rises then read an unchanged rotor as 1.10x slower (p = 0.0002)."""
    if len(reference) < STEP_NEIGHBOURS + int(leave_one_out):
        return np.zeros(0)
    ref_w = np.array([x.speed_mid for x in reference])
    scale = max(float(np.max([max(abs(x.speed_from), abs(x.speed_to)) for x in reference])), 1.0)
    ref_x = np.array([_depth_row(x, scale) for x in reference])
    ref_y = np.log(np.maximum([x.tau_s for x in reference], 1e-3))

    def plane(keep: np.ndarray) -> tuple[np.ndarray, int]:
        # the stop term only where the reference has falls of both kinds: a constant column
        # would share the intercept and move the falls of the other kind
        cols = 4 if np.ptp(ref_x[keep, 3]) > 0 else 3
        return np.linalg.lstsq(ref_x[keep, :cols], ref_y[keep], rcond=None)[0], cols

    # without leave-one-out every step is compared with the same plane: fitted once
    whole = plane(np.ones(len(reference), bool)) if by_depth and not leave_one_out \
        and len(reference) >= STEP_PLANE_MIN else None
    out = []
    for i, x in enumerate(steps):
        dist = np.abs(ref_w - x.speed_mid) / scale
        keep = np.ones(len(reference), bool)
        if leave_one_out:
            dist[i] = np.inf
            keep[i] = False
        near = np.argsort(dist)[:STEP_NEIGHBOURS]
        if dist[near[-1]] > STEP_NEAR:
            continue
        if by_depth and keep.sum() >= STEP_PLANE_MIN:
            coef, cols = whole if whole is not None else plane(keep)
            ref_tau = float(np.exp(_depth_row(x, scale)[:cols] @ coef))
        else:
            ref_tau = float(np.exp(np.median(ref_y[near])))
        out.append(x.tau_s / max(ref_tau, 1e-3))
    return np.array(out)


def ends_at_stop(x: StepResponse) -> bool:
    """Whether the step ends at the stop level, where no ESC drives: the rotor brakes or coasts
    all the way (above it the drive meets the rotor part way), whatever its start level."""
    return at_stop(x.pwm_to)


#: A rising step whose rotor turned slower than this share of its end speed started from rest.
REST_SHARE = 0.05


def from_rest(x: StepResponse) -> bool:
    """Whether the step starts the rotor from rest: its onset is then the ESC's start-up and the
    tachometer's first revolution (no speed until a blade has passed, then a revolution's mean),
    not the dead time: on a foreign bench such steps read 7-17 ms earlier than the same set's
    steps between spinning speeds, on one set and not the other."""
    return x.rising and x.speed_from < REST_SHARE * x.speed_to


def _depth_row(x: StepResponse, scale: float) -> np.ndarray:
    """The regressors of the falls' plane: 1, start and end speeds (/ ``scale``), ends at stop."""
    return np.array([1.0, x.speed_from / scale, x.speed_to / scale, float(ends_at_stop(x))])


@dataclass
class StepChange:
    """How one quantity of the step responses moved from the reference to the measured data."""

    measured: float
    reference: float
    change: float  #: measured - reference (dead time, s) or measured / reference (time constants)
    p_value: float
    n_measured: int
    n_reference: int
    margin: float

    @property
    def changed(self) -> bool:
        return self.p_value < STEP_ALPHA and self.change >= self.margin

    def as_dict(self) -> dict[str, float]:
        return {"measured": self.measured, "reference": self.reference, "change": self.change,
                "p_value": self.p_value, "steps_measured": self.n_measured, "steps_reference": self.n_reference,
                "margin": self.margin}


def step_change(meas: np.ndarray, ref: np.ndarray, ratio: bool, margin: float) -> StepChange | None:
    """How a quantity moved from the reference steps' values ``ref`` to the measured ones ``meas``
    (the medians' ratio or difference; one-sided Mann-Whitney U), None with fewer than
    STEP_MIN_COUNT on a set."""
    if len(meas) < STEP_MIN_COUNT or len(ref) < STEP_MIN_COUNT:
        return None
    m, r = float(np.median(meas)), float(np.median(ref))
    p = float(stats.mannwhitneyu(meas, ref, alternative="greater").pvalue)
    return StepChange(m, r, m / r if ratio and r > 0 else m - r, p, len(meas), len(ref), margin)
