"""The identification rules: which effect changed, decided from the response itself.

Two kinds of change cannot be told apart by a residual correction (``scoring.py``) alone:

- the dynamic family (rotor lag, dead time, spin-down, and the ESC start level that goes with
  them): a residual explained by one is partly explained by the others, so which one CHANGED is
  decided by identifying dead time, spin-up/spin-down time constants and start level from
  command -> measured speed on the measured and on the reference recordings
  (``identify_dynamics``, ``identify_start_level``, ``which_dynamic``);
- motor heating, a changed response to a thermal state both sets share (``identify_heating``).

``refine`` is the rule that applies them to a round of candidate scores (the network path: its
scores are residual corrections; the physics path fits each effect's strength in the model
itself, which is its identification).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from .. import contract as c
from ..core import effect_features as ef
from ..plant import throttle
from ..recordings import Signals

# --- the dynamic family: which of lag, dead time, spin-down changed ---------------------------------
#: Grids of the direct identification of the rotor's response (s).
ID_DELAYS = (0.0, 0.01, 0.02, 0.03, 0.04, 0.05, 0.06, 0.08, 0.1)
ID_TAU_UP = (0.0, 0.02, 0.04, 0.07, 0.1, 0.15, 0.2, 0.3)
ID_TAU_DOWN = (0.0, 0.02, 0.04, 0.07, 0.1, 0.15, 0.2, 0.3, 0.5, 0.8, 1.2, 2.0)
#: ESC start levels tried (PWM level) when esc_deadband is a candidate (identify_start_level: the start
#: level goes in before the lag, since a rotor commanded below it coasts down to zero like one that is
#: not braked, so a coast to zero is not taken for a slower spin-down), and the rise that counts.
ID_START_LEVELS = tuple(round(0.05 + 0.001 * k, 3) for k in range(11))  # 0.050 ... 0.060
START_LEVEL_MARGIN = 0.004  #: PWM level: twice the grid step, so one step of noise is no change
DYNAMIC_EFFECTS = ("rotor_lag", "input_delay", "spin_down_asymmetry")


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
    i, j = np.unravel_index(int(np.argmin(sse)), sse.shape)
    return Dynamics(float(ID_DELAYS[i]), float(tu[j]), float(td[j]), float(np.sqrt(sse[i, j] / max(n_total, 1))))


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


# --- motor heating: did the speed's response to the thermal state change --------------------------
HEATING_TAU_S = 120.0  #: thermal time constant of the identification (s)
HEATING_MIN_DROP = 5.0  #: rad/s: least extra speed loss at the measured data's hottest state
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

    @property
    def drop_rad_s(self) -> float:
        """Extra speed lost on the measured data at its hottest, beyond what the reference shows."""
        return (self.reference - self.measured) * self.hottest

    @property
    def changed(self) -> bool:
        return self.hottest >= HEATING_MIN_STATE and self.drop_rad_s >= HEATING_MIN_DROP

    def describe(self) -> str:
        return (f"at the measured data's hottest thermal state ({self.hottest:.2f}, time constant "
                f"{HEATING_TAU_S:.0f} s) the steady speed is {self.drop_rad_s:.1f} rad/s lower than the "
                f"reference's response to the same state predicts (margin {HEATING_MIN_DROP:g} rad/s)")

    def as_dict(self) -> dict[str, float]:
        return {"measured_rad_s_per_unit": self.measured, "reference_rad_s_per_unit": self.reference,
                "hottest_thermal_state": self.hottest, "extra_drop_rad_s": self.drop_rad_s}


def identify_heating(measured: Sequence[Signals], reference: Sequence[Signals]) -> Heating:
    """Thermal sensitivity on the measured and on the reference data, fitted together.

    speed ~ cubic(pwm) + V + V pwm (one static map for both) + k_set * theta * duty with theta the
    ``thermal_load`` state: a battery that sags over a long run lowers the speed on both sets
    alike, so the shared voltage terms take that, and only a response to the winding's heat that
    differs between the sets goes into k_measured - k_reference. Samples at least 0.7 s after a
    command change (the rotor's dynamics do not enter)."""
    rows, ys = [], []
    hottest = 0.0
    for which, sigs in ((0, measured), (1, reference)):
        for s in sigs:
            pwm_t, pwm = s.pwm_events
            vt, vv = s.voltage_events
            th = ef.compute(ef.THERMAL_LOAD, s.t, pwm_t, pwm, vt, vv, {"tau_s": HEATING_TAU_S})
            change = np.r_[pwm_t[0], pwm_t[1:][np.diff(pwm) != 0]] if len(pwm_t) else np.zeros(1)
            k = np.searchsorted(change, s.t, side="right") - 1
            ok = ((s.t - change[np.clip(k, 0, len(change) - 1)]) >= 0.7) & np.isfinite(s.speed) \
                & np.isfinite(s.voltage) & np.isfinite(th)
            p = (s.pwm[ok] - 0.075) / 0.025
            v = s.voltage[ok] - 11.5
            duty = throttle(s.pwm[ok], c.PWM_STOP)
            t_d = th[ok] * duty
            rows.append(np.column_stack([np.ones_like(p), p, p**2, p**3, v, v * p,
                                         t_d * (which == 0), t_d * (which == 1)]))
            ys.append(s.speed[ok])
            if which == 0 and ok.any():
                hottest = max(hottest, float(np.max(th[ok])))
    A, y = np.vstack(rows), np.concatenate(ys)
    if len(y) < 20:
        return Heating(0.0, 0.0, 0.0)
    beta, *_ = np.linalg.lstsq(A, y, rcond=None)
    return Heating(float(beta[6]), float(beta[7]), hottest)


def which_dynamic(meas: Dynamics, ref: Dynamics | None, exclude: Sequence[str] = ()) -> tuple[str | None, str]:
    """The dynamic effect whose parameter changed from reference to measured, and why.

    Margins: spin-up time constant up by 50 % and at least 50 ms; dead time up by 15 ms;
    spin-down time constant up by 0.1 s more than the spin-up one; ESC start level (when
    identified, else PWM_STOP on both) up by START_LEVEL_MARGIN."""
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
    changes["esc_deadband"] = (meas.start_level - ref.start_level, START_LEVEL_MARGIN - 1e-9,
                               f"the rotor gets no drive below PWM {meas.start_level:.3f} on the measured data vs "
                               f"{ref.start_level:.3f} on the reference (with the identified dead time and "
                               f"spin-up/spin-down time constants)")
    # in order of precedence: a start level that rose explains a coast to zero (no drive) and a
    # compressed throttle map, which the lags would otherwise take for a slower spin-down; a rotor
    # that lags at all comes before an asymmetry of its lag
    for name in ("esc_deadband", "rotor_lag", "input_delay", "spin_down_asymmetry"):
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

    - motor_heating, when nothing else is new: named when ``identify_heating`` says its response
      changed;
    - the dynamic family, when a dynamic candidate is significant on the measured data alone or
      the measured residual RMSE is GAP_RATIO x the reference's with nothing new: the one
      ``which_dynamic`` finds changed is named (at the identified parameters); when none
      changed, no dynamic candidate is new."""
    out = Refined(best)
    if not reference:
        return out
    offered = list(ev)
    if "motor_heating" in ev and out.best is None:
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
    if out.best is not None and out.best not in DYNAMIC_EFFECTS:
        return out
    if not (any(ev[k].measured_alone.p_value < alpha and ev[k].measured_alone.fraction >= min_effect
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
        progress("  a dynamic effect is new: identifying dead time and spin-up/spin-down "
                 "time constants on the measured and the reference recordings")
        dyn = (identify_dynamics(measured), identify_dynamics(reference))
        if "esc_deadband" in ev:
            for dy, sigs in zip(dyn, (measured, reference)):
                dy.start_level = identify_start_level(sigs, dy)
        cache["dynamics"] = dyn
    m, r = cache["dynamics"]
    choice, why = which_dynamic(m, r, exclude=[*named, *(set(c.EFFECTS) - set(offered))])
    info = {"measured": m.as_dict(), "reference": r.as_dict(), "changed": choice, "because": why}
    progress(f"  identified dynamics: {why}")
    if choice is None:
        # the response to the command did not change: the residual's dynamic structure is the
        # model's own (it is there on the reference too), not a new effect
        for k in DYNAMIC_EFFECTS:
            if k in ev and ev[k].verdict in ("new", "structural"):
                ev[k].verdict = "not new (identified dynamics unchanged)"
                ev[k].dynamics = info
        others = [k for k in offered if k not in DYNAMIC_EFFECTS and ev[k].verdict == "new"]
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
                      "input_delay": {"delay_s": max(m.delay_s - r.delay_s, 0.01)},
                      }.get(choice)
        if choice == "esc_deadband":
            out.reference_params = {"threshold": r.start_level}
    if out.best is not None:
        ev[out.best].dynamics = info
    return out
