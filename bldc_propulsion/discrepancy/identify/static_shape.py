"""The static shape at held command levels: where the rotor gets no drive, and the ESC start level.

An ESC gives no drive below its start level, so a start level that rose shows at held levels in
two ways none of the time quantities (lag, dead time, spin-down) mimics: the rotor runs down to
rest at a level where the reference's spins (``start_level_rose``), and the throttle map above it
is compressed, which the settled speeds show (``start_level_shift``: one static map for both
sets, with its voltage and thermal terms, and an F-test of a second start level).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import stats

from ... import contract as c
from ...core import effect_features as ef
from ...core.features import zero_order_hold
from ...physics.plant import throttle
from ...physics.scales import centred_voltage
from ...recordings import Signals
from ..residuals import robust_sigma
from .heating import HEATING_TAU_S
from .steps import STEP_ALPHA, STEP_HOLD_S, at_stop, held_levels

#: A measured hold "gets no drive" when the rotor ends it (not rising) below NO_DRIVE_FRACTION of
#: the speed the reference's rotor settles at for that level: a lower supply or a hotter winding
#: lowers the speed by some per cent, only the loss of drive halves it.
NO_DRIVE_FRACTION = 0.5
#: A measured hold ends "at rest" below this share of the reference's speed at its level: what
#: bounds the start level from below (``no_drive_bounds``). Half the speed is no drive's sign,
#: not its proof: just above a raised start level the throttle map gives a little.
AT_REST_FRACTION = 0.1
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
    """Held command levels (each at least STEP_HOLD_S, above the stop level: ``at_stop``) and the rotor at their end."""

    levels: np.ndarray  #: PWM level
    speed: np.ndarray  #: speed at the end of the hold (rad/s)
    settled: np.ndarray  #: the speed no longer drifted
    rising: np.ndarray  #: the speed was still rising (spinning up towards the level's speed)
    voltage: np.ndarray  #: mean filtered battery voltage over the hold's end (V; NaN if none)
    thermal: np.ndarray  #: ``thermal_load`` state at the hold's end (HEATING_TAU_S)
    #: the lowest level the rotor was seen leave rest at on a rising command (``leaves_rest_at``;
    #: inf: never seen): the ESC drives there and at every level above
    driven_from: float = math.inf


def holds(signals: Sequence[Signals]) -> Holds:
    """Every hold of at least STEP_HOLD_S above the stop level (``at_stop``) with the rotor's state at its end."""
    rows = []
    for s in signals:
        ok = np.isfinite(s.speed)
        if len(s.pwm_events[0]) < 2 or not ok.any():
            continue
        pwm_t, pwm = s.pwm_events
        vt, vv = s.voltage_events
        th = ef.compute(ef.THERMAL_LOAD, s.t, pwm_t, pwm, vt, vv, {"tau_s": HEATING_TAU_S})
        tc, lv, ends = held_levels(s)
        for k in range(len(tc)):
            if ends[k] - tc[k] < STEP_HOLD_S or at_stop(float(lv[k])):
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
    out = Holds(a[:, 0], a[:, 1], a[:, 2].astype(bool), a[:, 3].astype(bool), a[:, 4], a[:, 5])
    moving = _moving_speed(out)
    if moving > 0.0:
        out.driven_from = min((leaves_rest_at(s, moving) for s in signals), default=math.inf)
    return out


#: How long the rotor must have been at rest before a command rise for that rise to be a start
#: from rest (a rotor still coasting down is turned by what it had, not by the drive).
REST_BEFORE_S = 0.3


