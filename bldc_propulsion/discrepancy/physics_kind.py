"""The bench physics as the model of the discrepancy workflow (``discrepancy --physics``).

Its specifics, behind the ``base.ModelKind`` protocol the loop (``workflow.py``) talks to; the
model, its CONFIG, calibration and scores are ``physics.py``:

- step 1, reference first (with --reference): Kv, CP, the throttle exponent and the strengths of
  the CONFIG's effects fitted on the reference recordings (``physics.fit_reference``); then Kv and
  CP calibrated on the measured recordings (and, separately, on the reference), the exponent held
  (``physics.HELD_AFTER_REFERENCE``; without --reference it is calibrated there too);
- step 3: every effect that is off in the model switched on (strength grid, constants
  recalibrated) and scored on held-out time blocks of the measured data and, separately
  calibrated, of the reference data. The score is on the measured data alone (the fit is), so
  ``measured_alone`` is the same score; the strength fit is the identification, so the loop's
  identification rules do not apply;
- step 4: the effect at the strength fitted on all measured data (constants with it, earlier
  effects' strengths refitted along); a fit with a quantity at a bound, or implausibly far from
  a CONFIG the user gave (``physics.fit_flags``, ``PLAUSIBLE_FACTOR``), is not a basis for a verdict;
- step 5 without --holdout: step 3's per-fold refits are the held-out evidence.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np

from .. import contract as c
from ..recordings import Signals
from . import acceptance as acc
from . import physics as ph
from .base import DataSet, Progress, Scores, Trial, rmse
from .identify import identify_heating


def constants_text(model: ph.PhysicsModel) -> str:
    return ", ".join(f"{k} {v:.4g}" for k, v in model.constants().items())


def predictions(model: ph.PhysicsModel, signals: Sequence[Signals]) -> DataSet:
    return DataSet(list(signals), [model.predict(s) for s in signals])


class PhysicsKind:
    """``base.ModelKind`` for the bench physics (``physics.PhysicsModel``)."""

    noun = "the calibrated physics model"
    identifies_response = False
    fitted_on = "which the constants and strengths were fitted on"
    no_reference = "no --reference recordings: new and structural findings cannot be told apart"

    def __init__(self, model: ph.PhysicsModel) -> None:
        self.config = model  #: the CONFIG as given (what "implausibly far" is measured from)
        self.flags: list[ph.FitFlag] = []
        self.reference_fit: dict[str, Any] | None = None
        self._fits: dict[str, list[ph.Fit]] = {}
        self._named: list[str] = []

    @property
    def model(self) -> ph.PhysicsModel:
        return self.cur.model

    def start(self, measured: Sequence[Signals], reference: Sequence[Signals], hold: Sequence[Signals],
              progress: Progress) -> tuple[DataSet, DataSet | None, DataSet]:
        model = self.config.with_supply(measured)
        self.meas_data = ph.Data.of(measured, "measured")
        self.ref_data = ph.Data.of(reference, "reference") if reference else None
        self.uncal_rmse = rmse(predictions(model, hold).residuals)
        if self.ref_data is not None:
            # reference first: what the model needs to agree with its own data is structural; only
            # what the measured data need beyond it can be new
            on = [n for n in c.EFFECTS if model.effects[n] > 0.0]
            progress(f"step 1: reference first: {', '.join([*ph.CALIBRATED, *on])} fitted on "
                     f"{len(reference)} reference recording(s)")
            rf = ph.fit_reference(model, self.ref_data)
            model = rf.model
            flags = ph.fit_flags(rf, self.config, "reference fit")
            self.reference_fit = {"constants": rf.model.constants(), "strengths": {n: rf.model.effects[n] for n in on},
                                  "rmse_rad_s": float(np.sqrt(rf.sse / max(len(rf.r), 1))),
                                  "at_bound": [f.text() for f in flags if f.at_bound],
                                  "implausible": [f.text() for f in flags if not f.at_bound]}
            progress(f"  reference fit: {constants_text(model)}; strengths "
                     + (", ".join(f"{n} {model.effects[n]:.2f}" for n in on) or "none")
                     + "".join(f", {k} {v:.4g}" for k, v in rf.companions().items())
                     + f"; RMSE {self.reference_fit['rmse_rad_s']:.2f} rad/s")
            self.flags += flags
        progress(f"step 1: calibrating {', '.join(ph.CALIBRATED)} on {len(measured)} measured recording(s)")
        held = ph.HELD_AFTER_REFERENCE if self.ref_data else ()
        self.cur = ph.calibrate_base(model, self.meas_data, held)
        self.cur_ref = ph.calibrate_base(model, self.ref_data, held) if self.ref_data else None
        self._ref_pending: list[str] = []
        self.base = self.cur.model
        # (judged in the range it was calibrated in: calibrate_base hands on the narrower one of
        # the fits with effects)
        centre, span = ph.base_window(model, held)
        wide = dataclasses.replace(self.cur, anchor=centre, log_range=span)
        self.flags += ph.fit_flags(wide, self.config, "calibration on the measured data")
        progress(f"  calibrated: {constants_text(self.base)} (holdout RMSE {self.uncal_rmse:.2f} rad/s uncalibrated)")
        return (predictions(self.base, measured), predictions(self.cur_ref.model, reference) if self.cur_ref else None,
                predictions(self.base, hold))

    def warnings(self) -> list[str]:
        return [f"{f.text()}: {f.consequence()}" for f in self.flags]

    def candidates(self, restrict: Sequence[str], named: Sequence[str]) -> list[str]:
        return [n for n in restrict if self.cur.model.effects[n] == 0.0]

    def residual_rmse(self) -> tuple[float, float]:
        r = float(np.sqrt(self.cur.sse / max(len(self.cur.r), 1)))
        return r, float(np.sqrt(self.cur_ref.sse / max(len(self.cur_ref.r), 1))) if self.cur_ref else float("nan")

    def score(self, names: Sequence[str], progress: Progress) -> dict[str, Scores]:
        if self._ref_pending and self.cur_ref is not None:
            # the effect named since: on the reference too, from the measured data's strength
            m = self.cur_ref.model
            for name in self._ref_pending:
                m = m.with_effect(name, self.cur.model.effects[name])
            self.cur_ref = ph.recalibrate(self.cur_ref, m, self.ref_data, self.cur.free)
        self._ref_pending = []
        out = {}
        for name in names:
            grid = ph.STRENGTH_GRID[name]
            self._fits[name] = ph.effect_fits(self.cur, name, self.meas_data)
            m = ph.score(self.cur, self._fits[name], grid, self.meas_data)
            r = (ph.score(self.cur_ref, ph.effect_fits(self.cur_ref, name, self.ref_data), grid, self.ref_data)
                 if self.cur_ref else None)
            # (the grid strength chosen most often across the folds: the fit of step 4 refines it)
            out[name] = Scores(m, m, r, "grid " + ph.describe(name, m.params["strength"], self.cur.model))
        return out

    def add(self, name: str, params: dict[str, float] | None, reference_params: dict[str, float] | None,
            scores: Scores, hold: Sequence[Signals], progress: Progress) -> Trial:
        fit = ph.fit_strength(self.cur, name, self.meas_data, self._fits[name])
        strength = fit.model.effects[name]
        progress(f"step 4: fitted {name} at {ph.describe(name, strength, fit.model)}; constants "
                 f"{constants_text(fit.model)}"
                 + "".join(f"; {n} refitted to strength {fit.model.effects[n]:.3g}" for n in self.cur.free))
        flags = ph.fit_flags(fit, self.config, f"{name} fit")
        self.flags += flags
        params = {"strength": strength, **fit.model.constants(), **fit.companions()}
        return Trial(fit, predictions(fit.model, hold), params,
                     ph.describe(name, strength, fit.model), ph.fitted_value(name, strength, fit.model.params, fit.model.supply_v),
                     [f.text() for f in flags if f.blocks])

    def heldout(self, name: str, trial: Trial, scores: Scores, alpha: float) -> acc.Acceptance:
        # step 3's score refits the constants per fold: its blocks are held out of the fit
        return acc.from_score(name, scores.measured, "held-out blocks of the measured data (step 3)", alpha)

    def contradicted(self, name: str) -> str | None:
        """Heating, when the speed's response to the thermal state is the reference's: a slow
        drift the model lacks (a second battery RC branch, a drifting sensor) is fitted by a
        thermal state as well, and held-out data of the same drift confirm it. The network
        path's rule (``identify_heating``), which compares the response on both sets."""
        if name != "motor_heating" or self.ref_data is None:
            return None
        heat = identify_heating(self.meas_data.signals, self.ref_data.signals)
        return None if heat.changed else f"the speed's response to the thermal state is the reference's ({heat.describe()})"

    def keep(self, trial: Trial) -> None:
        self.cur = trial.model
        self._ref_pending.append(next(n for n in self.cur.free if n not in self._named))
        self._named.append(self._ref_pending[-1])

    def fitted(self, name: str) -> tuple[dict[str, Any], str, dict[str, Any]]:
        m = self.cur.model
        s = m.effects[name]
        return ({"strength": s, **m.constants(), **self.cur.companions()}, ph.describe(name, s, m),
                ph.fitted_value(name, s, m.params, m.supply_v))

    def finish(self, named: Sequence[str]) -> tuple[dict[str, Any], list[str], list[str]]:
        fields = {"holdout_rmse_uncalibrated": self.uncal_rmse, "reference_fit": self.reference_fit,
                  "calibrated_base": self.base.config(), "physics": self.cur.model.config(),
                  "fit_flags": [f.as_json() for f in self.flags]}
        head = [f"physics model calibrated on the measured data: {constants_text(self.base)}"
                f" (holdout RMSE {self.uncal_rmse:.2f} rad/s before calibration)"]
        tail = []
        if named:
            tail.append(f"with {', '.join(named)}: {constants_text(self.cur.model)}; strengths "
                        + ", ".join(f"{n} {self.cur.model.effects[n]:.3g}" for n in named))
        return fields, head, tail
