"""Online adaptation of a physics model's parameters from the measured rotor speed (issue 34 item 1).

A fitted physics model is right for the vehicle it was fitted on; in flight a propeller chips or
bends and a bearing wears, and the model's speed drifts away from the measured one. With the
measured speed (``rotor/speed``) the estimator can follow such a change: ``PhysicsAdapter``
estimates a few physical parameters online and the prediction (and the thrust) uses them.

What is adapted (``ADAPTED``, the contract's fault names), and why only these:

* ``propeller_damage``: the fractional loss of the propeller's CT and CP (its drag, so the speed;
  the thrust coefficient b scales with CT, so the thrust follows a loss: ``thrust_factor``);
* ``bearing_friction``: a factor on the motor's friction torque (the no-load current).

Both are identifiable from the speed alone once the rotor visits two operating points: the drag
grows with w^2, the friction is constant. And from the voltage, not the speed:

* ``pack_resistance``: the pack's series resistance (ohm). The model is fed the filtered battery
  voltage and undoes the filter's lag with its series resistance (``physics.plant.Supply``): a
  pack whose resistance rose sags more in every current step than the model adds back, so the
  motor gets less voltage than the model thinks until the filter catches up (a 2 s battery filter:
  seconds). In steady state the resistance cancels, so the speed barely tells it; the voltage
  does: the filtered voltage against the model's supply current through the same filter is a
  straight line of slope -R (``_Sag``: recursive least squares with forgetting, the offset fitted
  along). Adapted whenever the model undoes a filter, as a change: the model's resistance moves
  by the measured one's change from its baseline (its first ``pack_baseline_s`` of confident
  estimates), as the model's own was fitted along with its other constants (or held at a
  default), which setting the measured value in its place would undo; and only once the change
  is large (``pack_significant``), as the estimate carries the model's own current error.

Left out: the winding's
resistance (``motor_heating``): in the steady torque balance it scales the drag and the friction
torque alike, close to a mix of the two adapted, which absorb most of what it does to the speed;
not all of it (its share grows with the current and the duty, the ESC's and the pack's resistance
do not warm): on tuning benches 1 and 2, four flights with a 30 K rise, the best mix left 1.3-2.6
rad/s RMS of the 6-9 rad/s the rise did, where the winding's own direction left 0.1-0.2 rad/s. A
third parameter along it was tried (prior sigma 30 K, then 10 K) and cost more than it gained:
with the model's own error the three wander along the direction the mix nearly shares (a healthy
flight read a propeller 41 % gone, friction x5 and the winding 85 K hotter, the speed still right
and the thrust not), and on benches 1-3 the runs back within 1.2x of the healthy twin's RMSE from
10 s on fell, propeller 6/6 -> 3/6 and 4/6, heating 5/6 -> 4/6 and 0/6. What the adapter
cannot learn it can be told: with the health monitor watching (``core.health.HealthStream``), a
change it names is taken into the model (``take_named``), a heating as a fixed rise of the
winding's temperature (``heating_k``), set, not learnt, so nothing wanders along it; and a pack
whose resistance rose, which the monitor sizes within seconds where the voltage's own estimate
(below) takes 10-20 s, as a fixed addition to the series resistance (``pack_named_ohm``). A
propeller or a friction the monitor names restarts theta from before the onset with the named
size on the named parameter: at one operating point the two are one direction to the speed, and
the monitor's window, longer than the adapter's memory, tells them apart. A heating waits longest
for its name (a friction explains it alike for seconds): while a change is being named and a hot
winding leads, that lead is taken provisionally and undone if the change is named otherwise or
not at all.

How: the model's speed is linear in theta near a linearisation point theta_lin,
w(theta) = w(theta_lin) + S (theta - theta_lin), with S = d speed / d theta from the physics
stepped once per parameter with it perturbed (``core.health.PhysicsTwins``' lanes, only the
adapted ones). theta is estimated by recursive least squares with exponential forgetting in time
(memory ``memory_s``), bounded:

* theta is kept within physical bounds (``BOUNDS``) after every update, projected on them in the
  covariance's metric (``_projected``: a parameter held at its bound passes what it could not
  take to the one the covariance ties it to);
* the covariance never exceeds the prior (``prior_sigma``): no windup however long the
  excitation lacks; forgetting runs only on samples that update (the rotor turning, the speed
  fresh), and at most ``_MAX_FORGET_S`` of it per sample, so a gap or a stop does not inflate it;
* an innovation is limited to ``innovation_limit`` of its expected spread, so a tachometer glitch
  moves theta little;
* frozen (no update) while the model's lanes settle after their start, while the rotor is at rest
  or below the ESC start (the speed carries nothing on the parameters there), and, as the
  estimator sees it, while no measured speed comes (``MEASURED_SPEED_MAX_AGE_S``).

When theta has moved more than a lane's own step from theta_lin (or the resistance more than
``pack_relinearise`` of itself), the lanes are rebuilt at theta
(``_Lanes.rebase``, their states kept), so a large change stays right beyond the linear range.
The prediction keeps the estimator's own offline speed (its stream, interpolated) and adds the
lanes' difference ``w(theta) - w(0)``: a lane stepped at theta = 0 (``_ref``) gives w(0) once theta_lin
is not 0. The lanes are sampled at prediction times and at the measured speeds' stamps, which lag
them by a batch and half a revolution: a short history (``history_s``) aligns the two.

A guard keeps the adaptation from costing accuracy where it learns the wrong thing (a change it
cannot represent, such as a winding running hot, moves theta along the nearest direction it
has): at every measured speed the adapted and the offline predictions are both scored on it
before theta learns from it (a priori errors, so the adapted one is not judged on what it just
fitted), as squared errors forgotten over ``memory_s``, the adapter's own memory. The correction
(speed and thrust) applies only while the adapted scores no worse (``in_use``); theta goes on
learning either way, so the adapted prediction comes back as soon as it is the better one. Where
theta does not learn (below the speed floor, starting or stopping: a coast-down, the ESC's dead
band) the two are scored apart (``in_use_low``): theta learnt at speed may be wrong there (a
friction read from the driven range where it is confounded with drag shows in a coast), and a
coast of a second or two is too short to outweigh the guard's seconds of driven flight. Random
steps, healthy flights, adapted over offline RMSE: benches 308-311 worst 1.12 -> 0.98x, fresh
benches 320-323 1.07 -> 1.01x (within 1.05x 7/8 -> 8/8). The price there: one tripled friction
1.76 -> 3.34x its twin (the coasts' score picked the offline model while theta had it right).

``reset()`` returns to the offline model (theta = 0). ``adapted_plant()`` is the physics model
with the adapted constants (``replay --save-adapted`` writes it).
"""

from __future__ import annotations

import bisect
import collections
import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Generic, TypeVar

from ..errors import BadInputError
from ..physics.params import PlantParams
from ..physics.plant import REST_SPEED_RAD_S
from ..physics.plant_model import PlantModel
from .health import PACK_REFERENCE_OHM, PhysicsTwins, heated, require_physics

