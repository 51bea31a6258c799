"""The identification rules: which effect changed, decided from the response itself.

Two kinds of change cannot be told apart by a residual correction (``scoring.py``) alone:

- the dynamic family (rotor lag, dead time, spin-down, and the ESC start level that goes with
  them): a residual explained by one is partly explained by the others, so which one CHANGED is
  decided from command -> measured speed on the measured and on the reference recordings, by
  what physically identifies each (``step_dynamics``, ``which_dynamic``): a dead time moves the
  onset of the response to a rising command step and leaves its shape; a heavier rotor slows
  the rising steps at the same speed; an ESC that does not brake slows only the falling steps;
  a raised start level leaves the rotor without drive (running down, or at rest) at held
  levels where the reference's spins, and compresses the throttle map above it, which the
  settled speeds at held levels show (``start_level_shift``). Fitted over whole recordings
  (``identify_dynamics``, ``identify_start_level``: the parameters the network's added input
  gets unless the holds gave the start levels), the three time quantities trade off against
  each other and against the operating points each set visits;
- motor heating, a changed response to a thermal state both sets share (``identify_heating``).

``refine`` is the rule that applies them to a round of candidate scores (the network path: its
scores are residual corrections; the physics path fits each effect's strength in the model
itself, which is its identification).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import stats

from .. import contract as c
from ..core import effect_features as ef
from ..plant import throttle
from ..recordings import Signals
from .residuals import robust_sigma

# --- the dynamic family: which of lag, dead time, spin-down changed ---------------------------------
#: Grids of the direct identification of the rotor's response (s).
ID_DELAYS = (0.0, 0.01, 0.02, 0.03, 0.04, 0.05, 0.06, 0.08, 0.1)
ID_TAU_UP = (0.0, 0.02, 0.04, 0.07, 0.1, 0.15, 0.2, 0.3)
ID_TAU_DOWN = (0.0, 0.02, 0.04, 0.07, 0.1, 0.15, 0.2, 0.3, 0.5, 0.8, 1.2, 2.0)
#: ESC start levels tried (PWM level) when esc_deadband is a candidate (identify_start_level: the start
#: level goes in before the lag, since a rotor commanded below it coasts down to zero like one that is
#: not braked, so a coast to zero is not taken for a slower spin-down), and the rise that counts.
ID_START_LEVELS = tuple(round(0.05 + 0.001 * k, 3) for k in range(11))  # 0.050 ... 0.060
START_LEVEL_MARGIN = 0.002  #: PWM level: twice the grid step (0.001), so one step of noise is no change
DYNAMIC_EFFECTS = ("rotor_lag", "input_delay", "spin_down_asymmetry")
#: The effects ``which_dynamic`` tells apart: the dynamic family and the ESC start level, whose
#: residual features overlap (a start level moved up looks like a slower spin-up near it; a
#: slower rotor leaves a residual below the start level). A proposal of any of them from the
#: residual scores is checked against the identified response before it is made.
RESPONSE_EFFECTS = (*DYNAMIC_EFFECTS, "esc_deadband")


@dataclass
class Dynamics:
    """The rotor's response identified from command to measured speed (not from a residual)."""

    delay_s: float
    tau_up_s: float
    tau_down_s: float
    rmse_rad_s: float
    start_level: float = c.PWM_STOP  #: ESC start level (PWM level), when it was identified

    def as_dict(self) -> dict[str, float]:
        return {"dead_time_s": self.delay_s, "start_level_pwm": self.start_level,
                "spin_up_time_constant_s": self.tau_up_s,
                "spin_down_time_constant_s": self.tau_down_s, "fit_rmse_rad_s": self.rmse_rad_s}


def identify_dynamics(signals: Sequence[Signals]) -> Dynamics:
    """Dead time and spin-up/spin-down time constants that best explain the measured speed.

    speed ~ cubic(x) + linear(V) + V * x, with x the command delayed by d and passed through a
    first-order lag of tau_up while rising and tau_down while falling (state from rest). The
    grid (d, tau_up, tau_down) is searched exhaustively; all lags are run at once, vectorised
    over the grid, on the recordings' 100 Hz grid.
    """
    combos = [(tu, td) for tu in ID_TAU_UP for td in ID_TAU_DOWN]
    tu = np.array([x[0] for x in combos])
    td = np.array([x[1] for x in combos])
    sse = np.zeros((len(ID_DELAYS), len(combos)))
    n_total = 0
    for s in signals:
        ok = np.isfinite(s.speed) & np.isfinite(s.voltage)
        dt = float(np.median(np.diff(s.t)))
        a_up = np.where(tu > 0, np.exp(-dt / np.maximum(tu, 1e-9)), 0.0)
        a_dn = np.where(td > 0, np.exp(-dt / np.maximum(td, 1e-9)), 0.0)
        v = (s.voltage - 11.5)
        y = s.speed[ok]
        n_total += len(y)
        pwm_t, pwm = s.pwm_events
        for i, d in enumerate(ID_DELAYS):
            u = ef._held(pwm_t, pwm, s.t - d)
            X = np.empty((len(s.t), len(combos)))
            state = np.full(len(combos), c.PWM_STOP)
            for k in range(len(s.t)):
                uk = u[k]
                a = np.where(uk > state, a_up, a_dn)
                state = uk + (state - uk) * a
                X[k] = state
            X = (X[ok] - 0.075) / 0.025
            vv = v[ok]
            for j in range(len(combos)):
                x = X[:, j]
                A = np.column_stack([np.ones_like(x), x, x**2, x**3, vv, vv * x])
                beta, *_ = np.linalg.lstsq(A, y, rcond=None)
                sse[i, j] += float(np.sum((y - A @ beta) ** 2))
    best_i, best_j = (int(k) for k in np.unravel_index(int(np.argmin(sse)), sse.shape))
    return Dynamics(float(ID_DELAYS[best_i]), float(tu[best_j]), float(td[best_j]),
                    float(np.sqrt(sse[best_i, best_j] / max(n_total, 1))))