def leaves_rest_at(s: Signals, moving_rad_s: float) -> float:
    """The lowest command level at which the rotor was seen leaving rest (first above
    ``moving_rad_s`` after REST_BEFORE_S below it) while the command only rose from where the
    rotor was at rest; inf when never seen. A start up a slow ramp (a sweep from stop) places
    the level the ESC first drives at, a step from rest bounds it from above: either way the ESC
    drives at that level, and its map rises with the level, so it drives at every level above.
    The tachometer reports a turning rotor a revolution late, so the level is, if anything, high.
    The level is read where the rotor last left rest before the command stopped rising, and it
    must have turned since for REST_BEFORE_S: a start attempt that fails, or a glitch of the
    speed, is no drive."""
    pt, pv = s.pwm_events
    w = np.nan_to_num(s.speed, nan=0.0)
    best, k, n = math.inf, 1, len(pt)
    while k < n:
        if at_stop(float(pv[k])) or pv[k] <= pv[k - 1]:
            k += 1
            continue
        before = (s.t >= pt[k] - REST_BEFORE_S) & (s.t < pt[k])
        j = k
        while j + 1 < n and pv[j + 1] >= pv[j]:
            j += 1
        if pt[k] >= REST_BEFORE_S + s.t[0] and before.sum() >= 3 and not (w[before] > moving_rad_s).any():
            end = pt[j + 1] if j + 1 < n else s.t[-1]
            inside = np.flatnonzero((s.t >= pt[k]) & (s.t < end))
            still = np.flatnonzero(w[inside] <= moving_rad_s)
            # the rotor turns from the sample after the last one at rest to the end of the rise
            after = int(still[-1]) + 1 if len(still) else 0
            if after < len(inside) and end - s.t[inside[after]] >= REST_BEFORE_S:
                t_on = s.t[inside[after]]
                best = min(best, float(zero_order_hold(pt, pv, np.array([t_on]))[0]))
        k = j + 1
    return best


def _moving_speed(h: Holds) -> float:
    """The speed a rotor must exceed to count as turning: SPINNING_MIN_SHARE of the fastest
    settled hold (0 when none settled)."""
    return SPINNING_MIN_SHARE * float(np.max(h.speed[h.settled], initial=0.0))


def _spinning(h: Holds) -> np.ndarray:
    """The holds at which the rotor settles spinning: settled, not rising, above
    ``_moving_speed``."""
    return h.settled & ~h.rising & (h.speed > _moving_speed(h))


def lowest_spinning_level(h: Holds) -> float | None:
    """The lowest held level at which the rotor settles spinning (``_spinning``): from there up
    the ESC drives it. None when no hold settles spinning."""
    spin = _spinning(h)
    return float(np.min(h.levels[spin])) if spin.any() else None


def start_level_rose(measured: Holds, reference: Holds) -> tuple[bool, str]:
    """Whether the measured rotor gets no drive at a level where the reference's has it, and why.

    An ESC gives no drive below its start level: the rotor runs down to rest there (braked or
    coasting, however long that takes) whatever it did before. A measured hold at a level within
    the range where the reference's rotor settles spinning, ending (not rising) below
    NO_DRIVE_FRACTION of the reference's speed at that level, had no drive: the start level rose.
    Read from the holds, not from a fit of the throttle map (which the network re-weights, and a
    lag would take for a slower spin-down). Below the levels where the reference's rotor settles
    spinning, a measured rotor at rest at the end of a hold SHIFT_MIN_RISE or more above the
    level the reference's rotor was seen leaving rest at (``_at_rest_where_driven``) had no drive
    either: a coasting rotor takes seconds to settle at a low level, a start from rest does not."""
    rest = _at_rest_where_driven(measured, reference)
    if rest.any():
        k = int(np.argmax(np.where(rest, measured.levels, -np.inf)))
        return True, (f"the rotor is at rest at the end of {int(rest.sum())} held level(s) up to PWM "
                      f"{measured.levels[k]:.4f} on the measured data, where the reference's rotor leaves rest "
                      f"from PWM {reference.driven_from:.4f} up")
    found = _no_drive(measured, reference)
    if found is None:
        return False, ("the reference recordings hold too few levels at which the rotor settles spinning: "
                       "the holds cannot show a start level")
    none, _, _, expect, lv_r = found
    if not none.any():
        # below the reference's lowest settled hold only a rotor at rest where the reference's
        # leaves rest is evidence: say where the holds stop judging
        below = int(np.sum(measured.levels < lv_r[0]))
        judged = min(lv_r[0], reference.driven_from + SHIFT_MIN_RISE)
        seen = (f"; below it the reference's rotor leaves rest from PWM {reference.driven_from:.4f}, and no "
                f"measured hold from PWM {judged:.4f} up ends at rest" if judged < lv_r[0] else "")
        return False, (f"at every held level from PWM {lv_r[0]:.4f} (where the reference's rotor settles "
                       f"spinning) the measured rotor spins as well{seen}; a start level below PWM {judged:.4f} "
                       f"cannot show in these recordings ({below} measured hold(s) lie below PWM {lv_r[0]:.4f}: "
                       f"holds there long enough to settle, or starts from rest, on both sets would show one)")
    k = int(np.argmax(np.where(none, measured.levels, -np.inf)))
    return True, (f"the rotor runs at less than half the reference's speed, or stops, at {int(none.sum())} held "
                  f"level(s) up to PWM {measured.levels[k]:.4f} on the measured data ({measured.speed[k]:.0f} rad/s "
                  f"at the end of the hold, not rising, where the reference's settles at {expect[k]:.0f} rad/s; "
                  f"its rotor spins from PWM {lv_r[0]:.4f})")