#: The parameters adapted from the speed (the contract's fault names), in PhysicsTwins' lane order.
SPEED_ADAPTED: tuple[str, ...] = ("propeller_damage", "bearing_friction")
#: Everything adapted, in the order published: the speed's, then the pack's (from the voltage).
ADAPTED: tuple[str, ...] = (*SPEED_ADAPTED, "pack_resistance")
#: What a published value is: the propeller's fractional loss of CT and CP; the factor on the
#: friction torque (1: the offline model's); the pack's series resistance. Internally theta is
#: the loss and the factor - 1.
UNITS: dict[str, str] = {"propeller_damage": "fraction", "bearing_friction": "factor", "pack_resistance": "ohm"}
#: predicted/adapted's layout.dim[0].label (the node and replay publish ``values()`` in ADAPTED order)
ADAPTED_LABEL = ",".join(ADAPTED)
#: theta's physical bounds: a propeller between 30 % stronger and half gone (sim/faults.py
#: injects up to 0.9, but half the thrust gone is no flight to adapt to); friction torque >= 0,
#: at most 50x (the simulator's range).
BOUNDS: tuple[tuple[float, float], ...] = ((-0.3, 0.5), (-1.0, 49.0))
#: The series resistance's bounds, as factors on the model's (or, without one, on the nominal
#: bench's 0.035 ohm): the health monitor's plausible range of a pack's sag per ampere.
PACK_BOUNDS: tuple[float, float] = (0.2, 10.0)
#: Most seconds of forgetting one update applies: a gap in the speed or a stop forgets no more.
_MAX_FORGET_S = 0.1
#: While theta_lin = 0 the reference lane is only stepped this often (s), to consume its inputs.
_REF_CATCH_UP_S = 1.0
#: A lane's step may move the speed by at most this share of it for the sample to be learned from.
_LINEAR_SHARE = 0.1
#: The model's slope is taken between two measured speeds at most this far apart (s).
_SLOPE_GAP_S = 0.1
#: theta's history, for what it was at a named change's onset: kept this long (s; the monitor
#: names a change at most name_within_s after its onset, found at most a window after it), a
#: value at most every _THETA_STEP_S.
_THETA_HISTORY_S = 60.0
_THETA_STEP_S = 0.2
#: theta is taken back to what it was this long (s) before a named change's onset: the monitor
#: dates the onset from its residual, which a change may move seconds after the adapter's theta
#: did (tuning bench 2, a flight's propeller loss: its onset dated 2.9 s late, theta at the bound
#: of the friction by then)
_BEFORE_ONSET_S = 5.0
#: A named propeller or friction is checked against the adapter's updates of this long (s) before
#: the name: refused if the named model's squared errors there exceed _TAKE_CHECK times theta's.
_RECENT_S = 3.0
_RECENT_N = 4096  #: updates kept for it (trimmed to _RECENT_S when read): 3 s up to 1.3 kHz of speeds
_TAKE_CHECK = 4.0
_V = TypeVar("_V")
#: The winding's named rise (K) is taken within these bounds (a model fitted hot may see it cool).
HEATING_BOUNDS_K: tuple[float, float] = (-60.0, 200.0)
#: A refined size of a named heating moves the lanes once it differs this much (K) from theirs.
_HEATING_REBUILD_K = 2.0


@dataclass(frozen=True)
class AdaptationConfig:
    """How the adapter learns (times in s). Tuned on bench seeds 1-3 (benchmarks/bench_adaptation.py)."""

    #: forgetting time constant: data this old weigh 1/e (a change is followed within a few)
    memory_s: float = 4.0
    #: one measured speed's error, as a share of the model's full-drive speed (the tachometer's
    #: noise and the model's own error at a point)
    noise_fraction: float = 0.02
    #: a sample's error grows with how fast the model's speed moves: an error of the model's timing
    #: (dead time, rotor lag) of this long (s) counts as noise, not as a parameter's change
    timing_s: float = 0.3
    #: theta's sigma at the start and its ceiling (propeller loss fraction, friction factor).
    #: The friction's 0.5: a bearing that triples its friction (theta 2) is 4 sigma of it; at 0.2
    #: it was 10, and the ceiling held the gain so low that the adapted speed took 22 s (median)
    #: to come within 1.2x of the healthy twin's after it, in flight on tuning benches 1-3 (9
    #: runs; 9.5 s at 0.5; within 1.2x from 10 s on, every fault: 25 -> 28 of 36 runs in flight,
    #: 18 -> 21 on random steps; 1.0 did as 0.5). The price: the friction takes a share of a
    #: propeller loss at first (test_adaptation's case: 1.7 -> 2.4 rad/s after it, 0.8 before)
    prior_sigma: tuple[float, float] = (0.1, 0.5)
    #: an innovation beyond this many of its expected sigmas counts as this many
    innovation_limit: float = 4.0
    #: no update while the model's speed is below this share of its full-drive speed (rest,
    #: dead band: the sensitivities vanish and the tachometer's noise differs)
    min_speed_fraction: float = 0.15
    #: no update for this long after the lanes start (they start at rest, the rotor may not)
    settle_s: float = 1.0
    #: the lanes are rebuilt at theta once it moves this far from where they are (the lanes' steps)
    relinearise: tuple[float, float] = (0.05, 0.5)
    #: how far back a measured speed's stamp may lie behind the lanes (s)
    history_s: float = 0.5
    #: the pack's resistance: forgetting time constant (s), the voltage's error per row (V: the
    #: model's current is off by its own error; the sag of that), the prior's sigma as a share of
    #: the model's resistance, the share it moves before the lanes are rebuilt, and a row's spacing
    pack_memory_s: float = 5.0
    pack_noise_v: float = 0.05
    pack_prior: float = 1.0
    pack_relinearise: float = 0.15
    pack_row_s: float = 0.05
    #: the pack's baseline: the estimate's mean over this long (s) once its sigma is below
    #: ``pack_confident`` of the model's resistance; the model's resistance moves by the change from it
    pack_baseline_s: float = 10.0
    pack_confident: float = 0.2
    #: the change counts (moves the model) once it exceeds this share of the baseline, and until it
    #: falls back under half of it: the estimate swings +-20 % in a healthy flight (the model's
    #: current is off by its own error), a pack's fault is a step of tens of percent
    pack_significant: float = 0.35

    def __post_init__(self) -> None:
        for name in ("memory_s", "noise_fraction", "innovation_limit", "settle_s", "history_s", "timing_s",
                     "pack_memory_s", "pack_noise_v", "pack_prior", "pack_relinearise", "pack_row_s",
                     "pack_baseline_s", "pack_confident", "pack_significant"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0.0) and not (name in ("settle_s", "timing_s") and v == 0.0):
                raise BadInputError(f"adaptation {name}: {v!r} must be a finite number > 0")
        for name in ("prior_sigma", "relinearise"):
            v = getattr(self, name)
            if len(v) != len(SPEED_ADAPTED) or not all(math.isfinite(x) and x > 0.0 for x in v):
                raise BadInputError(f"adaptation {name}: {v!r} must be {len(SPEED_ADAPTED)} finite numbers > 0")
        if not 0.0 <= self.min_speed_fraction < 1.0:
            raise BadInputError(f"adaptation min_speed_fraction: {self.min_speed_fraction!r} must be in [0, 1)")


def ct_factor(loss: float) -> float:
    """CT adapted / CT offline (and so b's) for the propeller's adapted ``loss``: it follows a loss
    only. A damaged propeller loses CT and CP; none gains them. A negative loss is theta[0]
    standing in for what it cannot name (a winding running hot moves it to about -0.09, the more
    drag the same slower rotor a hotter winding gives), where the propeller's CT has not changed:
    scaling b up with it doubled the thrust's error after a 30 K rise on randomized benches."""
    return 1.0 - max(loss, 0.0)