def identify_start_level(signals: Sequence[Signals], dyn: Dynamics) -> float:
    """ESC start level that best explains the speed, the dead time and time constants held at
    ``dyn``'s (a scan of ID_START_LEVELS; one lag per level, so cheap next to identify_dynamics)."""
    sse = np.zeros(len(ID_START_LEVELS))
    for s in signals:
        ok = np.isfinite(s.speed) & np.isfinite(s.voltage)
        pwm_t, pwm = s.pwm_events
        u0 = ef._held(pwm_t, pwm, s.t - dyn.delay_s)
        vv = (s.voltage - 11.5)[ok]
        for i, thr in enumerate(ID_START_LEVELS):
            u = c.PWM_STOP + (c.PWM_FULL - c.PWM_STOP) * throttle(u0, thr)
            x = ef.asymmetric_lag_on_times(s.t, u, dyn.tau_up_s, dyn.tau_down_s, c.PWM_STOP)
            x = (x[ok] - 0.075) / 0.025
            A = np.column_stack([np.ones_like(x), x, x**2, x**3, vv, vv * x])
            beta, *_ = np.linalg.lstsq(A, s.speed[ok], rcond=None)
            sse[i] += float(np.sum((s.speed[ok] - A @ beta) ** 2))
    return float(ID_START_LEVELS[int(np.argmin(sse))])


# --- step responses: what physically identifies each dynamic effect --------------------------------
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
    constant of 0.1-0.25 s on the tuning benches; 0.066 tau on a rise with quadratic drag). The
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


def _levels(s: Signals) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
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
        tc, lv, ends = _levels(s)
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


#: Reference steps a step's time constant is compared with: the STEP_NEIGHBOURS nearest in
#: ``speed_mid``, within STEP_NEAR of the reference's speed range. The time constant depends on
#: the operating point (drag grows with speed; the tachometer averages over a revolution, long
#: at low speed), so only steps at similar speeds are compared.
STEP_NEIGHBOURS = 3
STEP_NEAR = 0.15


def _relative_tau(steps: Sequence[StepResponse], reference: Sequence[StepResponse],
                  leave_one_out: bool = False) -> np.ndarray:
    """Each step's time constant / the median of its nearest reference steps' (same direction;
    steps with no reference step near are left out)."""
    if len(reference) < STEP_NEIGHBOURS + int(leave_one_out):
        return np.zeros(0)
    ref_w = np.array([x.speed_mid for x in reference])
    ref_tau = np.array([x.tau_s for x in reference])
    scale = max(float(np.max([max(abs(x.speed_from), abs(x.speed_to)) for x in reference])), 1.0)
    out = []
    for i, x in enumerate(steps):
        dist = np.abs(ref_w - x.speed_mid) / scale
        if leave_one_out:
            dist[i] = np.inf
        near = np.argsort(dist)[:STEP_NEIGHBOURS]
        if dist[near[-1]] > STEP_NEAR:
            continue
        out.append(x.tau_s / max(float(np.median(ref_tau[near])), 1e-3))
    return np.array(out)


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


def _compare(meas: np.ndarray, ref: np.ndarray, ratio: bool, margin: float) -> StepChange | None:
    if len(meas) < STEP_MIN_COUNT or len(ref) < STEP_MIN_COUNT:
        return None
    m, r = float(np.median(meas)), float(np.median(ref))
    p = float(stats.mannwhitneyu(meas, ref, alternative="greater").pvalue)
    return StepChange(m, r, m / r if ratio and r > 0 else m - r, p, len(meas), len(ref), margin)


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

    def as_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {k: (v.as_dict() if v is not None else None) for k, v in
                               (("dead_time_s", self.dead_time), ("spin_up_time_constant_ratio", self.spin_up),
                                ("spin_down_time_constant_ratio", self.spin_down),
                                ("spin_down_driven_time_constant_ratio", self.spin_down_driven))}
        out["start_level_rose"] = {"changed": self.start_level[0], "because": self.start_level[1]}
        out["start_level_shift"] = self.start_level_shift.as_dict() if self.start_level_shift is not None else None
        return out