def _at_rest_where_driven(measured: Holds, reference: Holds) -> np.ndarray:
    """The measured holds that end at rest (not rising, below SPINNING_MIN_SHARE of the
    reference's fastest settled hold) at least SHIFT_MIN_RISE above the lowest level the
    reference's rotor was seen leaving rest at: the reference's ESC drives there, and a drive
    that turned the reference's rotor from rest would turn this one (a supply low enough to
    stall it there would show at every level)."""
    moving = _moving_speed(reference)
    if not math.isfinite(reference.driven_from) or moving <= 0.0:
        return np.zeros(len(measured.levels), bool)
    return (~measured.rising & (measured.speed < moving)
            & (measured.levels >= reference.driven_from + SHIFT_MIN_RISE - 1e-9))


def _no_drive(measured: Holds, reference: Holds
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """The measured holds with no drive (below NO_DRIVE_FRACTION of the reference's speed at
    their level), those at rest (below AT_REST_FRACTION of it) and those settled with drive,
    within the levels where the reference's rotor settles spinning; the speed the reference's
    gives at each measured level, and those reference levels (sorted). None when the reference
    holds too few such levels."""
    spin = _spinning(reference)
    if spin.sum() < 2:
        return None
    order = np.argsort(reference.levels[spin])
    lv_r, w_r = reference.levels[spin][order], reference.speed[spin][order]
    # the reference's rotor at rest at a level bounds its start level from below: levels at or
    # below that are no evidence
    inside = (measured.levels >= lv_r[0]) & (measured.levels <= lv_r[-1]) & ~measured.rising
    expect = np.interp(measured.levels, lv_r, w_r)
    none = inside & (measured.speed < NO_DRIVE_FRACTION * expect)
    rest = inside & (measured.speed < AT_REST_FRACTION * expect)
    drive = inside & measured.settled & (measured.speed >= NO_DRIVE_FRACTION * expect)
    return none, rest, drive, expect, lv_r


def no_drive_bounds(measured: Holds, reference: Holds) -> tuple[float, float] | None:
    """Where the measured start level lies as the holds bound it: above the highest held level
    where the rotor ends at rest (where the reference's spins), at or below the lowest held
    level above that with drive (inf: none held). None when no held level ends at rest."""
    found = _no_drive(measured, reference)
    rest = _at_rest_where_driven(measured, reference)
    drive = np.zeros(len(measured.levels), bool)
    if found is not None:
        rest, drive = rest | found[1], found[2]
    if not rest.any():
        return None
    floor = float(np.max(measured.levels[rest]))
    above = drive & (measured.levels > floor)
    return floor, float(np.min(measured.levels[above])) if above.any() else math.inf


def start_level_within(level: float, bounds: tuple[float, float] | None) -> float:
    """``level`` (a fitted start level) moved into the holds' ``bounds`` when it lies outside:
    to the middle of the gap between the highest level with no drive and the lowest with it (the
    holds say no more), or one SHIFT_STEP above the former when no level with drive is
    held above it. A start level at or below a level where the rotor got no drive cannot be."""
    if bounds is None:
        return level
    floor, ceiling = bounds
    if floor < level <= ceiling:
        return level
    return 0.5 * (floor + ceiling) if math.isfinite(ceiling) else floor + SHIFT_STEP


#: ESC start levels (PWM level) the held levels' static map is fitted at (start_level_shift): from
#: PWM_STOP to well past any start level an ESC ships with, in steps of SHIFT_STEP (10 us of pulse).
SHIFT_STEP = 0.0005
SHIFT_LEVELS = tuple(round(c.PWM_STOP + SHIFT_STEP * k, 4) for k in range(41))  # 0.0500 ... 0.0700
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
    speed, below the start level), d, d^2, d^3 and their change with the supply (V - 11.5 V) d, d^2,
    and a response to the winding's thermal state per set, theta d (a hotter winding loses speed in
    proportion to the load, a raised start level loses it most at low levels: they do not trade)."""
    d = throttle(h.levels, start)
    v = centred_voltage(h.voltage)
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