def adapted_params(params: PlantParams, theta: Sequence[float], friction_reference_a: float,
                   pack_ohm: float | None = None, heating_k: float = 0.0) -> PlantParams:
    """``params`` with the propeller's CP reduced by theta[0], its CT by ``ct_factor``,
    friction_reference_a * theta[1] amperes of no-load current (friction) added (at least 0),
    given, the series resistance ``pack_ohm``, and the winding ``heating_k`` hotter (``heated``)."""
    rs = params.battery_series_resistance_ohm if pack_ohm is None else pack_ohm
    if heating_k:
        params = heated(params, heating_k)
    return dataclasses.replace(params, propeller_ct=params.propeller_ct * ct_factor(theta[0]),
                               propeller_cp=params.propeller_cp * (1.0 - theta[0]),
                               motor_no_load_current_a=max(params.motor_no_load_current_a
                                                           + friction_reference_a * theta[1], 0.0),
                               battery_series_resistance_ohm=rs)


def finite_or_none(x: float) -> float | None:
    """x, or None (JSON's null) for what is not known (NaN)."""
    return x if math.isfinite(x) else None


def _rls2_step(P: list[list[float]], p_max: Sequence[float], forget_s: float, memory_s: float,
               s0: float, s1: float, e: float, r: float, limit: float) -> tuple[float, float]:
    """One step of two-parameter recursive least squares, for the speed's parameters and the
    pack's: P (its upper triangle kept, updated in place) first forgotten over ``forget_s`` of a
    ``memory_s`` memory with each variance capped at its prior ``p_max`` (D P D keeps P positive
    semidefinite), then updated on the regressor (s0, s1) with noise variance r. Returns the
    parameters' increments for the innovation e, limited to ``limit`` of its expected sigma.
    Plain floats: ~1 us, where numpy's per-call overhead on 2x2 arrays costs ~20 us."""
    p0, p1 = P
    p00, p01, p11 = p0[0], p0[1], p1[1]
    if forget_s > 0.0:
        grow = math.exp(forget_s / memory_s)
        p00 *= grow
        p01 *= grow
        p11 *= grow
        d0 = min(1.0, math.sqrt(p_max[0] / p00)) if p00 > 0.0 else 1.0
        d1 = min(1.0, math.sqrt(p_max[1] / p11)) if p11 > 0.0 else 1.0
        p00 *= d0 * d0
        p01 *= d0 * d1
        p11 *= d1 * d1
    ps0 = p00 * s0 + p01 * s1
    ps1 = p01 * s0 + p11 * s1
    den = r + s0 * ps0 + s1 * ps1
    lim = limit * math.sqrt(den)
    e = min(max(e, -lim), lim)
    k0, k1 = ps0 / den, ps1 / den
    p0[0] = p00 - k0 * ps0
    p0[1] = p01 - k0 * ps1
    p1[1] = p11 - k1 * ps1
    return k0 * e, k1 * e


def _projected(P: list[list[float]], x0: float, x1: float) -> tuple[float, float]:
    """(x0, x1) projected on ``BOUNDS`` in the metric of the covariance P (its upper triangle):
    the box's point nearest in P^-1, the estimate's most likely value within the bounds. Clipping
    each alone broke a propeller loss on a randomized bench: the friction's first move took the
    error, hit its lower bound within 2 s, and the clipped remainder, which the covariance ties to
    a larger loss, never reached the propeller (its loss went negative and stayed there for 7 s).
    On a box in two dimensions the nearest point is the estimate (if inside) or on an edge, where
    it is the conditional mean given that bound, clipped to the edge: the least of those four."""
    (lo0, hi0), (lo1, hi1) = BOUNDS
    if lo0 <= x0 <= hi0 and lo1 <= x1 <= hi1:
        return x0, x1
    p00, p01, p11 = P[0][0], P[0][1], P[1][1]
    det = p00 * p11 - p01 * p01
    if not (p00 > 0.0 and p11 > 0.0 and det > 0.0):  # degenerate: each alone
        return min(max(x0, lo0), hi0), min(max(x1, lo1), hi1)
    best, out = math.inf, (x0, x1)
    for c0, c1 in ((lo0, None), (hi0, None), (None, lo1), (None, hi1)):
        if c0 is not None:
            y0, y1 = c0, min(max(x1 + p01 / p00 * (c0 - x0), lo1), hi1)
        else:
            assert c1 is not None
            y0, y1 = min(max(x0 + p01 / p11 * (c1 - x1), lo0), hi0), c1
        d0, d1 = y0 - x0, y1 - x1
        dist = (p11 * d0 * d0 - 2.0 * p01 * d0 * d1 + p00 * d1 * d1) / det
        if dist < best:
            best, out = dist, (y0, y1)
    return out


class _History(Generic[_V]):
    """A value's recent past: at most one per ``_THETA_STEP_S`` (the latest value stands for its
    step), kept ``_THETA_HISTORY_S``; for what it was before a named change's onset."""

    def __init__(self) -> None:
        self.t: list[float] = []  #: times (s)
        self.values: list[_V] = []

    def keep(self, t: float, value: _V) -> None:
        """The value at t (s)."""
        ht = self.t
        if ht and t - ht[-1] < _THETA_STEP_S:
            self.values[-1] = value
            return
        ht.append(t)
        self.values.append(value)
        old = bisect.bisect_left(ht, t - _THETA_HISTORY_S) - 1  # the value at the cut-off kept
        if old > 64:  # amortised
            del ht[:old], self.values[:old]

    def at(self, t: float, default: _V) -> _V:
        """The value at t (s): the latest kept at or before t, else (t before the history) the
        oldest kept; ``default`` without a history."""
        if not self.t:
            return default
        return self.values[max(bisect.bisect_right(self.t, t) - 1, 0)]


class _Score:
    """The guard's tally: both predictions' squared errors on the measured speeds (rad/s)^2,
    forgotten in time, and the latest time scored."""

    __slots__ = ("adapted", "offline", "t")

    def __init__(self) -> None:
        self.t: float | None = None
        self.offline = self.adapted = 0.0

    def add(self, t: float, error_offline: float, e_adapted: float, memory_s: float) -> bool:
        """Both errors at t (s), the earlier ones forgotten over memory_s; whether the adapted
        prediction scores no worse."""
        last, self.t = self.t, t
        keep = math.exp(-(t - last) / memory_s) if last is not None and t > last else 1.0
        self.offline = keep * self.offline + error_offline * error_offline
        self.adapted = keep * self.adapted + e_adapted * e_adapted
        return self.adapted <= self.offline


class _Sag:
    """The pack's series resistance from the filtered voltage v and the model's supply current
    through the same filter i: v = e - R i + noise, (e, R) by recursive least squares with
    exponential forgetting in time, each variance capped at its prior (no windup while the current
    holds still), innovations limited to ``limit`` sigmas (``_rls2_step``). The open-circuit
    voltage and the pack's slow polarisation (tens of seconds) move e over a memory of seconds;
    fitting the polarisation as a third term (a 30 s lag of i) made it trade off against e, whose
    lag it nearly is over such a memory, and a doubled resistance took twice as long to show."""

    def __init__(self, r0: float, sigma_r: float, noise_v: float, memory_s: float, limit: float) -> None:
        self.x = [math.nan, r0]  #: (e (V), R (ohm)); e from the first row
        self._p_max = (1e4, sigma_r * sigma_r)  #: the prior's variances: e free (any pack)
        self.P = [[self._p_max[0], 0.0], [0.0, self._p_max[1]]]
        self._r, self._memory, self._limit = noise_v * noise_v, memory_s, limit
        self._t = math.nan

    @property
    def sigma_r(self) -> float:
        """R's one sigma (ohm)."""
        return math.sqrt(max(self.P[1][1], 0.0))

    def add(self, t: float, volts: float, current_a: float) -> None:
        """A row at t (s): the filtered voltage (V) and the model's filtered supply current (A)."""
        x = self.x
        dt = t - self._t if self._t == self._t else 0.0
        self._t = t
        if x[0] != x[0]:
            x[0] = volts + x[1] * current_a
        # the regressor (1, -i)
        d0, d1 = _rls2_step(self.P, self._p_max, min(dt, _MAX_FORGET_S), self._memory, 1.0, -current_a,
                            volts - x[0] + x[1] * current_a, self._r, self._limit)
        x[0] += d0
        x[1] += d1