def compare_steps(measured: Sequence[StepResponse], reference: Sequence[StepResponse],
                  resolution_s: float = 0.01, driven_above: float | None = None) -> StepDynamics:
    """The step responses of the two sets compared quantity by quantity:

    - dead time: the rising steps' onsets (a falling step's onset depends on braking), a change
      of at least ``resolution_s`` (the recordings' grid step);
    - spin-up: the rising steps' time constants relative to the reference's rising steps
      at similar speeds (1 = unchanged; the reference's own: leave-one-out), up by
      TAU_MIN_RATIO;
    - spin-down: the same for the falling steps. A heavier rotor slows both; an ESC that does
      not brake only the falling ones (``which_dynamic`` takes a lag first);
    - with ``driven_above`` (a PWM level), the spin-down again from the measured falling steps
      that end above it: an ESC that does not brake coasts there too, a raised start level only
      below it."""
    mu = [x for x in measured if x.rising]
    md = [x for x in measured if not x.rising]
    ru = [x for x in reference if x.rising]
    rd = [x for x in reference if not x.rising]
    dead = _compare(np.array([x.dead_time_s for x in mu]), np.array([x.dead_time_s for x in ru]), False,
                    resolution_s)
    up = _compare(_relative_tau(mu, ru), _relative_tau(ru, ru, True), True, TAU_MIN_RATIO)
    ref_down = _relative_tau(rd, rd, True)
    down = _compare(_relative_tau(md, rd), ref_down, True, TAU_MIN_RATIO)
    driven = None
    if driven_above is not None:
        driven = _compare(_relative_tau([x for x in md if x.pwm_to >= driven_above], rd), ref_down, True,
                          TAU_MIN_RATIO)
    return StepDynamics(dead, up, down, spin_down_driven=driven)

# --- the ESC start level from where the rotor gets no drive --------------------------------------
#: A measured hold "gets no drive" when the rotor ends it (not rising) below NO_DRIVE_FRACTION of
#: the speed the reference's rotor settles at for that level: a lower supply or a hotter winding
#: lowers the speed by some per cent, only the loss of drive halves it.
NO_DRIVE_FRACTION = 0.5
#: A reference hold counts as "spinning" only above this share of the reference's fastest settled
#: hold: a rotor that reads a few hundredths of a rad/s is at rest, and interpolating from it
#: puts tens of rad/s at levels just above, where the static map is still at zero (the friction
#: is not yet overcome; on a lower pack even less so), so a measured rotor at rest there would be
#: taken for a start level that rose.
SPINNING_MIN_SHARE = 0.02
#: The end of a hold the speed is read from: a line fitted to it gives the end speed and whether
#: the rotor had settled (drift <= 2 % + twice the noise) or was still rising.
SETTLED_S = 0.3


@dataclass
class Holds:
    """Held command levels (each at least STEP_HOLD_S, above PWM_STOP) and the rotor at their end."""

    levels: np.ndarray  #: PWM level
    speed: np.ndarray  #: speed at the end of the hold (rad/s)
    settled: np.ndarray  #: the speed no longer drifted
    rising: np.ndarray  #: the speed was still rising (spinning up towards the level's speed)
    voltage: np.ndarray  #: mean filtered battery voltage over the hold's end (V; NaN if none)
    thermal: np.ndarray  #: ``thermal_load`` state at the hold's end (HEATING_TAU_S)


def holds(signals: Sequence[Signals]) -> Holds:
    """Every hold of at least STEP_HOLD_S above PWM_STOP with the rotor's state at its end."""
    rows = []
    for s in signals:
        ok = np.isfinite(s.speed)
        if len(s.pwm_events[0]) < 2 or not ok.any():
            continue
        pwm_t, pwm = s.pwm_events
        vt, vv = s.voltage_events
        th = ef.compute(ef.THERMAL_LOAD, s.t, pwm_t, pwm, vt, vv, {"tau_s": HEATING_TAU_S})
        tc, lv, ends = _levels(s)
        for k in range(len(tc)):
            if ends[k] - tc[k] < STEP_HOLD_S or lv[k] <= c.PWM_STOP:
                continue
            last = (s.t >= ends[k] - SETTLED_S) & (s.t < ends[k]) & ok
            if last.sum() < 5:
                continue
            tl = s.t[last] - ends[k]
            slope, icpt = np.polyfit(tl, s.speed[last], 1)
            noise = max(robust_sigma(s.speed[last] - (icpt + slope * tl)), 0.5)
            drift = slope * SETTLED_S
            volt = s.voltage[last]
            volt = volt[np.isfinite(volt)]
            rows.append((float(lv[k]), max(float(icpt), 0.0), abs(drift) <= 0.02 * abs(icpt) + 2.0 * noise,
                         drift > 2.0 * noise, float(np.mean(volt)) if len(volt) else math.nan,
                         float(np.nanmean(th[last])) if np.isfinite(th[last]).any() else math.nan))
    a = np.array(rows, dtype=float).reshape(-1, 6)
    return Holds(a[:, 0], a[:, 1], a[:, 2].astype(bool), a[:, 3].astype(bool), a[:, 4], a[:, 5])


