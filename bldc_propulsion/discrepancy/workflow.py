"""The discrepancy workflow: simulate, find the disagreement, name the effect, add it, show the gap.

One loop for both model kinds (``base.ModelKind``: the trained network, ``network.py``; the
bench physics, ``physics_kind.py``):

1. Simulate: the kind runs (and, the physics, calibrates) the model over the measured, reference
   and holdout recordings; residual r = measured - predicted.
2. Disagree: windows where the smoothed |r| exceeds 3 x the reference residual's robust sigma,
   with their operating conditions; whiteness and input cross-correlation tests; residual per
   operating condition (the disagreement map).
3. Name: every effect the model can still add is scored by the kind on held-out time blocks of
   the measured data (and of the measured data alone) and of the reference. NEW (``classify``):
   significant (p < alpha, >= min_effect) on the measured data and on the measured data alone,
   and the share of the residual it removes on the reference is less than STRUCTURAL_RATIO of
   the share it removes on the measured data; STRUCTURAL otherwise if it helps the reference. The best new effect (measured score) is proposed; for a kind whose scores are
   residual corrections, the identification rules (``identify.refine``) decide the dynamic
   family and heating from the response itself.
4. Add: the kind fits the effect into a trial model.
5. Keep or reject (``acceptance.py``): the trial is kept only if it beats the current model on
   data it was not fitted on (the holdout, at p < HOLDOUT_ALPHA: a replication of step 3's
   finding; else the kind's own held-out data, at p < alpha) by ACCEPT_MIN_REDUCTION, and no
   fitted quantity ended at a bound or implausibly far from the CONFIG; the first rejection
   ends the loop, and every candidate not added is reported as "considered, not added". Show: holdout RMSE before and after, overall and inside the
   holdout's disagreement windows. Repeat from 3 until nothing new is significant, a candidate
   is rejected, or ``max_effects``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .. import contract as c
from ..errors import BadInputError
from ..recordings import Signals
from . import acceptance as acc
from . import identify as idf
from . import residuals as rs
from . import scoring as sc
from .base import ALPHA, MIN_EFFECT, DataSet, ModelKind, Options, Progress, rmse
from .network import NetworkKind
from .physics_kind import PhysicsKind
from .results import (STRUCTURAL_RATIO, Disagreement, Evidence, Result, Round, gap_fields,
                      sentence, summary_lines, write_report)

__all__ = ["ALPHA", "MIN_EFFECT", "Options", "WorkflowResult", "check_effect_names", "check_holdout",
           "classify", "run", "run_physics_workflow", "run_workflow"]


@dataclass
class WorkflowResult:
    data: dict[str, Any]  #: the --json object (``result.as_json()``)
    model: Any  #: final model (the base model if nothing was added)
    lines: list[str]  #: the summary for people
    result: Result | None = None


def classify(meas: sc.Score, ref: sc.Score | None, alpha: float, min_effect: float) -> str:
    """'new', 'structural' or 'not significant'.

    The rule: an effect is structural when the share of the residual it removes on the reference
    is at least STRUCTURAL_RATIO of the share it removes on the measured data (significant or not
    there: a reference too short or noisy to reach significance must not turn a structural effect
    into a new one), and new when it is significant with a clear effect size on the measured data
    and not structural. Shares, not (rad/s)^2: a measured fit calibrated worse than the reference
    fit leaves more for any effect to remove, and an effect the reference needs as much is
    present there, whatever its absolute size on the measured data.
    """
    sig_meas = meas.p_value < alpha and meas.fraction >= min_effect
    sig_ref = ref is not None and ref.p_value < alpha and ref.fraction >= min_effect
    if sig_meas:
        if ref is not None and max(ref.fraction, 0.0) >= STRUCTURAL_RATIO * meas.fraction:
            return "structural"
        return "new"
    if sig_ref:
        return "structural"
    return "not significant"


def check_effect_names(names: Sequence[str] | None) -> list[str]:
    """``names`` as a list; BadInputError naming the first one that is not an effect of the contract."""
    for name in names or []:
        if name not in c.EFFECTS:
            raise BadInputError(f"--effects {name}: unknown effect (known: {', '.join(c.EFFECTS)})")
    return list(names or [])


def check_holdout(holdout: Sequence[Signals], measured: Sequence[Signals], reference: Sequence[Signals]) -> None:
    """The holdout must be data nothing is fitted on: refused (one line) when it overlaps the
    measured or the reference recordings; BadInputError too when it is too short to block."""
    if holdout:
        acc.check_holdout_disjoint(holdout, measured=measured, reference=reference)
        sc.make_blocks([s.duration_s for s in holdout], "holdout")


def windows_of(ds: DataSet, threshold: float) -> tuple[list[rs.Window], list[np.ndarray]]:
    wins: list[rs.Window] = []
    masks = []
    for s, r in zip(ds.signals, ds.residuals):
        w, m = rs.find_windows(s.path, s.t, r, s.pwm, s.voltage, threshold)
        wins += w
        masks.append(m)
    return wins, masks


def find_disagreement(meas: DataSet, ref: DataSet | None, progress: Progress) -> Disagreement:
    """Windows above 3 sigma of the reference residual (the measured one without a reference),
    whiteness and cross-correlation tests, residual per operating condition."""
    noise = rs.robust_sigma(np.concatenate(ref.residuals if ref else meas.residuals))
    if not np.isfinite(noise) or noise <= 0:
        noise = rs.robust_sigma(np.concatenate(meas.residuals))
    threshold = rs.THRESHOLD_SIGMAS * max(noise, 1e-6)
    windows, _ = windows_of(meas, threshold)

    def tests(ds: DataSet) -> Any:
        return rs.residual_tests(ds.residuals, [{"pwm": s.pwm, "pwm_rate": rs.pwm_rate(s.t, s.pwm)}
                                                for s in ds.signals])

    conditions = rs.condition_bins([s.t for s in meas.signals], meas.residuals,
                                   [s.pwm for s in meas.signals], [s.voltage for s in meas.signals])
    progress(f"step 2: {len(windows)} disagreement window(s) above {threshold:.1f} rad/s; "
             f"measured residual RMSE {rmse(meas.residuals):.2f} rad/s"
             + (f", reference {rmse(ref.residuals):.2f} rad/s" if ref else ""))
    return Disagreement(threshold, windows, tests(meas), tests(ref) if ref else None, conditions)


def run_workflow(model: Any, measured: Sequence[Signals], reference: Sequence[Signals],
                 holdout: Sequence[Signals], opts: Options, progress: Progress) -> WorkflowResult:
    """``discrepancy --model``: the loop with a trained network."""
    return run(NetworkKind(model, opts), measured, reference, holdout, opts, progress)


def run_physics_workflow(model: Any, measured: Sequence[Signals], reference: Sequence[Signals],
                         holdout: Sequence[Signals], opts: Options, progress: Progress) -> WorkflowResult:
    """``discrepancy --physics``: the loop with the bench physics (``physics.PhysicsModel``)."""
    return run(PhysicsKind(model), measured, reference, holdout, opts, progress)


def run(kind: ModelKind, measured: Sequence[Signals], reference: Sequence[Signals],
        holdout: Sequence[Signals], opts: Options, progress: Progress) -> WorkflowResult:
    """Steps 1-5 (see the module docstring) with ``kind``'s model."""
    restrict = check_effect_names(opts.restrict) or list(c.EFFECTS)
    warnings: list[str] = []
    if not reference:
        warnings.append(kind.no_reference)
    in_sample = not holdout
    if in_sample:
        warnings.append(f"no --holdout recordings: before/after RMSE is on the measured recordings, "
                        f"{kind.fitted_on} (optimistic)")
    hold = list(holdout) if holdout else list(measured)
    check_holdout(holdout, measured, reference)

    # step 1, step 2
    meas, ref, hold_base = kind.start(measured, reference, hold, progress)
    hold_cur = hold_base
    found = find_disagreement(meas, ref, progress)

    named: list[str] = []
    structural: list[dict[str, Any]] = []
    evidence: dict[str, Evidence] = {}
    rounds: list[Round] = []
    cache: dict[str, Any] = {}  # the identified dynamics, once per run
    no_verdict = kind.no_verdict()
    if no_verdict:
        progress(f"  no effect is named: {no_verdict}")
    while len(named) < opts.max_effects and not no_verdict:
        names = kind.candidates(restrict, named)
        if not names:
            progress("  every effect considered is already in the model")
            break
        progress(f"step 3: scoring {len(names)} candidate effect(s) on held-out time blocks")
        scores = kind.score(names, progress)
        round_ev: dict[str, Evidence] = {}
        best: str | None = None
        for name in names:
            feature, m, own, r = scores[name].feature, scores[name].measured, scores[name].measured_alone, \
                scores[name].reference
            verdict = classify(m, r, opts.alpha, opts.min_effect)
            if verdict == "new" and not (own.p_value < opts.alpha and own.fraction >= opts.min_effect):
                verdict = "not significant"
            ev = round_ev[name] = Evidence(name, verdict, m, own, r, feature,
                                           sentence(name, feature, m, r, verdict, kind.noun), kind.noun)
            progress(f"  {name:20s} measured {100 * m.fraction:6.1f} % (p {m.p_value:.2g})"
                     + (f" alone {100 * own.fraction:6.1f} % (p {own.p_value:.2g})" if own is not m else "")
                     + (f"  reference {100 * r.fraction:6.1f} % (p {r.p_value:.2g})" if r else "")
                     + f"  -> {verdict}")
            if verdict == "new" and (best is None or m.fraction > round_ev[best].measured.fraction):
                best = name
            if verdict == "structural" and name not in [x["effect"] for x in structural]:
                structural.append({"effect": name, "sentence": ev.sentence, "measured_mse_reduction": m.fraction,
                                   "reference_mse_reduction": r.fraction if r else None})
        # an effect named earlier is never a candidate again, so this round's evidence replaces
        # the earlier rounds' for every effect it scored
        evidence.update(round_ev)
        rounds.append(Round(round_ev))
        refined = idf.Refined(best)
        if kind.identifies_response:
            refined = idf.refine(round_ev, best, named, measured, reference, *kind.residual_rmse(), cache,
                                 opts.alpha, opts.min_effect, progress)
        if refined.best is None:
            progress("  no new effect is significant")
            break
        name = refined.best
        ev = round_ev[name]
        progress(f"  proposed: {ev.sentence}")
        trial = kind.add(name, refined.params, refined.reference_params, scores[name], hold, progress)
        if holdout:
            judged = acc.judge(name, hold, hold_cur.predictions, trial.hold.predictions, "holdout",
                               opts.replication_alpha)
        else:
            judged = kind.heldout(name, trial, scores[name], opts.alpha)
        if trial.flags:
            judged = dataclasses.replace(judged, at_bound="; ".join(trial.flags))
        against = kind.contradicted(name)
        if against:
            judged = dataclasses.replace(judged, contradicted=against)
        ev.acceptance = judged
        ev.refit(trial.parameters, trial.feature, trial.value)
        rounds[-1] = Round(round_ev, name, trial.parameters, rmse(trial.hold.residuals), judged, extra=trial.extra)
        progress(f"step 5: {judged.describe()}")
        if not judged.accepted:
            # the best candidate does not help data it was not fitted on: weaker ones will not either
            break
        kind.keep(trial)
        named.append(name)
        ev.named = True
        rounds[-1].named = name
        hold_cur = trial.hold

    # the one number: a named effect's fitted value as the final model has it (the physics path
    # refits earlier effects' strengths with every later one)
    for name in named:
        now = kind.fitted(name)
        if now is not None:
            evidence[name].refit(*now)

    # step 5: the gap
    hold_windows, hold_masks = windows_of(hold_base, found.threshold)
    kind_fields, head, tail = kind.finish(named)
    result = Result(
        named, structural, evidence, rounds, gap_fields(hold_base, hold_cur, hold_masks), found, hold_windows,
        {"reference": [s.path for s in reference], "measured": [s.path for s in measured],
         "holdout": [s.path for s in hold]},
        in_sample,
        {"alpha": opts.alpha, "holdout_alpha": opts.replication_alpha if holdout else None,
         "min_mse_reduction": opts.min_effect, "structural_ratio": STRUCTURAL_RATIO,
         "test": "one-sided paired sign-flip randomisation test over held-out time blocks"},
        [*warnings, *kind.warnings()], kind_fields, no_verdict)
    data = result.as_json()
    if opts.report_dir:
        data["report"] = write_report(Path(opts.report_dir), meas, hold_base, hold_cur, hold_windows, data,
                                      force=opts.report_force)
    return WorkflowResult(data, kind.model, [*head, *summary_lines(data), *tail], result)