class _Twins(PhysicsTwins):
    """PhysicsTwins that can say when a sample would give nothing new."""

    def still_at(self, t: float) -> bool:
        """Whether ``sample(t)`` would take no step: its lanes' state, so its sample (but for the
        time), is then the latest sample's. Predictions come faster than the steps (a 1 kHz
        caller, 5 ms steps): the caller reuses what it made of that sample instead of sampling."""
        t0 = self._t0
        return t0 is not None and t >= t0 and bool(self._vt) and int((t - t0) / self._dt + 1e-9) + 1 <= self._k


class _Lanes(_Twins):
    """The adapted parameters' lanes (no voltage lane), which can be rebuilt at other constants."""

    def __init__(self, params: PlantParams, effects: Mapping[str, float], supply_v: float, tau_s: float) -> None:
        super().__init__(params, effects, supply_v, tau_s, faults=SPEED_ADAPTED, voltage_lane=False)
        self._build = (dict(effects), supply_v, tau_s)

    def supply(self) -> tuple[float, float, float] | None:
        """(the stamp of the filtered voltage the latest step took (s), that voltage (V), the
        nominal lane's supply current through the battery filter after the step (A)); None
        before a step."""
        if self._t0 is None or self._k == 0 or not self._vv:
            return None
        return self._vt[self._vi], self._vv[self._vi], self._ib_lp[0]

    def rebase(self, params: PlantParams, moves: Sequence[float]) -> None:
        """Rebuild the lanes at ``params`` keeping their states: the nominal lane's state moves
        along the lanes' own sensitivities by ``moves`` (per lane, in its units before the
        rebase), each perturbed lane keeps its distance from it: no jump in the prediction."""
        fresh = PhysicsTwins(params, *self._build, faults=SPEED_ADAPTED, voltage_lane=False)
        for x in (self._w, self._temp, self._ib_lp, self._vp, self._vp_lp, self._w_now):
            lift = sum(m * (x[j + 1] - x[0]) * self._inv[j + 1] for j, m in enumerate(moves))
            for j in range(len(x)):
                x[j] += lift
        self._w[:] = [max(w, 0.0) for w in self._w]
        self._steps, self._rs, self._rp, self._gp, self._inv = fresh._steps, fresh._rs, fresh._rp, fresh._gp, fresh._inv
        self.params, self.friction_reference_a = fresh.params, fresh.friction_reference_a


@dataclass(frozen=True)
class _Before:
    """What a provisional hot winding moves, or theta learns on its model (``PhysicsAdapter.take_named``),
    as it was before it."""

    theta: tuple[float, ...]
    P: tuple[tuple[float, ...], ...]
    heating_k: float
    heat_before: float
    taken: tuple[tuple[str, float, float], ...]