def start_level_rose(measured: Holds, reference: Holds) -> tuple[bool, str]:
    """Whether the measured rotor gets no drive at a level where the reference's has it, and why.

    An ESC gives no drive below its start level: the rotor runs down to rest there (braked or
    coasting, however long that takes) whatever it did before. A measured hold at a level within
    the range where the reference's rotor settles spinning, ending (not rising) below
    NO_DRIVE_FRACTION of the reference's speed at that level, had no drive: the start level rose.
    Read from the holds, not from a fit of the throttle map (which the network re-weights, and a
    lag would take for a slower spin-down)."""
    top = float(np.max(reference.speed[reference.settled], initial=0.0))
    spin = reference.settled & (reference.speed > SPINNING_MIN_SHARE * top) & ~reference.rising
    if spin.sum() < 2:
        return False, "the reference recordings hold too few levels at which the rotor settles spinning"
    order = np.argsort(reference.levels[spin])
    lv_r, w_r = reference.levels[spin][order], reference.speed[spin][order]
    # the reference's rotor at rest at a level bounds its start level from below: levels at or
    # below that are no evidence
    inside = (measured.levels >= lv_r[0]) & (measured.levels <= lv_r[-1]) & ~measured.rising
    expect = np.interp(measured.levels, lv_r, w_r)
    none = inside & (measured.speed < NO_DRIVE_FRACTION * expect)
    if not none.any():
        return False, (f"at every held level from PWM {lv_r[0]:.4f} (where the reference's rotor spins) the "
                       f"measured rotor spins as well")
    k = int(np.argmax(np.where(none, measured.levels, -np.inf)))
    return True, (f"the rotor runs at less than half the reference's speed, or stops, at {int(none.sum())} held "
                  f"level(s) up to PWM {measured.levels[k]:.4f} on the measured data ({measured.speed[k]:.0f} rad/s "
                  f"at the end of the hold, not rising, where the reference's settles at {expect[k]:.0f} rad/s; "
                  f"its rotor spins from PWM {lv_r[0]:.4f})")


#: ESC start levels (PWM level) the held levels' static map is fitted at (start_level_shift): from
#: PWM_STOP to well past any start level an ESC ships with, in steps of 0.0005 (10 us of pulse).
SHIFT_LEVELS = tuple(round(c.PWM_STOP + 0.0005 * k, 4) for k in range(41))  # 0.0500 ... 0.0700
#: Least settled holds on each set for the start-level shift test (the static map has 7 terms).
SHIFT_MIN_HOLDS = 8
#: Least rise that counts: two steps of SHIFT_LEVELS, since a start level between two of them lands
#: on either neighbour on each set (a one-step difference is the scan's own resolution).
SHIFT_MIN_RISE = 0.001


@dataclass
class StartLevelShift:
    """The two sets' start levels fitted on their settled holds with one static map for both,
    and the F-test of "the measured set's start level differs" against "one start level"."""

    measured: float  #: PWM level
    reference: float  #: PWM level
    f_stat: float
    p_value: float
    n_measured: int
    n_reference: int

    @property
    def changed(self) -> bool:
        return self.p_value < STEP_ALPHA and self.measured - self.reference >= SHIFT_MIN_RISE - 1e-9

    @property
    def at_bound(self) -> bool:
        return self.measured >= SHIFT_LEVELS[-1]

    def describe(self) -> str:
        bound = (f" (at the end of the levels tried, PWM {SHIFT_LEVELS[-1]:.4f}: it may be higher)"
                 if self.at_bound else "")
        return (f"the settled speeds at held levels give an ESC start level of PWM {self.measured:.4f} on the "
                f"measured data vs {self.reference:.4f} on the reference{bound}, one static map for both "
                f"with its voltage and thermal terms (F = {self.f_stat:.1f}, p = {self.p_value:.2g}; "
                f"{self.n_measured} vs {self.n_reference} holds; a rise counts from {SHIFT_MIN_RISE:g})")

    def as_dict(self) -> dict[str, float]:
        return {"measured_pwm": self.measured, "reference_pwm": self.reference, "f_stat": self.f_stat,
                "p_value": self.p_value, "holds_measured": self.n_measured, "holds_reference": self.n_reference,
                "at_bound": self.at_bound}


def _static_map(h: Holds, start: float, measured: bool) -> np.ndarray:
    """Columns of the settled speed at held levels: duty d = throttle(level, start) (no drive, no
    speed, below the start level), d, d^2, d^3 and their change with the supply (V - 11.5) d, d^2,
    and a response to the winding's thermal state per set, theta d (a hotter winding loses speed in
    proportion to the load, a raised start level loses it most at low levels: they do not trade)."""
    d = throttle(h.levels, start)
    v = h.voltage - 11.5
    td = h.thermal * d
    return np.column_stack([d, d**2, d**3, v * d, v * d**2, td * measured, td * (not measured)])


