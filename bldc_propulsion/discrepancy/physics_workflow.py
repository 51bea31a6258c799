"""The discrepancy workflow with the bench physics as the model (``discrepancy --physics``).

Same steps, data and summary as the network path (``workflow.py``), the model being a
``physics.PhysicsModel``:

1. Reference first (with --reference): Kv, CP and the strengths of the CONFIG's effects fitted on
   the reference recordings (``physics.fit_reference``); then Kv and CP calibrated on the measured
   recordings; residual r = measured - predicted.
2. Disagreement windows, whiteness and input cross-correlation tests, the condition map.
3. Name: every effect that is off in the model is switched on (strength grid, constants
   recalibrated) and scored on held-out time blocks of the measured data and, separately
   calibrated, of the reference data; new / structural by ``workflow.classify``.
4. Add: the best new effect at the strength fitted on all measured data (constants with it),
   kept only if it improves held-out data (``acceptance.py``: the holdout, else step 3's per-fold
   scores) and its strength did not end at a bound.
5. Show: holdout RMSE before (the calibrated base) and after. Repeat from 3.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .. import contract as c
from ..recordings import Signals
from . import acceptance as acc
from . import physics as ph
from .workflow import (DataSet, Options, Progress, WorkflowResult, _rmse, check_effect_names, check_holdout, classify,
                       explained_mse, find_disagreement, gap_fields, shared_fields, summary_lines, windows_of,
                       write_report)


def constants_text(model: ph.PhysicsModel) -> str:
    return ", ".join(f"{k} {v:.4g}" for k, v in model.constants().items())


def predictions(model: ph.PhysicsModel, signals: Sequence[Signals]) -> DataSet:
    return DataSet(list(signals), [model.predict(s) for s in signals])


def sentence(name: str, strength: float, p: Any, m: Any, r: Any, verdict: str) -> str:
    what = ph.describe(name, strength, p)
    ref = (f"{100 * max(r.fraction, 0):.0f} % on the reference data (p = {r.p_value:.2g}), "
           f"{explained_mse(r) / max(explained_mse(m), 1e-12):.2g} times the mean squared residual it "
           f"removes on the measured data" if r is not None else "the reference data were not available")
    core = (f"{what} removes {100 * m.fraction:.0f} % of the calibrated physics model's residual on "
            f"held-out time blocks of the measured data ({m.blocks_improved} of {m.blocks} blocks better, "
            f"p = {m.p_value:.2g})")
    if verdict == "new":
        return f"{core}; {ref}"
    if verdict == "structural":
        return f"{core} and {ref}: the model lacks it on the reference data too (structural)"
    return f"{core}: not significant"


def run_physics_workflow(model: ph.PhysicsModel, measured: Sequence[Signals], reference: Sequence[Signals],
                         holdout: Sequence[Signals], opts: Options, progress: Progress) -> WorkflowResult:
    restrict = check_effect_names(opts.restrict) or list(c.EFFECTS)
    warnings: list[str] = []
    if not reference:
        warnings.append("no --reference recordings: new and structural findings cannot be told apart")
    in_sample = not holdout
    if in_sample:
        warnings.append("no --holdout recordings: before/after RMSE is on the measured recordings, "
                        "which the constants and strengths were fitted on (optimistic)")
    hold = list(holdout) if holdout else list(measured)
    check_holdout(holdout, measured, reference)
    meas_data = ph.Data.of(measured, "measured")
    ref_data = ph.Data.of(reference, "reference") if reference else None

    # step 1
    model = model.with_supply(measured)
    uncal_rmse = _rmse(predictions(model, hold).residuals)
    reference_fit: dict[str, Any] | None = None
    if ref_data is not None:
        # reference first: what the model needs to agree with its own data is structural; only
        # what the measured data need beyond it can be new
        on = [n for n in c.EFFECTS if model.effects[n] > 0.0]
        progress(f"step 1: reference first: {', '.join([*ph.CALIBRATED, *on])} fitted on "
                 f"{len(reference)} reference recording(s)")
        rf = ph.fit_reference(model, ref_data)
        model = rf.model
        bounds = ph.at_bounds(rf)
        reference_fit = {"constants": rf.model.constants(), "strengths": {n: rf.model.effects[n] for n in on},
                         "rmse_rad_s": float(np.sqrt(rf.sse / max(len(rf.r), 1))), "at_bound": bounds}
        progress(f"  reference fit: {constants_text(model)}; strengths "
                 + (", ".join(f"{n} {model.effects[n]:.2f}" for n in on) or "none")
                 + f"; RMSE {reference_fit['rmse_rad_s']:.2f} rad/s")
        warnings += [f"reference fit: {b}: the fit is not a basis for a verdict on it" for b in bounds]
    progress(f"step 1: calibrating {', '.join(ph.CALIBRATED)} on {len(measured)} measured recording(s)")
    cur = ph.calibrate_base(model, meas_data)
    cur_ref = ph.calibrate_base(model, ref_data) if ref_data else None
    base = cur.model
    progress(f"  calibrated: {constants_text(base)}"
             + f" (holdout RMSE {uncal_rmse:.2f} rad/s uncalibrated)")
    meas = predictions(base, measured)
    ref = predictions(cur_ref.model, reference) if cur_ref else None
    hold_base = predictions(base, hold)
    hold_cur = hold_base

    # step 2
    found = find_disagreement(meas, ref, progress)

    named: list[str] = []
    structural: list[dict[str, Any]] = []
    evidence: dict[str, Any] = {}
    iterations: list[dict[str, Any]] = []
    while len(named) < opts.max_effects:
        cands = [n for n in restrict if cur.model.effects[n] == 0.0]
        if not cands:
            progress("  every effect considered is already on in the model")
            break
        progress(f"step 3: switching on {len(cands)} effect(s) one at a time, scored on held-out time blocks")
        round_ev: dict[str, Any] = {}
        fits: dict[str, list[ph.Fit]] = {}
        scores: dict[str, Any] = {}
        best: tuple[float, str] | None = None
        for name in cands:
            grid = ph.STRENGTH_GRID[name]
            fits[name] = ph.effect_fits(cur, name, meas_data)
            m = ph.score(cur, fits[name], grid, meas_data)
            r = ph.score(cur_ref, ph.effect_fits(cur_ref, name, ref_data), grid, ref_data) if cur_ref else None
            scores[name] = m
            verdict = classify(m, r, opts.alpha, opts.min_effect)
            strength = m.params["strength"]
            round_ev[name] = {
                "verdict": verdict,
                "measured": m.as_dict(),
                "reference": r.as_dict() if r is not None else None,
                "p_value": m.p_value,
                "feature": ph.describe(name, strength, cur.model.params),
                "sentence": sentence(name, strength, cur.model.params, m, r, verdict),
            }
            progress(f"  {name:20s} measured {100 * m.fraction:6.1f} % (p {m.p_value:.2g})"
                     + (f"  reference {100 * r.fraction:6.1f} % (p {r.p_value:.2g})" if r else "")
                     + f"  -> {verdict}")
            if verdict == "new" and (best is None or m.fraction > best[0]):
                best = (m.fraction, name)
            if verdict == "structural" and name not in [x["effect"] for x in structural]:
                structural.append({"effect": name, "sentence": round_ev[name]["sentence"],
                                   "measured_mse_reduction": m.fraction,
                                   "reference_mse_reduction": r.fraction if r else None})
        for k, v in round_ev.items():
            if k not in named:
                evidence[k] = v
        iterations.append({"evidence": round_ev})
        if best is None:
            progress("  no new effect is significant")
            break
        name = best[1]
        trial = ph.fit_strength(cur, name, meas_data, fits[name])
        hold_new = predictions(trial.model, hold)
        if holdout:
            judged = acc.judge(name, hold, hold_cur.predictions, hold_new.predictions, "holdout", opts.alpha)
        else:
            # step 3's score refits the constants per fold: its blocks are held out of the fit
            judged = acc.from_score(name, scores[name], "held-out blocks of the measured data (step 3)",
                                    opts.alpha)
        strength = trial.model.effects[name]
        bound = ph.strength_at_bound(name, strength)
        if bound:
            judged = dataclasses.replace(judged, at_bound=bound)
        evidence[name].update(feature=ph.describe(name, strength, trial.model.params),
                              fitted_parameters={"strength": strength, **trial.model.constants()},
                              acceptance=judged.as_json())
        iterations[-1].update(proposed=name, parameters=evidence[name]["fitted_parameters"],
                              holdout_rmse_rad_s=_rmse(hold_new.residuals), acceptance=judged.as_json())
        progress(f"  proposed: {evidence[name]['sentence']}")
        progress(f"step 4: fitted {ph.describe(name, strength, trial.model.params)}; constants "
                 f"{constants_text(trial.model)}")
        progress(f"step 5: {judged.describe()}")
        if not judged.accepted:
            break
        cur = trial
        if cur_ref is not None:
            cur_ref = ph.recalibrate(cur_ref, cur_ref.model.with_effect(name, cur.model.effects[name]), ref_data,
                                     cur.free)
        named.append(name)
        evidence[name]["named"] = True
        iterations[-1]["named"] = name
        hold_cur = hold_new

    # step 5: the gap
    hold_final = hold_cur
    hold_windows, hold_masks = windows_of(hold_base, found.threshold)
    structural = [x for x in structural if x["effect"] not in named]
    data: dict[str, Any] = {
        "named": named,
        "structural": structural,
        "considered_not_added": acc.considered(evidence, named),
        **gap_fields(hold_base, hold_final, hold_masks),
        "holdout_rmse_uncalibrated": uncal_rmse,
        **shared_fields(hold, found, hold_windows, reference, measured, opts, in_sample),
        "evidence": evidence,
        "iterations": iterations,
        "reference_fit": reference_fit,
        "calibrated_base": base.config(),
        "physics": cur.model.config(),
        "warnings": warnings,
        "model": None,
    }
    if opts.report_dir:
        data["report"] = write_report(Path(opts.report_dir), meas, hold_base, hold_final, found.windows,
                                      hold_windows, data, force=opts.report_force)
    lines = [f"physics model calibrated on the measured data: {constants_text(base)}"
             + f" (holdout RMSE {uncal_rmse:.2f} rad/s before calibration)", *summary_lines(data)]
    if named:
        lines.append(f"with {', '.join(named)}: {constants_text(cur.model)}; strengths "
                     + ", ".join(f"{n} {cur.model.effects[n]:.2f}" for n in named))
    return WorkflowResult(data, cur.model, lines)