class PhysicsAdapter:
    """Recursive least squares of ``ADAPTED`` on a physics (or hybrid) model's measured speed.

    Fed what the estimator is fed (``update_pwm``, ``update_voltage``), each measured speed with the
    offline model's speed at its stamp (``update``); ``correction(t)`` is what to add to the
    offline speed at t and the variance the parameters' uncertainty gives it."""

    def __init__(self, plant: PlantModel, config: AdaptationConfig | None = None) -> None:
        self.config = config or AdaptationConfig()
        assert plant.supply_tau_s is not None, "PlantModel.__post_init__ resolves None"
        self.plant = plant
        self._tau = float(plant.supply_tau_s)
        self.updates = 0  #: measured speeds that updated theta
        self.frozen_samples = 0  #: measured speeds that did not (and ``note`` says why)
        self.relinearisations = 0
        self.reset()

    # --- state --------------------------------------------------------------------------------
    def reset(self) -> None:
        """Back to the offline model: theta = 0, the prior covariance, the lanes restarted."""
        self.theta = [0.0] * len(SPEED_ADAPTED)
        #: the winding's rise (K) a change the health monitor named set (``take_named``); not learned
        self.heating_k = 0.0
        self._heat_before = 0.0  #: heating_k before the latest named heating: its size is relative to it
        #: the named changes taken: (name, size, onset_s)
        self.taken: list[tuple[str, float, float]] = []
        #: the change being named, taken as its leading candidate (``take_named(provisional=True)``):
        #: its name, onset (s) and what the adapter was before it; None if none
        self._provisional: tuple[str, float, _Before] | None = None
        self._theta_hist: _History[tuple[float, ...]] = _History()  #: theta's
        #: the latest _RECENT_S of updates: (t, c, S0, S1), the a priori error at theta being c - S theta
        self._recent: collections.deque[tuple[float, float, float, float]] = collections.deque(maxlen=_RECENT_N)
        self._score = _Score()  #: the guard's, where theta learns
        self.in_use = True  #: whether the correction applies (the guard: it scores no worse)
        self._score_low = _Score()  #: the guard's where theta does not learn (``_driven`` false)
        self.in_use_low = True  #: whether the correction applies there
        cfg = self.config
        sig = cfg.prior_sigma
        self._p_max = [s * s for s in sig]
        self._P = self._prior_cov()
        rs = self.plant.params.battery_series_resistance_ohm
        self._pack_model = rs  #: the offline model's series resistance (ohm)
        ref = rs if rs > 0.0 else PACK_REFERENCE_OHM
        self._pack_bounds = (PACK_BOUNDS[0] * ref, PACK_BOUNDS[1] * ref)
        #: the pack's estimator: only where the model undoes a battery filter (else R is not used)
        self._sag = (_Sag(rs, cfg.pack_prior * ref, cfg.pack_noise_v, cfg.pack_memory_s, cfg.innovation_limit)
                     if self._tau > 0.0 else None)
        self._pack_lin = rs  #: the series resistance the lanes are built at (ohm)
        self._pack_row_t = -math.inf
        self._pack_ref = ref
        #: the baseline's start (s), its rows' sum and count; its value once complete
        self._base_t: float | None = None
        self._base_sum, self._base_n = 0.0, 0
        self.pack_baseline_ohm: float | None = None
        self.pack_changed = False  #: whether the measured resistance's change counts (hysteresis)
        #: the series resistance the named pack changes added (ohm; ``take_named``), None before one
        self.pack_named_ohm: float | None = None
        #: the latest named pack change: its onset (s), what the names before it added and the
        #: resistance measured before its onset (ohm)
        self._pack_named: tuple[float, float, float] | None = None
        self._pack_hist: _History[float] = _History()  #: the measured resistance's
        self.restart()

    def restart(self) -> None:
        """Forget the inputs (the lanes start again at the next command; theta is kept): the
        estimator's physics restarted, what the rotor did meanwhile is unknown."""
        p = self.plant
        self._lin = list(self.theta)
        self._lanes = _Lanes(p.params, p.effects, p.supply_v, self._tau)
        self.speed_scale_rad_s = self._lanes.speed_scale_rad_s
        self._friction_ref = self._lanes.friction_reference_a  #: A per unit of theta[1]
        self._heat_lin = self.heating_k  #: the winding's rise the lanes are built at (K)
        moved = any(self._lin) or self._pack_lin != self._pack_model or self._heat_lin != 0.0
        if moved:
            self._lanes.rebase(adapted_params(p.params, self._lin, self._friction_ref, self._pack_lin, self._heat_lin),
                               self._lin)
        self._units = self._lane_units()
        self._ref = _Twins(p.params, p.effects, p.supply_v, self._tau, faults=(), voltage_lane=False)
        #: the latest fresh row of ``_sample``: the row while neither the lanes nor (live) the
        #: reference take a step, as they would give it again; None after a rebuild
        self._row: tuple[float, float, float] | None = None
        self._ref_live = moved
        self._ref_t = -math.inf  #: the reference lane's latest sample while not live
        self._hist_t: list[float] = []  #: lanes' sample times
        #: (w(theta_lin) - w(0), S0, S1) there, at theta_lin when kept, and the lanes' rebuilds before it
        self._hist: list[tuple[float, float, float, int]] = []
        self._moves: list[tuple[float, float]] = []  #: theta_lin's moves at the rebuilds the history spans
        self._move0 = 0  #: the number of the rebuild of _moves[0]
        self._rebuilds = 0
        self._start_t: float | None = None
        self._last_update_t: float | None = None
        self._prev_offline = (-math.inf, 0.0)  #: the previous measured speed's (t, offline speed)
        sigma = self.config.noise_fraction * self.speed_scale_rad_s
        self._r = sigma * sigma
        self.note = "frozen: no measured speed yet"

    def _prior_cov(self) -> list[list[float]]:
        """theta's covariance at the prior (its upper triangle read): the start, and a named restart."""
        return [[self._p_max[0], 0.0], [0.0, self._p_max[1]]]

    def _set_theta(self, values: Sequence[float]) -> None:
        """theta set (in place) by a named change, its history's latest value with it (it stands
        for its step)."""
        self.theta[:] = values
        if self._theta_hist.values:
            self._theta_hist.values[-1] = tuple(self.theta)

    def _lane_units(self) -> list[float]:
        """Per lane: d lane / d theta, units of the lane's own (relative to the constants it was
        built at) per unit of theta (relative to the offline model); a rebuild moves the lanes'
        states by theta's move times these, the rows' sensitivities are the lanes' times these."""
        return [1.0 / (1.0 - self._lin[0]), self._friction_ref / self._lanes.friction_reference_a]

    # --- inputs -------------------------------------------------------------------------------
    def update_pwm(self, t: float, level: float) -> None:
        """An accepted command frame (PWM level) at t (s)."""
        if self._start_t is None:
            self._start_t = t
        self._lanes.update_pwm(t, level)
        self._ref.update_pwm(t, level)

    def update_voltage(self, t: float, volts: float) -> None:
        """An accepted filtered battery voltage (V) at t (s)."""
        self._lanes.update_voltage(t, volts)
        self._ref.update_voltage(t, volts)

    def _sample(self, t: float) -> tuple[float, float, float] | None:
        """Step the lanes to t: (w(theta_lin) - w(0), S) there, kept in the history; None before
        a command and a voltage."""
        row = self._row
        live = self._ref_live
        if row is None or not self._lanes.still_at(t) or (live and not self._ref.still_at(t)):
            tw = self._lanes.sample(t)
            if tw is None:
                return None
            if self._sag is not None:
                self._pack_row()
            dlin = 0.0
            if live:  # w(0) from the reference lane once theta_lin has moved
                ref = self._ref.sample(t)
                dlin = tw.speed_rad_s - ref.speed_rad_s if ref is not None else 0.0
            u = self._units
            s = tw.speed_sensitivity
            row = self._row = (dlin, s[0] * u[0], s[1] * u[1])
        if not live and t - self._ref_t >= _REF_CATCH_UP_S:  # else only kept up (its inputs consumed)
            self._ref.sample(t)
            self._ref_t = t
        ht = self._hist_t
        if ht and t <= ht[-1]:
            return self._now(self._hist[-1])
        ht.append(t)
        self._hist.append((*row, self._rebuilds))
        old = bisect.bisect_left(ht, t - self.config.history_s)
        if old > 64:  # amortised
            del ht[:old], self._hist[:old]
            gone = self._hist[0][3] - self._move0  # moves older than any row kept
            del self._moves[:gone]
            self._move0 += gone
        return row

    def _pack_row(self) -> None:
        """The pack's estimator fed the lanes' latest step: a row per voltage sample (so none while
        the voltage stops; the current is the lanes', a step or a measured speed's spacing after the
        sample's stamp, far inside the filter's seconds), at most one per ``pack_row_s``."""
        now = self._lanes.supply()
        assert self._sag is not None
        cfg = self.config
        if now is None or now[0] < self._pack_row_t + cfg.pack_row_s:
            return
        self._pack_row_t = now[0]
        self._sag.add(*now)
        self._pack_hist.keep(now[0], self.pack_measured_ohm)
        if self.pack_baseline_ohm is None:
            if self._base_t is None and self._sag.sigma_r < cfg.pack_confident * self._pack_ref:
                self._base_t = now[0]
            if self._base_t is not None:
                self._base_sum += self.pack_measured_ohm
                self._base_n += 1
                if now[0] - self._base_t >= cfg.pack_baseline_s:
                    self.pack_baseline_ohm = self._base_sum / self._base_n
        else:
            self._count_pack_change()

    def _count_pack_change(self) -> None:
        """Hysteresis on the measured resistance's change from its baseline: it counts from
        ``pack_significant`` of the baseline on, until it falls back under half of that."""
        assert self.pack_baseline_ohm is not None
        share = abs(self.pack_measured_ohm - self.pack_baseline_ohm) / self.pack_baseline_ohm
        self.pack_changed = share >= self.config.pack_significant * (0.5 if self.pack_changed else 1.0)

    @property
    def pack_measured_ohm(self) -> float:
        """The pack's sag per ampere as the voltage shows it (ohm), within ``PACK_BOUNDS``."""
        if self._sag is None:
            return self._pack_model
        lo, hi = self._pack_bounds
        return min(max(self._sag.x[1], lo), hi)

    @property
    def pack_ohm(self) -> float:
        """The adapted series resistance (ohm): the model's plus the change of the measured one
        since its baseline, within ``PACK_BOUNDS``, while that change counts (``pack_significant``);
        else the model's. After a named pack change (``take_named``): the model's plus what the
        names added."""
        lo, hi = self._pack_bounds
        if self.pack_named_ohm is not None:
            return min(max(self._pack_model + self.pack_named_ohm, lo), hi)
        if self.pack_baseline_ohm is None or not self.pack_changed:
            return self._pack_model
        return min(max(self._pack_model + self.pack_measured_ohm - self.pack_baseline_ohm, lo), hi)

    def _now(self, row: tuple[float, float, float, int]) -> tuple[float, float, float]:
        """A history row moved to the present theta_lin along its S by each rebuild since it was
        kept, in order: what moving every row at each rebuild would give, bit for bit, without a
        pass over the history per rebuild."""
        x, s0, s1, k = row
        for d0, d1 in self._moves[k - self._move0:]:
            x = x + s0 * d0 + s1 * d1
        return x, s0, s1

    def _aligned(self, t: float) -> tuple[float, float, float] | None:
        """(w(theta_lin) - w(0), S) at a measured speed's stamp t: the lanes stepped to t if they
        are not past it, else interpolated in the history; None if t is older than the history."""
        ht = self._hist_t
        if not ht or t >= ht[-1]:
            return self._sample(t)
        i = bisect.bisect_right(ht, t)
        if i == 0 or t < ht[-1] - self.config.history_s:
            return None
        (t0, a), (t1, b) = (ht[i - 1], self._now(self._hist[i - 1])), (ht[i], self._now(self._hist[i]))
        g = (t - t0) / (t1 - t0)
        return a[0] + g * (b[0] - a[0]), a[1] + g * (b[1] - a[1]), a[2] + g * (b[2] - a[2])

    # --- output -------------------------------------------------------------------------------
    def correction(self, t: float, offline_rad_s: float | None = None) -> tuple[float, float]:
        """(speed to add to the offline model's at t (rad/s), its variance from theta's covariance
        ((rad/s)^2, S P S^T)); (0, 0) before the lanes have inputs. With the offline speed there,
        the guard of its regime decides (``in_use_low`` where theta does not learn), else ``in_use``."""
        row = self._sample(t)  # stepped whether in use or not: the lanes must keep up
        if row is None:
            return 0.0, 0.0
        low = offline_rad_s is not None and not self._driven(row, offline_rad_s)
        if not (self.in_use_low if low else self.in_use):
            return 0.0, 0.0
        return self._delta(row), self._variance(row)

    def _driven(self, row: tuple[float, float, float], offline_rad_s: float) -> bool:
        """Whether theta learns at this offline speed (rad/s): above the speed floor and linear."""
        return (offline_rad_s >= self.config.min_speed_fraction * self.speed_scale_rad_s
                and self._linear(row, offline_rad_s))

    def _delta(self, row: tuple[float, float, float]) -> float:
        th, lin = self.theta, self._lin
        return row[0] + row[1] * (th[0] - lin[0]) + row[2] * (th[1] - lin[1])

    def _variance(self, row: tuple[float, float, float]) -> float:
        P, s0, s1 = self._P, row[1], row[2]
        return s0 * s0 * P[0][0] + 2.0 * s0 * s1 * P[0][1] + s1 * s1 * P[1][1]

    @property
    def thrust_factor(self) -> float:
        """b adapted / b offline: CT's, ``ct_factor`` of the propeller's adapted loss."""
        return ct_factor(self.theta[0])

    @property
    def applied_thrust_factor(self) -> float:
        """What the prediction scales b by: ``thrust_factor`` while the correction is in use, else 1."""
        return self.thrust_factor if self.in_use else 1.0

    def values(self) -> dict[str, tuple[float, float]]:
        """name -> (adapted value in ``UNITS``, its one sigma). The pack's is its sag per ampere as
        the voltage shows it, NaN until the current has varied enough to tell it (its sigma below
        ``pack_confident`` of the model's) and without a battery filter to undo."""
        P = self._P
        return {ADAPTED[0]: (self.theta[0], math.sqrt(max(P[0][0], 0.0))),
                ADAPTED[1]: (1.0 + self.theta[1], math.sqrt(max(P[1][1], 0.0))),
                ADAPTED[2]: ((self.pack_measured_ohm, self._sag.sigma_r) if self._sag is not None
                             and self._base_t is not None else (math.nan, math.nan))}

    def named_changes(self) -> list[dict[str, object]]:
        """The named changes taken (``take_named``), as the saved model's metadata and replay's JSON
        give them: name, size (its unit) and onset (s)."""
        return [{"name": n, "size": v, "onset_s": o} for n, v, o in self.taken]

    def adapted_plant(self) -> PlantModel:
        """The physics model with the adapted constants (b scaled by ``thrust_factor``); its
        metadata says what was adapted from what."""
        p = self.plant
        b = p.thrust_coefficient
        meta = {**p.metadata, "adapted": {n: {"value": finite_or_none(v), "sigma": finite_or_none(s), "unit": UNITS[n]}
                                          for n, (v, s) in self.values().items()}}
        if self.taken:
            meta["named_changes_taken"] = self.named_changes()
            meta["adapted"]["motor_heating"] = {"value": self.heating_k, "sigma": None, "unit": "K"}
        return dataclasses.replace(p, params=adapted_params(p.params, self.theta, self._friction_ref, self.pack_ohm,
                                                            self.heating_k),
                                   thrust_coefficient=None if b is None else b * self.thrust_factor,
                                   metadata=meta)

    # --- learning -----------------------------------------------------------------------------
    def update(self, t: float, measured_rad_s: float, offline_rad_s: float) -> bool:
        """A measured speed at t (s) and the offline model's speed there (rad/s); True if theta
        was updated, else ``note`` says why not."""
        cfg, row, innovation = self.config, None, math.nan
        prev, self._prev_offline = self._prev_offline, (t, offline_rad_s)
        if self._start_t is None or t - self._start_t < cfg.settle_s:
            why = "frozen: settling after the start"
        else:
            row = self._aligned(t)
            error = measured_rad_s - offline_rad_s
            driven = row is not None and measured_rad_s >= REST_SPEED_RAD_S and self._driven(row, offline_rad_s)
            if row is not None:
                innovation = error - self._delta(row)  # the adapted prediction's a priori error
                if math.isfinite(error):  # judged at every speed, rest included
                    self._judge(t, error, innovation, not driven)
            if not (measured_rad_s >= REST_SPEED_RAD_S
                    and offline_rad_s >= cfg.min_speed_fraction * self.speed_scale_rad_s):  # (NaN: not ready)
                row, why = None, "frozen: rotor at rest or below the ESC start"
            elif row is None:
                why = "frozen: measured speed older than the model's history"
            elif not driven:  # above the floor, so: not linear
                row, why = None, "frozen: the rotor is starting or stopping (the model is not linear in theta there)"
        if row is None:
            self.note = why
            self.frozen_samples += 1
            if self._pack_moved():
                self._rebase()
            return False
        slope = (offline_rad_s - prev[1]) / (t - prev[0]) if 0.0 < t - prev[0] <= _SLOPE_GAP_S else 0.0
        r = self._r + (cfg.timing_s * slope) ** 2
        th = self.theta
        self._recent.append((t, innovation + row[1] * th[0] + row[2] * th[1], row[1], row[2]))
        self._learn(t, innovation, row[1], row[2], r)
        self._theta_hist.keep(t, tuple(self.theta))
        self.note = "on"
        self.updates += 1
        th, lin, step = self.theta, self._lin, cfg.relinearise
        if abs(th[0] - lin[0]) > step[0] or abs(th[1] - lin[1]) > step[1] or self._pack_moved():
            self._rebase()
        return True

    def theta_at(self, t: float) -> list[float]:
        """theta as it was at t (s): the latest update at or before t, else (t before the history)
        the oldest kept, or the present one without a history."""
        return list(self._theta_hist.at(t, tuple(self.theta)))

    def _theta_before(self, onset_s: float) -> list[float]:
        """theta as it was before a named change's onset (``_BEFORE_ONSET_S`` earlier): where each
        named change takes theta back to, what theta learnt since being that change."""
        return self.theta_at(onset_s - _BEFORE_ONSET_S)

    def _taken_index(self, name: str, onset_s: float) -> int | None:
        """Where ``taken`` holds the named change of this name and onset (the latest), else None."""
        same = [k for k, (n, _, o) in enumerate(self.taken) if n == name and o == onset_s]
        return same[-1] if same else None

    def take_named(self, name: str, size: float, onset_s: float, provisional: bool = False,
                   reference: float | None = None) -> bool:
        """A change the health monitor named (``core.health.HealthEvent``: a fault's name, its size
        in ``FAULT_UNITS``, its onset on the caller's clock), taken into the model if the adapter
        has no parameter for it or learns it slower (all four names, below). A winding running hot
        (``motor_heating``): theta goes back to
        what it was before the onset (``_BEFORE_ONSET_S``: what it learnt since was the heating,
        taken in the propeller's and the friction's place), the winding's rise (``heating_k``) to
        the named size over what the previous named heating left (the monitor tests the offline
        model and starts afresh after each change), and the lanes are rebuilt there; the
        covariance stays as it is. A later call for the same change (its size refined) moves only
        the rise. Returns whether the model moved.

        A propeller's loss or a bearing's friction (``_take_speed``): theta back to what it was
        before the onset, the named size added to its own parameter, the covariance back to the
        prior, and theta learns on from there. Why: a friction step at hover reads first as drag
        (the two parameters are one direction to the speed at one operating point, the prior
        decides who moves first, and the wrong split shows once the rotor changes speed), and
        theta's gain, capped by the prior, takes 10-15 s to climb a friction tripled (5 sigma);
        the monitor names and sizes it within seconds (a tripled friction named 3.09x 4 s after
        its onset on tuning bench 2). In flight with the monitor (``bench_adaptation.py --health``,
        two flights per fault and bench), within 1.2x of the healthy twin's RMSE from 10 s on:
        benches 308-311 friction 0/8 -> 5/8 (median 2.27 -> 1.18x), propeller 4/8 -> 5/8; fresh
        benches 320-323 friction 5/8 -> 7/8, propeller 5/8 -> 7/8; the other faults unchanged.
        A heating it cannot learn: it stands the propeller and the friction in for it, which
        leaves a third to half of what the rise does (the module's docstring).

        And a pack's resistance (``pack_resistance``, a factor on its sag per ampere): the model's
        series resistance moves by the factor's share of ``reference``, the sag per ampere the
        monitor sized the factor against (``HealthEvent.reference``), so by the ohms the monitor
        found added; without one, of the resistance the adapter measured before the onset
        (``_BEFORE_ONSET_S``, its history). What earlier names added stands, and the model stays
        there (``_take_pack``): the voltage's own estimate follows a doubling over 10-20 s and
        swings while the current holds still, where the monitor sized it 1.72-2.12x within 1.5-8 s
        on benches 840-847. theta goes back to what it was before the onset, the covariance kept,
        as for a heating: at each current step after the onset the pack sagged more than the model
        undid, and theta learnt that in the propeller's and the friction's place (bench 311, random
        steps: a propeller 7.6 % stronger and the friction 0.74x at the first step after the onset;
        on benches 308-311 with the monitor, pack within 1.2x of the twin 6/8 -> 8/8 in flight,
        5/8 -> 7/8 on random steps). Tried: the voltage's estimate set to the named value and
        refining from there; it drifted off again (tuning benches 1-7, 14 flights with a doubled
        pack: within 1.2x of the twin 10/14, the worst 2.50x; held at the named value 12/14,
        1.65x; not taken 12/14, 5.94x).

        ``provisional``: the change is still being named and this is its leading candidate (the
        monitor's ``HealthMonitor.leading``): a hot winding is taken as above, and undone (the
        adapter back to what it was before, ``drop_provisional``) if the change is named otherwise
        or not at all; the others the adapter learns itself are not taken (False). Why: a
        hot winding and a bearing's friction explain a change in flight alike for seconds, and the
        name waits for them to part, 4-13 s after the onset on benches 308-311, when what the
        adapter learnt meanwhile (the heating in the propeller's and the friction's place) has
        already cost the first 10 s."""
        if not math.isfinite(size):
            return False
        prov = self._provisional
        if provisional and prov is not None and prov[:2] == (name, onset_s):
            return self._take(name, size, onset_s, reference)  # the lead's size refined
        if prov is not None:
            # named (as led or otherwise), or another lead: the lead undone, and the lanes rebuilt
            # once, straight to what follows (by way of the state before the lead, a second large
            # move of their states in an instant, theta ran off on tuning bench 5)
            self._restore(prov[2])
        # a lead is taken only where the adapter does not learn it itself: theta learns a propeller
        # or a friction (and a restart's prior covariance on the transient right after the onset let
        # it learn a propeller's loss of 0.04 beside a friction the lead had right: tuning bench 5,
        # flight 50101, 1.38 -> 4.26x the twin's RMSE), the voltage a pack
        undone = not provisional and self._untake_renamed(name, onset_s)
        before = self._before()
        moved = (not provisional or name == "motor_heating") and self._take(name, size, onset_s, reference)
        if moved and provisional:
            self._provisional = (name, onset_s, before)
        elif not moved and (prov is not None or undone):
            self._rebase()  # back at the state before the lead, or without the earlier name
            moved = undone
        return moved

    def _untake_renamed(self, name: str, onset_s: float) -> bool:
        """Undo what a change taken under another name added (a winding's rise, a pack's ohms), now
        that it is named ``name``: the monitor renames a change being sized when another candidate
        comes to lead it by the naming rule, and the model must not hold both. theta needs no undo:
        every first take of a change sets it back to before the onset. Returns whether one was."""
        old = [n for n, _, o in self.taken if o == onset_s and n != name]
        for n in old:
            if n == "motor_heating":
                self.heating_k = self._heat_before
            elif n == "pack_resistance" and self._pack_named is not None and self._pack_named[0] == onset_s:
                earlier = any(e[0] == n and e[2] != onset_s for e in self.taken)
                self.pack_named_ohm, self._pack_named = (self._pack_named[1] if earlier else None), None
        self.taken = [e for e in self.taken if e[2] != onset_s or e[0] == name]
        return bool(old)

    @property
    def provisional(self) -> bool:
        """Whether a change still being named is in the model (its lead, ``take_named``)."""
        return self._provisional is not None

    def drop_provisional(self) -> bool:
        """Undo the change taken provisionally (``take_named``), if any: the adapter back to what it
        was before it (what it learnt since was learnt on the lead's model). Returns whether one was."""
        prov = self._provisional
        if prov is None:
            return False
        self._restore(prov[2])
        self._rebase()
        return True

    def _restore(self, b: _Before) -> None:
        """The state before a provisional change (the lanes not yet rebuilt), which is no more."""
        self._provisional = None
        self.taken = list(b.taken)
        self.heating_k, self._heat_before = b.heating_k, b.heat_before
        self._P = [list(r) for r in b.P]
        self._set_theta(b.theta)

    def _before(self) -> _Before:
        """What a provisional hot winding would move, as it is now (``_restore`` puts it back)."""
        return _Before(tuple(self.theta), tuple(tuple(r) for r in self._P), self.heating_k, self._heat_before,
                       tuple(self.taken))

    def _take(self, name: str, size: float, onset_s: float, reference: float | None = None) -> bool:
        """``take_named`` without the provisional's bookkeeping."""
        if name == "pack_resistance":
            return self._take_pack(size, onset_s, reference)
        if name in SPEED_ADAPTED:
            return self._take_speed(SPEED_ADAPTED.index(name), size, onset_s)
        if name != "motor_heating":
            return False
        i = self._taken_index(name, onset_s)
        again = i is not None
        if i is not None:
            self.taken[i] = (name, size, onset_s)
        else:
            self.taken.append((name, size, onset_s))
            self._heat_before = self.heating_k
            self._set_theta(self._theta_before(onset_s))
        self.heating_k = min(max(self._heat_before + size, HEATING_BOUNDS_K[0]), HEATING_BOUNDS_K[1])
        if again and abs(self.heating_k - self._heat_lin) < _HEATING_REBUILD_K:
            return False
        self._rebase()
        return True

    def _take_speed(self, k: int, size: float, onset_s: float) -> bool:
        """``take_named``'s propeller (k 0) or friction (k 1): theta back to what it was before the
        onset with the named change added to its own parameter, and the covariance back to the prior
        (theta goes on learning from there, as fast as at the start); a refined size of the same
        change moves that parameter by the refinement only, keeping what theta learnt since.

        Refused (False) where theta explains the speed of the latest ``_RECENT_S``
        far better than the named model would (``_TAKE_CHECK``): a name dated after theta had
        already learnt the change counts it twice, and a wrong name is no better. Bench 311, flight
        3110000: a propeller loss at 45.2 s, learnt by theta within 10 s, then named a bearing's
        friction 2.54x from 56.8 s; taken, the RMSE after the change went 1.02 -> 2.19x the twin's
        (the named model's squared errors over the 3 s before it 677x theta's, where the names
        taken right on benches 308-311 were 0.04-0.93x)."""
        none = 0.0 if k == 0 else 1.0  # the size of no change in the monitor's unit (``FAULT_UNITS``)
        name = SPEED_ADAPTED[k]
        i = self._taken_index(name, onset_s)
        th = list(self.theta)
        if i is not None:
            _, was, _ = self.taken[i]
            self.taken[i] = (name, size, onset_s)
            th[k] += size - was
        else:
            prior = self._prior_cov()
            th = self._theta_before(onset_s)
            th[k] += size - none
            th = list(_projected(prior, *th))
            if self.recent_sq(th) > _TAKE_CHECK * self.recent_sq(self.theta):
                return False
            self.taken.append((name, size, onset_s))
            self._P = prior
        self._set_theta(_projected(self._P, *th))
        self._rebase()
        return True

    def recent_sq(self, theta: Sequence[float]) -> float:
        """The sum of the a priori squared errors ((rad/s)^2) theta would have made on the updates
        of the latest ``_RECENT_S`` (linear in theta: each update's sensitivities)."""
        t0, t1 = theta
        rec = self._recent
        since = rec[-1][0] - _RECENT_S if rec else 0.0
        return sum((c - s0 * t0 - s1 * t1) ** 2 for t, c, s0, s1 in rec if t >= since)

    def _take_pack(self, factor: float, onset_s: float, reference: float | None = None) -> bool:
        """``take_named``'s pack: the resistance added (ohm) set to the factor's share of
        ``reference`` (or, without one, of the resistance measured before the onset), over what
        the names before it added, and theta back to before the onset; a refined factor of the
        same change moves only its own share.
        Why the monitor's reference: its factor is the ohms it found added over its own window's
        sag, and the adapter's measured resistance differs from that by up to a fifth (benches
        308-311), which scaled the ohms added by as much."""
        if self._sag is None:
            return False  # the model undoes no battery filter: its resistance is not used
        entry = ("pack_resistance", factor, onset_s)
        named = self._pack_named
        i = self._taken_index(entry[0], onset_s)
        moved = False
        if named is not None and named[0] == onset_s and i is not None:  # refined
            self.taken[i] = entry
        else:
            named = (onset_s, self.pack_named_ohm or 0.0,
                     self._pack_hist.at(onset_s - _BEFORE_ONSET_S, self.pack_measured_ohm))
            self._pack_named = named
            self.taken.append(entry)
            theta = self._theta_before(onset_s)
            moved = theta != self.theta
            self._set_theta(theta)
        share = named[2] if reference is None or not math.isfinite(reference) or reference <= 0.0 else reference
        self.pack_named_ohm = named[1] + (factor - 1.0) * share
        if moved or self._pack_moved():
            self._rebase()
        return True

    def _pack_moved(self) -> bool:
        """Whether the resistance moved more than ``pack_relinearise`` of the lanes' from it."""
        lin = self._pack_lin
        return abs(self.pack_ohm - lin) > self.config.pack_relinearise * max(lin, self._pack_bounds[0])

    def _judge(self, t: float, error_offline: float, e_adapted: float, low: bool = False) -> None:
        """The guard: score both predictions on a measured speed (its error from the offline and
        from the adapted prediction, rad/s, the latter the innovation theta learns from), forget
        over memory_s; ``low``: a speed where theta does not learn, scored on its own."""
        if low:
            self.in_use_low = self._score_low.add(t, error_offline, e_adapted, self.config.memory_s)
        else:
            self.in_use = self._score.add(t, error_offline, e_adapted, self.config.memory_s)

    def _linear(self, row: tuple[float, float, float], w: float) -> bool:
        """Whether the lanes' own steps move the speed by at most _LINEAR_SHARE of it: where a lane
        starts or stops at another time than the nominal one (friction decides when the rotor
        breaks away), the sensitivity is a jump, not a slope, and would collapse the covariance."""
        step = self.config.relinearise
        return max(abs(row[1] * step[0]), abs(row[2] * step[1])) <= _LINEAR_SHARE * w

    def _learn(self, t: float, e: float, s0: float, s1: float, r: float) -> None:
        """One RLS step (``_rls2_step``) on the innovation e with the regressor (s0, s1) and the
        sample's noise variance r ((rad/s)^2), forgetting over the excited time since the last
        update; theta then projected on ``BOUNDS`` (``_projected``, with the updated covariance)."""
        last = self._last_update_t
        self._last_update_t = t
        forget = min(t - last, _MAX_FORGET_S) if last is not None and t > last else 0.0
        d0, d1 = _rls2_step(self._P, self._p_max, forget, self.config.memory_s, s0, s1, e, r,
                            self.config.innovation_limit)
        th = self.theta
        th[0], th[1] = _projected(self._P, th[0] + d0, th[1] + d1)

    def _rebase(self) -> None:
        """The lanes rebuilt at theta (their states kept); the history moved to the new point
        (lazily: ``_now``)."""
        new = list(self.theta)
        moves = [(a - b) * u for a, b, u in zip(new, self._lin, self._units, strict=True)]
        if not self._ref_live and self._hist_t:
            self._ref.sample(self._hist_t[-1])  # the reference goes live: at the lanes' time
        self._ref_live = True
        # the resistance has no lane, so no move: the rows kept from before stand (a history of
        # history_s, where the filter spreads what the resistance does over seconds)
        self._pack_lin = self.pack_ohm
        self._heat_lin = self.heating_k  # no lane either: the states stand, the rotor settles in its lag
        self._lanes.rebase(adapted_params(self.plant.params, new, self._friction_ref, self._pack_lin, self._heat_lin),
                           moves)
        d = [a - b for a, b in zip(new, self._lin, strict=True)]
        self._moves.append((d[0], d[1]))  # the history's rows move when read (``_now``)
        self._rebuilds += 1
        self._lin = new
        self._units = self._lane_units()
        self._row = None
        self.relinearisations += 1


def adapter_for(model: object, config: AdaptationConfig | None = None) -> PhysicsAdapter:
    """The adapter of a physics or hybrid model; BadInputError for a network (it has no physical
    parameters to adapt)."""
    return PhysicsAdapter(require_physics(model, "adaptation (--adapt / parameter adapt)", ""), config)