def start_level_shift(measured: Holds, reference: Holds) -> StartLevelShift | None:
    """Whether the measured ESC's start level rose, from the settled speeds at held levels.

    A start level compresses the throttle map: the duty at a level drops most just above it
    and not at all at full command, which neither a lag, a dead time nor a coasting rotor
    changes (they move the path between holds, not where the rotor settles), and which a hotter
    winding or a lower supply does not mimic (they lose speed in proportion to the load; both are
    in the map). The two sets share one static map; their start levels are fitted on
    SHIFT_LEVELS, together (the null: one level) and apart, and the F-test of the one extra
    parameter, with the holds as the units, says whether they differ. None with fewer than
    SHIFT_MIN_HOLDS settled holds on a set."""
    def usable(h: Holds) -> Holds:
        k = h.settled & ~h.rising & np.isfinite(h.voltage) & np.isfinite(h.thermal)
        return Holds(h.levels[k], h.speed[k], h.settled[k], h.rising[k], h.voltage[k], h.thermal[k])

    m, r = usable(measured), usable(reference)
    if len(m.levels) < SHIFT_MIN_HOLDS or len(r.levels) < SHIFT_MIN_HOLDS:
        return None
    y = np.r_[m.speed, r.speed]
    cols_m = [_static_map(m, t, True) for t in SHIFT_LEVELS]
    cols_r = [_static_map(r, t, False) for t in SHIFT_LEVELS]

    def sse(i: int, j: int) -> float:
        A = np.vstack([cols_m[i], cols_r[j]])
        beta, *_ = np.linalg.lstsq(A, y, rcond=None)
        return float(np.sum((y - A @ beta) ** 2))

    n = len(SHIFT_LEVELS)
    grid = np.array([[sse(i, j) for j in range(n)] for i in range(n)])
    null = float(np.min(np.diag(grid)))
    i, j = np.unravel_index(int(np.argmin(grid)), grid.shape)
    dof = len(y) - cols_m[0].shape[1] - 2  # the map's terms and the two start levels
    f = (null - float(grid[i, j])) / max(float(grid[i, j]) / max(dof, 1), 1e-12)
    return StartLevelShift(SHIFT_LEVELS[i], SHIFT_LEVELS[j], f, float(stats.f.sf(f, 1, max(dof, 1))),
                           len(m.levels), len(r.levels))


def step_dynamics(measured: Sequence[Signals], reference: Sequence[Signals],
                  start_level: float | None = None) -> StepDynamics:
    """What changed from the reference to the measured recordings, read from their command steps
    and holds (``compare_steps`` at the recordings' grid step, ``start_level_rose``,
    ``start_level_shift``). With the measured data's fitted ``start_level``, the spin-down is
    compared again on the falling steps that end where the ESC still drives: START_LEVEL_MARGIN
    above it."""
    dts = [np.diff(s.t) for s in measured if len(s.t) > 1]
    grid = float(np.median(np.concatenate(dts))) if dts else 0.01
    driven = start_level + START_LEVEL_MARGIN if start_level is not None else None
    out = compare_steps(step_responses(measured), step_responses(reference), resolution_s=grid,
                        driven_above=driven)
    hm, hr = holds(measured), holds(reference)
    out.start_level = start_level_rose(hm, hr)
    out.start_level_shift = start_level_shift(hm, hr)
    return out

# --- motor heating: did the speed's response to the thermal state change --------------------------
HEATING_TAU_S = 120.0  #: thermal time constant of the identification (s)
#: least extra speed loss at the measured data's hottest state, as a fraction of the fitted
#: full-drive speed: a loss of speed with the winding's resistance is in proportion to the speed
#: (5 rad/s on the nominal bench's 600 rad/s; an absolute figure would be another threshold on a
#: motor that spins twice as fast)
HEATING_MIN_DROP = 0.0083
#: ... and at least this many standard errors of the fit with the holds as the independent units
#: (one-sided p = 0.0013), so that a noisy motor's 5 rad/s is not taken for heating. Neither alone
#: suffices: on tuning seed 101 a control with no heating anywhere (a hot 180 s measured load vs a
#: 120 s reference one) gives 3.5 rad/s at 3.6 standard errors; heating on seeds 100-108 gives
#: 9.3-31.6 rad/s at 8.9-39, every other case -2.3 to 1.1 standard errors
HEATING_MIN_Z = 3.0
#: least thermal state the measured data must reach (~15 K above ambient on the bench): a
#: recording that barely warms the winding cannot show its heating, and a sensitivity fitted on
#: a tiny thermal range takes up whatever else differs at that range
HEATING_MIN_STATE = 0.15


@dataclass
class Heating:
    """Speed change per unit thermal state (rad/s at full drive), on the measured and the reference."""

    measured: float
    reference: float
    hottest: float  #: largest thermal state on the measured data
    #: standard error of reference - measured (rad/s per unit), clustered by hold
    se: float = math.inf
    #: the fitted steady speed at full command and the measured data's median voltage (rad/s)
    full_speed_rad_s: float = math.inf

    @property
    def drop_rad_s(self) -> float:
        """Extra speed lost on the measured data at its hottest, beyond what the reference shows."""
        return (self.reference - self.measured) * self.hottest

    @property
    def z(self) -> float:
        """The drop in standard errors (holds as the independent units)."""
        return (self.reference - self.measured) / self.se if self.se > 0 else 0.0

    @property
    def changed(self) -> bool:
        return (self.hottest >= HEATING_MIN_STATE and self.drop_rad_s >= HEATING_MIN_DROP * self.full_speed_rad_s
                and self.z >= HEATING_MIN_Z)

    def describe(self) -> str:
        # without a battery voltage (or too few settled samples) there is no static map, so no
        # full-drive speed to take the threshold from: said in words, never "inf rad/s"
        drop = (f"{HEATING_MIN_DROP * self.full_speed_rad_s:.1f} rad/s ({100 * HEATING_MIN_DROP:.2g} % of the "
                f"{self.full_speed_rad_s:.0f} rad/s at full drive)" if math.isfinite(self.full_speed_rad_s) else
                f"{100 * HEATING_MIN_DROP:.2g} % of the full-drive speed, not computed here: no battery voltage "
                "or too few settled samples, so heating is not named;")
        return (f"at the measured data's hottest thermal state ({self.hottest:.2f}, time constant "
                f"{HEATING_TAU_S:.0f} s) the steady speed is {self.drop_rad_s:.1f} rad/s lower than the "
                f"reference's response to the same state predicts ({self.z:.1f} standard errors; named from "
                f"{drop} and {HEATING_MIN_Z:g} standard errors at a thermal state from {HEATING_MIN_STATE:g})")

    def as_dict(self) -> dict[str, float | None]:
        """(The full-drive speed None when it could not be computed: JSON has no infinity.)"""
        return {"measured_rad_s_per_unit": self.measured, "reference_rad_s_per_unit": self.reference,
                "hottest_thermal_state": self.hottest, "extra_drop_rad_s": self.drop_rad_s,
                "extra_drop_z": self.z,
                "full_drive_speed_rad_s": self.full_speed_rad_s if math.isfinite(self.full_speed_rad_s) else None}


