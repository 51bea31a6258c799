"""The bench physics as the model of the discrepancy workflow: effects scored and fitted on it.

The model is a physics CONFIG (``physics.config.PhysicsConfig``: the plant driven by a
recording's command events and its measured, filtered battery voltage), calibrated on the
measured speed first (``physics.fit``), so that a mere parameter mismatch is not taken for a
missing effect.

An effect that is off is a candidate: switched on at each strength of a small grid, the
constants recalibrated with it (warm start), it is scored like ``scoring.py`` scores network
candidates: blocked K-fold over time, per held-out block the constants refitted on all other
blocks, held-out SSE with the effect vs without (the null: the current model, recalibrated the
same way), one-sided sign-flip test over the blocks' log SSE ratios. The per-fold refit is the
Gauss-Newton step from the all-data calibration with its Jacobian (``scoring.BlockStats`` on
the Jacobian columns), which to first order is the calibration on the training blocks alone
and costs no extra simulation; the strength is chosen per fold by training SSE. A named
effect's strength is refitted along with the constants from then on.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TypedDict

import numpy as np

from .. import contract as c
from ..physics.config import PhysicsConfig
from ..physics.fit import STRENGTH_MAX, Data, Fit, recalibrate_with
from ..physics.params import BenchParams
from ..physics.plant import full_drive_speeds, map_origin, spin_up_time_constant_s
from ..recordings import Signals
from . import scoring as sc

#: Strengths tried for each effect (nominal 1 in the middle), and the range a fit may reach.
STRENGTH_GRID: dict[str, tuple[float, ...]] = {
    "battery_voltage": (0.5, 1.0, 1.5),
    "rotor_lag": (0.1, 0.3, 1.0, 2.0),  # another motor and propeller may have far less inertia
    # from 10 ms (a 13 ms dead time tried at 20 ms, the nearest point, is not significant) to
    # 80 ms; longer ones are reached by the fit (up to STRENGTH_MAX). A 120 ms point would let a
    # dead time stand in for a missing inertia with every effect off (167 ms on the demo's bags)
    "input_delay": (0.25, 0.5, 1.0, 1.5, 2.0),
    # a start threshold on the wrong side of one commanded level predicts a stopped rotor where it
    # runs (or the reverse) for that whole hold, so the grid is as fine as the levels a random
    # staircase commands (1.25e-3 PWM level between points): with 0.5, 1, 2 (0.0525, 0.055,
    # 0.06) a foreign bench's 0.0567 scored -127 % with its rotor resting at 0.0558 and running at 0.0574
    "esc_deadband": (0.25, 0.5, 0.75, 1.0, 1.25, 1.5, 1.75, 2.0),
    "spin_down_asymmetry": (0.5, 1.0),
    "motor_heating": (0.25, 0.5, 1.0, 2.0),
}
#: Effects whose strength sets a threshold on the commanded level: fitted by trying the gaps between
#: the levels the data command (``threshold_strengths``), not by a parabola
THRESHOLDS = frozenset({"esc_deadband"})
#: Most gaps between commanded levels tried in one round of the search (a sweep commands every
#: level: evenly spread then)
THRESHOLD_TRIES = 8
#: Rounds of that search: all gaps (spread), then those between the best and its neighbours
THRESHOLD_ROUNDS = 3
#: A base effect freed on the measured data is no new effect when its strength there is within this
#: factor of the reference's: the same bench recalibrated (the reference fit trades inertia and dead
#: time with the constants, so a freed rotor_lag refitted after battery_voltage would otherwise be
#: "added" for a holdout already at 1.6 rad/s). Below BASE_SAME_ZERO the reference had none of it.
BASE_SAME_FACTOR = 1.3
BASE_SAME_ZERO = 0.05
#: Least held-out SSE per sample ((rad/s)^2) in the score's log ratios.
SSE_FLOOR = 1e-6


@dataclass
class BlockedData(Data):
    """Recordings (``physics.fit.Data``) cut into time blocks: each used row's block, for the
    held-out scores."""

    signals: Sequence[Signals]
    labels: np.ndarray  #: block of each used row (concatenated), -1 outside every block
    blocks: int


def blocked(signals: Sequence[Signals], what: str) -> BlockedData:
    """The recordings, the rows of each with a measured speed and their blocks (``scoring.make_blocks``:
    BadInputError when the ``what`` recordings are too short to hold out blocks)."""
    blocks = sc.make_blocks([s.duration_s for s in signals], what)
    lab = sc.block_labels([len(s.t) for s in signals], blocks)
    data = Data.of(signals)
    labels, first = [], 0
    for s, ok in zip(signals, data.rows, strict=True):
        labels.append(lab[first + ok])
        first += len(s.t)
    return BlockedData(list(signals), data.rows, np.concatenate(labels), int(sum(blocks)))


class _FittedValueCore(TypedDict):
    quantity: str
    value: float
    unit: str
    strength: float


class FittedValue(_FittedValueCore, total=False):
    """``fitted_value``: an effect's strength as the physical quantity it sets, and what the
    recordings identify of it (for some effects, and only with the model's supply voltage)."""

    thermal_time_constant_s: float
    map_origin_pwm: float
    time_constant_ms: float
    at_speed_rad_s: float
    warm_speed_loss_percent: float
    supply_v: float


#: The physical quantity each effect's strength scales (sim.bench.EFFECT_DOCS): name, unit, and its
#: value at a strength on a bench.
def fitted_value(name: str, strength: float, p: BenchParams, supply_v: float | None = None) -> FittedValue:
    """An effect's strength as the physical quantity it sets: {quantity, value, unit, strength}.

    With the model's ``supply_v``, also what the recordings identify whatever the CONFIG's split of
    winding resistance and propeller drag (``plant.spin_up_time_constant_s``): for rotor_lag the
    spin-up time constant at half the full-drive speed, for motor_heating the share of the
    full-drive speed lost once the winding is warm. The inertia and the %/K are the CONFIG's terms."""
    quantity, value, unit = {
        "battery_voltage": ("share of the measured battery voltage's deviation from a stiff supply the motor sees",
                            strength, "x"),
        "rotor_lag": ("rotor inertia", strength * p.rotor_inertia_kg_m2, "kg m^2"),
        "input_delay": ("dead time", 1000.0 * strength * p.esc_input_delay_s, "ms"),
        "esc_deadband": ("ESC start level", c.PWM_STOP + strength * p.esc_deadband_pwm, "PWM level"),
        "spin_down_asymmetry": ("share of the ESC's active braking removed", 100.0 * strength, "%"),
        "motor_heating": ("winding resistance rise", 100.0 * strength * p.copper_temperature_coefficient_per_k, "%/K"),
    }[name]
    out: FittedValue = {"quantity": quantity, "value": float(value), "unit": unit, "strength": float(strength)}
    if name == "motor_heating":  # fitted along with it (COMPANIONS)
        out["thermal_time_constant_s"] = float(p.motor_thermal_capacity_j_per_k * p.motor_thermal_resistance_k_per_w)
    if name == "esc_deadband":  # fitted along with it (SWITCH_COMPANIONS)
        out["map_origin_pwm"] = float(map_origin(p, {"esc_deadband": strength}))
    if supply_v is not None and name in ("rotor_lag", "motor_heating"):
        eff = {**{n: 0.0 for n in c.EFFECTS}, name: float(strength)}
        cold, warm = full_drive_speeds(p, eff, supply_v)
        if name == "rotor_lag":
            out["time_constant_ms"] = 1000.0 * spin_up_time_constant_s(p, eff, 0.5 * cold)
            out["at_speed_rad_s"] = 0.5 * cold
        else:
            out["warm_speed_loss_percent"] = 100.0 * (1.0 - warm / cold)
        out["supply_v"] = float(supply_v)
    return out


def value_text(value: FittedValue) -> str:
    """A ``fitted_value`` for people, e.g. 'dead time 52 ms': the one text of it in the console,
    the report and ``describe``. Heating leads with what the speed identifies, the share of the
    full-drive speed lost once warm: its %/K and time constant hold only with the CONFIG's winding
    resistance and thermal capacity (the simulator's 12 in bench's unless a CONFIG or the motor's
    priors say otherwise), which the speed cannot check, so the text says so."""
    if value.get("warm_speed_loss_percent") is not None:
        return (f"full-drive speed {value['warm_speed_loss_percent']:.2g} % lower once warm ({value['quantity']} "
                f"{value['value']:.4g} {value['unit']}, thermal time constant "
                f"{value.get('thermal_time_constant_s', math.nan):.0f} s, given the CONFIG's winding resistance "
                "and thermal capacity)")
    text = f"{value['quantity']} {value['value']:.4g} {value['unit']}".rstrip()
    if value.get("thermal_time_constant_s") is not None:
        text += f", thermal time constant {value['thermal_time_constant_s']:.0f} s"
    if value.get("map_origin_pwm") is not None:
        text += f", throttle map from {value['map_origin_pwm']:.4g}"
    if value.get("time_constant_ms") is not None:
        text += f"; spin-up time constant {value['time_constant_ms']:.0f} ms at {value['at_speed_rad_s']:.0f} rad/s"
    return text


def describe(name: str, strength: float, model: PhysicsConfig) -> str:
    """The physical meaning of an effect's strength, for people (the numbers of ``fitted_value``)."""
    return f"strength {strength:.3g} ({value_text(fitted_value(name, strength, model.params, model.supply_v))})"


# --- scores ----------------------------------------------------------------------------------------
def score(null: Fit, cands: Sequence[Fit], grid: Sequence[float], data: BlockedData) -> sc.Score:
    """Held-out score of an effect (see the module docstring); same fields as scoring.Score."""
    K = data.blocks
    null_st = sc.BlockStats.of(null.J, null.r, data.labels, K)
    cand_st = [sc.BlockStats.of(f.J, f.r, data.labels, K) for f in cands]
    sse_null, sse_cand, chosen = np.zeros(K), np.zeros(K), np.full(K, -1)
    for k in range(K):
        if null_st.n[k] == 0:
            continue
        beta0, _ = null_st.fit_without(k)
        sse_null[k] = null_st.sse(k, beta0)
        fits = [st.fit_without(k) for st in cand_st]
        j = int(np.argmin([f[1] for f in fits]))
        chosen[k] = j
        sse_cand[k] = cand_st[j].sse(k, fits[j][0])
    used = null_st.n > 0
    # the statistics of scoring.score_candidate_groups (per-block log ratio, sign-flip test), the
    # SSEs floored at (1 mrad/s)^2 per sample: a stopped rotor that both predict exactly is a tie
    floor = SSE_FLOOR * null_st.n[used]
    d = np.log(np.maximum(sse_null[used], floor) / np.maximum(sse_cand[used], floor))
    total_r2, n = float(null_st.s[used].sum()), float(null_st.n[used].sum())
    counts = np.bincount(chosen[used], minlength=len(grid))
    return sc.Score(
        fraction=float(1.0 - np.exp(-np.mean(d))) if len(d) else 0.0,
        fraction_of_residual=float(1.0 - sse_cand[used].sum() / total_r2) if total_r2 > 0 else 0.0,
        null_fraction=float(1.0 - sse_null[used].sum() / total_r2) if total_r2 > 0 else 0.0,
        p_value=sc.sign_flip_p(d),
        blocks=int(used.sum()),
        blocks_improved=int(np.sum(d > 0)),
        params={"strength": float(grid[int(np.argmax(counts))])},
        params_per_fold=[{"strength": float(grid[j])} for j in chosen[used]],
        rmse_null=math.sqrt(sse_null[used].sum() / n) if n else float("nan"),
        rmse_candidate=math.sqrt(sse_cand[used].sum() / n) if n else float("nan"),
    )


def score_effect(base: Fit, name: str, data: BlockedData) -> tuple[sc.Score, list[Fit]]:
    """``name`` scored against ``base`` on held-out blocks of ``data`` (``score`` over
    ``effect_fits`` at its STRENGTH_GRID), and those fits (``fit_strength`` starts from them)."""
    fits = effect_fits(base, name, data)
    return score(base, fits, STRENGTH_GRID[name], data), fits


def threshold_strengths(model: PhysicsConfig, data: Data, lo: float, hi: float,
                        exclude: Sequence[float] = ()) -> list[float]:
    """Start-threshold strengths in (``lo``, ``hi``) worth a fit: the middle of each gap between two
    consecutive distinct levels ``data`` commands (at most THRESHOLD_TRIES, evenly spread), less
    those in ``exclude``. A threshold anywhere in a gap predicts the same stopped and running
    holds, so the SSE is a staircase in the strength: a parabola or a gradient finds nothing, a
    grid point can sit on the wrong side of the one level that matters, and the middle is as far
    as the data allow from either side."""
    scale = model.params.esc_deadband_pwm
    levels = np.unique(np.concatenate([[c.PWM_STOP], *(np.asarray(s.pwm_events[1], dtype=float)
                                                        for s in data.signals)]))
    mids = (0.5 * (levels[1:] + levels[:-1]) - c.PWM_STOP) / scale
    mids = mids[(mids > lo) & (mids < hi)]
    mids = mids[[not np.any(np.isclose(m, exclude, rtol=0.0, atol=1e-9)) for m in mids]]
    if len(mids) > THRESHOLD_TRIES:
        mids = mids[np.unique(np.round(np.linspace(0, len(mids) - 1, THRESHOLD_TRIES)).astype(int))]
    return [float(m) for m in mids]


def effect_fits(base: Fit, name: str, data: Data) -> list[Fit]:
    """The effect switched on at each grid strength, constants recalibrated from ``base``'s (its
    COMPANIONS held at the CONFIG's: fitted with its strength in ``fit_strength``; its
    SWITCH_COMPANIONS fitted along: ``physics.fit.recalibrate_with``)."""
    return [recalibrate_with(base, base.model.with_effect(name, g), data, [name]) for g in STRENGTH_GRID[name]]


def fit_strength(base: Fit, name: str, data: Data, fits: Sequence[Fit]) -> Fit:
    """The strength with the least SSE on all of ``data`` (jointly with the constants): the best
    grid point, the grid extended past its end when the best is there, then the vertex of the
    parabola through the best point and its neighbours; for a threshold (THRESHOLDS) the gaps
    between the levels the data command instead (``threshold_strengths``)."""
    pts = dict(zip(STRENGTH_GRID[name], fits, strict=True))
    lo, hi = 0.0, STRENGTH_MAX[name]
    for _ in range(3):
        xs = sorted(pts)
        best = min(xs, key=lambda x: pts[x].sse)
        if best == xs[-1] and best < hi:
            nxt = min(hi, 2.0 * best)
        elif best == xs[0] and best > lo:
            nxt = best / 2.0
        else:
            break
        pts[nxt] = recalibrate_with(base, base.model.with_effect(name, nxt), data, [name])
    xs = sorted(pts)
    j = min(range(len(xs)), key=lambda i: pts[xs[i]].sse)
    if name in THRESHOLDS:
        # every gap first (the SSE is flat across the gaps that change no hold, so the one that
        # matters may lie past a neighbour of the best grid point), then around the best
        lo, hi = xs[0], xs[-1]
        for _ in range(THRESHOLD_ROUNDS):
            gaps = threshold_strengths(base.model, data, lo, hi, exclude=xs)
            if not gaps:
                break
            for s in gaps:
                pts[s] = recalibrate_with(base, pts[xs[j]].model.with_effect(name, s), data, [name],
                                          companions_from=pts[xs[j]].model)
            xs = sorted(pts)
            j = min(range(len(xs)), key=lambda i: pts[xs[i]].sse)
            lo, hi = xs[max(j - 1, 0)], xs[min(j + 1, len(xs) - 1)]
    elif 0 < j < len(xs) - 1:
        x = np.array(xs[j - 1:j + 2])
        y = np.array([pts[v].sse for v in x])
        a, b, _ = np.polyfit(x, y, 2)
        if a > 0:
            s = float(np.clip(-b / (2 * a), x[0], x[2]))
            cand = recalibrate_with(base, pts[xs[j]].model.with_effect(name, s), data, [name],
                                    companions_from=pts[xs[j]].model)
            if cand.sse < pts[xs[j]].sse:
                pts[s] = cand
                xs[j] = s
    # polished jointly with its strength free, as it will be refitted with every later effect
    # (see calibrate): the next round's null then has the same free parameters as its candidates
    return recalibrate_with(base, pts[xs[j]].model, data, [name], (*base.free, name), pts[xs[j]].model)