def _static_map_terms(pwm: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``identify_heating``'s static map, one for both sets: cubic in the PWM level, voltage and
    voltage x level (levels and volts centred on the bench's middle for conditioning)."""
    p = (np.asarray(pwm, dtype=float) - 0.075) / 0.025
    v = np.asarray(v, dtype=float) - 11.5
    return np.column_stack([np.ones_like(p), p, p**2, p**3, v, v * p])


def identify_heating(measured: Sequence[Signals], reference: Sequence[Signals]) -> Heating:
    """Thermal sensitivity on the measured and on the reference data, fitted together.

    speed ~ cubic(pwm) + V + V pwm (one static map for both) + k_set * theta * duty with theta the
    ``thermal_load`` state: a battery that sags over a long run lowers the speed on both sets
    alike, so the shared voltage terms take that, and only a response to the winding's heat that
    differs between the sets goes into k_measured - k_reference. Samples at least 0.7 s after a
    command change (the rotor's dynamics do not enter)."""
    rows, ys, holds_, volts = [], [], [], []
    hottest = 0.0
    n_holds = 0
    for which, sigs in ((0, measured), (1, reference)):
        for s in sigs:
            pwm_t, pwm = s.pwm_events
            vt, vv = s.voltage_events
            th = ef.compute(ef.THERMAL_LOAD, s.t, pwm_t, pwm, vt, vv, {"tau_s": HEATING_TAU_S})
            change = np.r_[pwm_t[0], pwm_t[1:][np.diff(pwm) != 0]] if len(pwm_t) else np.zeros(1)
            k = np.searchsorted(change, s.t, side="right") - 1
            ok = ((s.t - change[np.clip(k, 0, len(change) - 1)]) >= 0.7) & np.isfinite(s.speed) \
                & np.isfinite(s.voltage) & np.isfinite(th)
            duty = throttle(s.pwm[ok], c.PWM_STOP)
            t_d = th[ok] * duty
            rows.append(np.column_stack([_static_map_terms(s.pwm[ok], s.voltage[ok]),
                                         t_d * (which == 0), t_d * (which == 1)]))
            ys.append(s.speed[ok])
            holds_.append(n_holds + k[ok])  # the hold each sample belongs to: the unit of the test
            n_holds += len(change)
            if which == 0 and ok.any():
                hottest = max(hottest, float(np.max(th[ok])))
                volts.append(s.voltage[ok])
    A, y = np.vstack(rows), np.concatenate(ys)
    if len(y) < 20:
        return Heating(0.0, 0.0, 0.0)
    beta, *_ = np.linalg.lstsq(A, y, rcond=None)
    v_med = float(np.median(np.concatenate(volts))) if volts else 11.5
    full = float(_static_map_terms(np.array([c.PWM_FULL]), np.array([v_med]))[0] @ beta[:6])
    return Heating(float(beta[6]), float(beta[7]), hottest,
                   _clustered_se(A, y - A @ beta, np.concatenate(holds_), np.array([0, 0, 0, 0, 0, 0, -1, 1])),
                   full if full > 0.0 else math.inf)


def _clustered_se(A: np.ndarray, resid: np.ndarray, cluster: np.ndarray, contrast: np.ndarray) -> float:
    """Standard error of ``contrast @ beta`` with residuals correlated within a cluster (CR1).

    By hand because the samples of one hold share a slow error (noise filtered by the rotor, the
    battery's drift), so the textbook standard error is far too small; scipy and numpy offer
    no cluster-robust covariance and statsmodels is not worth a dependency for one sandwich."""
    pinv = np.linalg.pinv(A.T @ A)
    _, inverse = np.unique(cluster, return_inverse=True)
    g = inverse.max() + 1
    if g < 3:
        return math.inf
    scores = np.zeros((g, A.shape[1]))
    np.add.at(scores, inverse, A * resid[:, None])
    n, k = A.shape
    meat = scores.T @ scores * (g / (g - 1)) * ((n - 1) / max(n - k, 1))
    var = float(contrast @ pinv @ meat @ pinv @ contrast)
    return math.sqrt(var) if var > 0 else math.inf


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
    changes = {
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
    }
    if steps is not None:
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
        for name, (chg, because) in from_steps.items():
            # too few steps at speeds the reference also has is no evidence: the fit of the whole
            # recordings is not asked instead (its spin-down time constant takes a rotor running
            # down with no drive below a raised start level, or other speeds, for a change)
            changes[name] = ((chg.change - chg.margin if chg.changed else -1.0, 0.0, because(chg)) if chg is not None
                             else (-1.0, 0.0, ""))
        if steps.spin_up is not None and steps.spin_up.changed:
            # a heavier rotor slows the falling steps too, and not by the same factor (braking and
            # driving currents differ): with the rising steps slower, slower falling ones are no
            # evidence of an ESC that does not brake (tuning benches: a lag's falls 1.2-2.5x its
            # rises, a coasting ESC's 1.5-3x), so the spin-down is not named after a lag
            changes["spin_down_asymmetry"] = (-1.0, 0.0, "")
    changes["esc_deadband"] = (meas.start_level - ref.start_level, START_LEVEL_MARGIN - 1e-9,
                               f"the rotor gets no drive below PWM {meas.start_level:.3f} on the measured data vs "
                               f"{ref.start_level:.3f} on the reference (with the identified dead time and "
                               f"spin-up/spin-down time constants)")
    order = ["esc_deadband", "rotor_lag", "input_delay", "spin_down_asymmetry"]
    if steps is not None:
        shift = steps.start_level_shift
        if steps.start_level[0]:
            # the direct evidence: no drive where the reference's rotor has it
            changes["esc_deadband"] = (1.0, 0.0, steps.start_level[1])
        elif shift is not None:
            # the settled speeds at held levels, which none of the three time quantities moves,
            # decide whether the start level rose; it is not read from how late the rotor leaves
            # rest (which a lag or a dead time also delays) nor from the fitted start level
            # (which takes a hotter winding's lost speed for a compressed throttle map)
            changes["esc_deadband"] = (1.0 if shift.changed else -1.0, 0.0, shift.describe())
        else:
            # the fitted start level is read from how late the rotor leaves rest, which a dead time
            # or a lag between the fit's grid points also delays: where the step responses show a
            # longer time constant at the same speed or a later onset, those decide first. A
            # rotor that coasts also where the ESC drives (falling steps ending above the fitted
            # start level) does not brake: that is no start level either
            order = ["rotor_lag", "input_delay", "esc_deadband", "spin_down_asymmetry"]
            if steps.spin_down_driven is not None and steps.spin_down_driven.changed:
                order = ["rotor_lag", "input_delay", "spin_down_asymmetry", "esc_deadband"]
    # the default order of precedence: a start level that rose explains a coast to zero (no
    # drive) and a compressed throttle map, which the lags would otherwise take for a slower
    # spin-down; a heavier rotor also delays the step response's apparent onset, so a lag comes
    # before a dead time; the asymmetry is measured against the set's own rising steps
    for name in order:
        if name in exclude:
            continue
        change, margin, why = changes[name]
        if change >= margin:
            return name, why
    return None, "the identified dead time and time constants did not change beyond their margins"


# --- the rule: what the identification changes in a round's verdicts -------------------------------
#: Measured residual RMSE >= this x the reference's, with no residual feature significant: the
#: response (dynamics, start level) is identified directly all the same.
GAP_RATIO = 1.5


@dataclass
class Refined:
    """A round's proposal after the identification: the effect, and its parameters when the
    identification fixed them (else the kind fits them)."""

    best: str | None
    params: dict[str, float] | None = None
    reference_params: dict[str, float] | None = None  #: the effect's parameters on the reference itself


def refine(ev: dict[str, Any], best: str | None, named: Sequence[str], measured: Sequence[Signals],
           reference: Sequence[Signals], rmse_measured: float, rmse_reference: float, cache: dict[str, Any],
           alpha: float, min_effect: float, progress: Callable[[str], None]) -> Refined:
    """Apply the identification to one round (``ev``: effect -> results.Evidence of the offered
    candidates, changed in place; ``best``: the proposal from the scores; ``cache`` keeps the
    identified dynamics across rounds). Needs reference recordings (else nothing changes):

    - motor_heating, when nothing or one of RESPONSE_EFFECTS is proposed: named when ``identify_heating``
      says its response to the thermal state changed (first: a hotter winding also brakes and
      drives a little less, which the step responses would take for a slower rotor, while no
      dynamic effect makes the steady speed depend on the thermal state);
    - the dynamic family and the start level, when the scores propose one of them
      (RESPONSE_EFFECTS), a dynamic candidate is significant on the measured data alone or the
      measured residual RMSE is GAP_RATIO x the reference's with nothing new: the one
      ``which_dynamic`` finds changed is named (at the identified parameters); when none
      changed, none of them is new (the start level included: with esc_deadband offered, the
      identification always judges it, from held levels or the fitted start level). Randomized
      benches, network path: with the scores' start-level proposal taken as it came, a slower
      rotor (seed 3) and a heating winding (seed 1) were named esc_deadband first; the
      identification alone names both right."""
    out = Refined(best)
    if not reference:
        return out
    offered = list(ev)
    if "motor_heating" in ev and (out.best is None or out.best in RESPONSE_EFFECTS):
        # a changed response to the same thermal state: the feature (driven by the command) is
        # the same on both sets, so the pooled residual score cannot see it; identified on the
        # speed directly, the measured and the reference sets fitted together
        heat = identify_heating(measured, reference)
        e = ev["motor_heating"]
        e.heating = heat.as_dict()
        progress(f"  identified heating: {heat.describe()}")
        if heat.changed:
            e.override("new", f"motor_heating: {heat.describe()}")
            out.best, out.params = "motor_heating", {"tau_s": HEATING_TAU_S}
    if out.best is not None and out.best not in RESPONSE_EFFECTS:
        return out
    if not (out.best in RESPONSE_EFFECTS
            or any(ev[k].measured_alone.p_value < alpha and ev[k].measured_alone.fraction >= min_effect
                   for k in offered if k in DYNAMIC_EFFECTS)
            or (out.best is None and rmse_measured >= GAP_RATIO * rmse_reference)):
        return out
    # (judged on the measured data alone: which dynamic effect changed is decided by identifying
    # the response directly, not by the pooled residual correction) the measured residual has
    # significant dynamic structure, or is far larger than the reference's with no residual
    # feature to explain it (a changed static map, as a start level, re-weights into the null
    # columns); whether anything is NEW is decided by comparing the identified response with
    # the reference's
    if out.best is None:
        dyn_sig = [k for k in offered if k in DYNAMIC_EFFECTS and ev[k].measured_alone.p_value < alpha]
        out.best = max(dyn_sig, key=lambda k: ev[k].measured_alone.fraction, default=None)
    gap_txt = (f"({out.best}'s feature removes {100 * ev[out.best].measured_alone.fraction:.0f} % of it, "
               f"p = {ev[out.best].measured_alone.p_value:.2g})" if out.best is not None else
               f"(its RMSE is {rmse_measured:.1f} rad/s vs {rmse_reference:.1f} rad/s on the reference)")
    # lag, dead time and spin-down all change the response to a command change, and a residual
    # explained by one is partly explained by the others: which one CHANGED is decided by
    # identifying the response itself on the measured and the reference data
    if "dynamics" not in cache:
        progress("  a dynamic effect or the ESC start level is in question: identifying dead time, "
                 "start level and spin-up/spin-down time constants on the measured and the reference "
                 "recordings")
        dyn = (identify_dynamics(measured), identify_dynamics(reference))
        if "esc_deadband" in ev:
            for dy, sigs in zip(dyn, (measured, reference), strict=True):
                dy.start_level = identify_start_level(sigs, dy)
        cache["dynamics"] = dyn
        cache["steps"] = step_dynamics(measured, reference,
                                       start_level=dyn[0].start_level if "esc_deadband" in ev else None)
    m, r = cache["dynamics"]
    steps: StepDynamics = cache["steps"]
    choice, why = which_dynamic(m, r, exclude=[*named, *(set(c.EFFECTS) - set(offered))], steps=steps)
    info = {"measured": m.as_dict(), "reference": r.as_dict(), "step_responses": steps.as_dict(),
            "changed": choice, "because": why}
    progress(f"  identified dynamics: {why}")
    if choice is None:
        # the response to the command did not change: the residual's dynamic structure is the
        # model's own (it is there on the reference too), not a new effect
        for k in RESPONSE_EFFECTS:
            if k in ev and ev[k].verdict in ("new", "structural"):
                ev[k].verdict = "not new (identified dynamics unchanged)"
                ev[k].dynamics = info
        others = [k for k in offered if k not in RESPONSE_EFFECTS and ev[k].verdict == "new"]
        out.best = max(others, key=lambda k: ev[k].measured.fraction, default=None)
    elif choice not in named and choice in ev:
        ev[choice].override("new", f"{choice}: {why}; the model's residual on the measured data "
                                   f"follows the command {gap_txt}")
        out.best = choice
    if out.best is not None and choice == out.best:
        out.params = {"rotor_lag": {"tau_s": max(m.tau_up_s, 0.02)},
                      "spin_down_asymmetry": {"tau_up_s": max(m.tau_up_s, 0.02),
                                              "tau_down_s": max(m.tau_down_s, 0.04)},
                      "esc_deadband": {"threshold": m.start_level},
                      # the model already has the reference's own dead time: add the change
                      "input_delay": {"delay_s": max(steps.dead_time.change if steps.dead_time is not None
                                                     else m.delay_s - r.delay_s, 0.01)},
                      }.get(choice)
        if choice == "esc_deadband":
            out.reference_params = {"threshold": r.start_level}
            shift = steps.start_level_shift
            if shift is not None and shift.changed:
                # the settled holds' levels: read on a finer grid reaching further than the
                # whole-recording fit's, and not moved by the dynamics
                out.params, out.reference_params = {"threshold": shift.measured}, {"threshold": shift.reference}
        elif choice == "input_delay":  # the delay added is the change: the reference has none of it
            out.reference_params = {"delay_s": 0.0}
    if out.best is not None:
        ev[out.best].dynamics = info
    return out
