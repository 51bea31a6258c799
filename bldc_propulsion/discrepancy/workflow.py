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
   the share it removes on the measured data; STRUCTURAL otherwise if it helps the reference.
   These verdicts only PROPOSE and rank (``proposals``): the kind's ``identify`` refines the
   proposal (the network, whose scores are residual corrections, decides the dynamic family
   and heating from the response itself, ``identify.refine``) and its choice is tried first;
   then every other candidate new or structural on the measured data, or removing >=
   min_effect of the residual whatever its p, by that share (at most MAX_TRIALS per round).
4. Add: the kind fits the effect into a trial model.
5. Decide (``decide``, ``acceptance.py``): one test for every candidate, the held-out one, because
   a replication on recordings nothing was fitted on is the stronger evidence and one test per
   candidate cannot contradict itself. The trial is added only if it beats the current model on
   the holdout at p < HOLDOUT_ALPHA (else on the kind's own held-out data of the measured
   recordings, at p < alpha) by ACCEPT_MIN_REDUCTION, and no fitted quantity ended at a bound or
   implausibly far from the CONFIG. The first proposal that passes is added,
   labelled new or structural (``added_as``: structural = the model lacks it on its own
   reference data too); when every proposal fails, the loop ends, and every candidate not added
   is reported as "considered, not added" (or "structural" when it is one) with the figure of
   the test that decided. Show: holdout RMSE before and after, overall and inside the holdout's
   disagreement windows. Repeat from 3 until nothing is added or ``max_effects`` are.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Generic, TypeVar

import numpy as np

from .. import contract as c
from ..errors import BadInputError
from ..recordings import Signals
from . import acceptance as acc
from . import residuals as rs
from . import scoring as sc
from .base import ALPHA, MIN_EFFECT, FitT, ModelKind, Options, Progress, Proposal, Refined, Scores, Trial
from .dataset import DataSet, rmse
from .network import NetworkKind
from .physics_kind import PhysicsKind
from .results import (
    STRUCTURAL_RATIO,
    Disagreement,
    Evidence,
    Result,
    ResultJson,
    Round,
    StructuralJson,
    gap_fields,
    sentence,
    summary_lines,
    write_report,
)

if TYPE_CHECKING:
    from ..model import NetworkModel
    from ..physics.config import PhysicsConfig

__all__ = ["ALPHA", "MIN_EFFECT", "Options", "WorkflowResult", "check_effect_names", "check_holdout",
           "classify", "run", "run_physics_workflow", "run_workflow"]


#: The model a run hands back (a network, or the bench physics).
ModelT = TypeVar("ModelT")


@dataclass
class WorkflowResult(Generic[ModelT]):
    data: ResultJson  #: the --json object (``result.as_json()``)
    model: ModelT  #: final model (the base model if nothing was added)
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


#: Most candidates fitted and judged per round (each costs a fit, a network's a retraining).
MAX_TRIALS = 3
#: The holdout's residual (calibrated base) this many times the measured data's: a coverage warning
COVERAGE_FACTOR = 3.0

#: The deciding rule, printed with every run (module docstring, step 5).
RULE = ("the measured data only propose and rank the candidates; the test that adds or rejects each one is the "
        "held-out one (the --holdout when given, else held-out data of the measured recordings), because a "
        "replication on recordings nothing was fitted on is the stronger evidence and one test for every "
        "candidate cannot contradict itself; the k candidates tried in a round are each tested at alpha / k, "
        "so trying several does not raise the chance of a false addition")


def proposals(ev: dict[str, Evidence], first: str | None, min_effect: float) -> list[str]:
    """The candidates step 4 fits, in the order they are tried (at most MAX_TRIALS): the
    identification's (or the scores') proposal, then every other one the measured data propose
    (new or structural there, or removing >= ``min_effect`` of the residual whatever its p), by
    the share it removes; those the identification found unchanged from the reference ("not
    new") after the others, since it proposes and ranks like the scores and decides nothing."""
    rest = [k for k, e in ev.items() if k != first and e.proposed(min_effect)]
    rest.sort(key=lambda k: (ev[k].verdict.startswith("not new"), -ev[k].measured.fraction))
    return ([first] if first is not None else []) + rest[:MAX_TRIALS - (first is not None)]


def added_as(ev: Evidence) -> str:
    """'new' or 'structural' for an effect the deciding test added: the step-3 (or the
    identification's) verdict when it was one of them, else by the shares it removes (classify's
    rule without the measured data's significance, which does not decide here). The reference's
    share is compared with the smaller of the measured data's two: the correction fitted on the
    measured data alone is the like of the reference's (fitted on the reference alone), and the
    pooled fit's share on the measured data can exceed it by what the pooling adds; an effect the
    measured data alone do not show, which the holdout still confirms, improves the model wherever
    it runs: structural."""
    if ev.verdict in ("new", "structural"):
        return ev.verdict
    if ev.verdict.startswith("not new"):  # the response is the reference's: the model's own lack
        return "structural"
    if ev.reference is None:
        return "new"
    m = min(ev.measured.fraction, ev.measured_alone.fraction)
    # new in the measured data only where the measured data alone show it and the reference less
    return "new" if m > 0 and max(ev.reference.fraction, 0.0) < STRUCTURAL_RATIO * m else "structural"


def decide(kind: ModelKind[object, FitT], name: str, trial: Trial[FitT], scores: Scores, hold: Sequence[Signals],
           hold_cur: DataSet, holdout: bool, opts: Options, tried: int = 1) -> acc.Acceptance:
    """The deciding test of one fitted candidate (RULE): the --holdout against the current model,
    else the kind's own held-out data of the measured recordings, at the level divided by the
    ``tried`` candidates of the round (Bonferroni: the first of several that passes is added, so
    each is held to alpha / k for the round's chance of a false addition to stay at alpha)."""
    if not holdout:
        return kind.heldout(name, trial, scores, opts.alpha / tried)
    return acc.judge(name, hold, hold_cur.predictions, trial.hold.predictions, "holdout",
                     opts.replication_alpha / tried)


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
    for s, r in zip(ds.signals, ds.residuals, strict=True):
        w, m = rs.find_windows(s.path, s.t, r, s.pwm, s.voltage, threshold)
        wins += w
        masks.append(m)
    return wins, masks


def coverage_warning(meas: DataSet, hold_base: DataSet, hold_windows: Sequence[rs.Window]) -> str | None:
    """A line when the holdout disagrees with the calibrated model far more than the measured data
    do (COVERAGE_FACTOR): it holds conditions the measured recordings lack (a level commanded from
    rest, a charge, a length under load), where they can neither show nor fit what is missing, so
    "nothing named" there is no verdict on it. Names the holdout's worst window."""
    before, measured = rmse(hold_base.residuals), rmse(meas.residuals)
    if not (measured > 0 and before > COVERAGE_FACTOR * measured):
        return None
    text = (f"the holdout disagrees with the calibrated model {before / measured:.1f}x as much as the measured "
            f"data do ({before:.2f} vs {measured:.2f} rad/s RMS): it has conditions the measured recordings "
            "do not cover, where they cannot show what is missing")
    if hold_windows:
        w = max(hold_windows, key=lambda w: w.rms_residual_rad_s * (w.t_end_s - w.t_start_s) ** 0.5)
        text += (f"; worst: {Path(w.path).name} {w.t_start_s:.1f}-{w.t_end_s:.1f} s, RMS "
                 f"{w.rms_residual_rad_s:.1f} rad/s at PWM {w.pwm_mean:.4f} ({w.pwm_direction}); record "
                 "measured data there")
    return text


def find_disagreement(meas: DataSet, ref: DataSet | None, progress: Progress) -> Disagreement:
    """Windows above 3 sigma of the reference residual (the measured one without a reference),
    whiteness and cross-correlation tests, residual per operating condition."""
    noise = rs.robust_sigma(np.concatenate(ref.residuals if ref else meas.residuals))
    if not np.isfinite(noise) or noise <= 0:
        noise = rs.robust_sigma(np.concatenate(meas.residuals))
    threshold = rs.THRESHOLD_SIGMAS * max(noise, 1e-6)
    windows, _ = windows_of(meas, threshold)

    def tests(ds: DataSet) -> rs.ResidualTests:
        return rs.residual_tests(ds.residuals, [{"pwm": s.pwm, "pwm_rate": rs.pwm_rate(s.t, s.pwm)}
                                                for s in ds.signals])

    conditions = rs.condition_bins([s.t for s in meas.signals], meas.residuals,
                                   [s.pwm for s in meas.signals], [s.voltage for s in meas.signals])
    progress(f"step 2: {len(windows)} disagreement window(s) above {threshold:.1f} rad/s; "
             f"measured residual RMSE {rmse(meas.residuals):.2f} rad/s"
             + (f", reference {rmse(ref.residuals):.2f} rad/s" if ref else ""))
    return Disagreement(threshold, windows, tests(meas), tests(ref) if ref else None, conditions)


def run_workflow(model: NetworkModel, measured: Sequence[Signals], reference: Sequence[Signals],
                 holdout: Sequence[Signals], opts: Options, progress: Progress) -> WorkflowResult[NetworkModel]:
    """``discrepancy --model``: the loop with a trained network."""
    return run(NetworkKind(model, opts), measured, reference, holdout, opts, progress)


def run_physics_workflow(model: PhysicsConfig, measured: Sequence[Signals], reference: Sequence[Signals],
                         holdout: Sequence[Signals], opts: Options, progress: Progress
                         ) -> WorkflowResult[PhysicsConfig]:
    """``discrepancy --physics``: the loop with the bench physics (``physics.config.PhysicsConfig``)."""
    return run(PhysicsKind(model), measured, reference, holdout, opts, progress)


class _Rounds(Generic[FitT]):
    """Steps 3-5 round by round: what the rounds found (every effect added, the new ones among
    them, the structural ones, the evidence and the rounds) and the current model's prediction on
    the holdout."""

    def __init__(self, kind: ModelKind[object, FitT], hold: Sequence[Signals], holdout: bool, hold_base: DataSet,
                 opts: Options, progress: Progress) -> None:
        self.kind, self.hold, self.holdout, self.opts, self.progress = kind, hold, holdout, opts, progress
        self.hold_cur = hold_base
        self.added: list[str] = []  # every effect added, in order (new and structural)
        self.named: list[str] = []  # the new ones
        self.structural: list[StructuralJson] = []
        self.evidence: dict[str, Evidence] = {}
        self.rounds: list[Round] = []

    def verdicts(self, names: Sequence[str], scores: dict[str, Scores]) -> tuple[dict[str, Evidence], str | None]:
        """Step 3's verdicts on the measured data, which only propose: every candidate's evidence
        (a new round), and the new one that removes the most of the residual (None: none is new)."""
        opts, noun = self.opts, self.kind.noun
        round_ev: dict[str, Evidence] = {}
        best: str | None = None
        for name in names:
            feature, m, own, r = scores[name].feature, scores[name].measured, scores[name].measured_alone, \
                scores[name].reference
            verdict = classify(m, r, opts.alpha, opts.min_effect)
            if verdict == "new" and not (own.p_value < opts.alpha and own.fraction >= opts.min_effect):
                verdict = "not significant"
            ev = round_ev[name] = Evidence(name, verdict, m, own, r, feature,
                                           sentence(name, feature, m, r, verdict, noun), noun)
            self.progress(f"  {name:20s} measured {100 * m.fraction:6.1f} % (p {m.p_value:.2g})"
                          + (f" alone {100 * own.fraction:6.1f} % (p {own.p_value:.2g})" if own is not m else "")
                          + (f"  reference {100 * r.fraction:6.1f} % (p {r.p_value:.2g})" if r else "")
                          + f"  -> {verdict} on the measured data (proposes only)")
            if verdict == "new" and (best is None or m.fraction > round_ev[best].measured.fraction):
                best = name
            if verdict == "structural" and name not in [x["effect"] for x in self.structural]:
                self.structural.append({"effect": name, "sentence": ev.sentence, "measured_mse_reduction": m.fraction,
                                        "reference_mse_reduction": r.fraction if r else None})
        # an effect named earlier is never a candidate again, so this round's evidence replaces
        # the earlier rounds' for every effect it scored
        self.evidence.update(round_ev)
        self.rounds.append(Round(round_ev))
        return round_ev, best

    def try_in_turn(self, tried: Sequence[str], refined: Refined,
                    scores: dict[str, Scores]) -> tuple[str, Trial[FitT]] | None:
        """Steps 4 and 5 for each proposal in turn: the first one the deciding test accepts, and its
        trial (None: every one failed)."""
        kind, progress = self.kind, self.progress
        for name in tried:
            ev = self.rounds[-1].evidence[name]
            progress(f"  proposed: {ev.sentence}")
            params = (refined.params, refined.reference_params) if name == refined.best else (None, None)
            trial = kind.add(name, *params, scores[name], self.hold, progress)
            judged = decide(kind, name, trial, scores[name], self.hold, self.hold_cur, self.holdout, self.opts,
                            len(tried))
            if trial.flags:
                judged = dataclasses.replace(judged, at_bound="; ".join(trial.flags))
            against = kind.contradicted(name)
            if against:
                judged = dataclasses.replace(judged, contradicted=against)
            ev.acceptance = judged
            ev.refit(trial.parameters, trial.feature, trial.value)
            self.rounds[-1].trials.append({"effect": name, "parameters": trial.parameters, **trial.extra,
                                           "holdout_rmse_rad_s": rmse(trial.hold.residuals),
                                           "acceptance": judged.as_json()})
            self.rounds[-1] = dataclasses.replace(self.rounds[-1], proposed=name, parameters=trial.parameters,
                                                  holdout_rmse=rmse(trial.hold.residuals), acceptance=judged,
                                                  extra=trial.extra)
            progress(f"step 5: {judged.describe()}")
            if judged.accepted:
                return name, trial
        return None

    def add(self, name: str, kept: Trial[FitT]) -> None:
        """The accepted trial becomes the model; ``name`` is added (new or structural)."""
        self.kind.keep(kept)
        self.added.append(name)
        ev = self.rounds[-1].evidence[name]
        ev.added_as = added_as(ev)
        if ev.verdict_residual is None and ev.verdict not in ("new", "structural"):
            # the sentence says what it was added as, not the measured test's (proposing) verdict
            ev.sentence = sentence(name, ev.feature, ev.measured, ev.reference, ev.added_as, self.kind.noun)
        if ev.added_as == "new":
            self.named.append(name)
        ev.named = True
        self.rounds[-1].named = name
        self.hold_cur = kept.hold


def run(kind: ModelKind[ModelT, FitT], measured: Sequence[Signals], reference: Sequence[Signals],
        holdout: Sequence[Signals], opts: Options, progress: Progress) -> WorkflowResult[ModelT]:
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
    found = find_disagreement(meas, ref, progress)

    loop = _Rounds(kind, hold, bool(holdout), hold_base, opts, progress)
    no_verdict = kind.no_verdict()
    if no_verdict:
        progress(f"  no effect is named: {no_verdict}")
    if not no_verdict:
        progress(f"the rule: {RULE}")
    while len(loop.added) < opts.max_effects and not no_verdict:
        names = kind.candidates(restrict, loop.added)
        if not names:
            progress("  every effect considered is already in the model")
            break
        progress(f"step 3: scoring {len(names)} candidate effect(s) on held-out time blocks")
        scores = kind.score(names, progress)
        round_ev, best = loop.verdicts(names, scores)
        refined = kind.identify(Proposal(round_ev, best, loop.added), progress)
        tried = proposals(round_ev, refined.best, opts.min_effect)
        if not tried:
            progress(f"  nothing to propose: no candidate removes >= {100 * opts.min_effect:.0f} % of the "
                     "residual on the measured data")
            break
        kept = loop.try_in_turn(tried, refined, scores)
        if kept is None:
            # every proposal failed the deciding test: a later round would propose the same
            break
        loop.add(*kept)
    added, evidence, hold_cur = loop.added, loop.evidence, loop.hold_cur

    # the one number: a named effect's fitted value as the final model has it (the physics path
    # refits earlier effects' strengths with every later one)
    for name in added:
        now = kind.fitted(name)
        if now is not None:
            evidence[name].refit(*now)

    # step 5: the gap
    hold_windows, hold_masks = windows_of(hold_base, found.threshold)
    uncovered = None if in_sample else coverage_warning(meas, hold_base, hold_windows)
    if uncovered:
        warnings.append(uncovered)  # printed with the command's other warnings, once
    kind_fields, head, tail = kind.finish(added)
    result = Result(
        loop.named, loop.structural, evidence, loop.rounds, gap_fields(hold_base, hold_cur, hold_masks), found,
        hold_windows,
        {"reference": [s.path for s in reference], "measured": [s.path for s in measured],
         "holdout": [s.path for s in hold]},
        in_sample,
        {"alpha": opts.alpha, "holdout_alpha": opts.replication_alpha if holdout else None,
         "min_mse_reduction": opts.min_effect, "structural_ratio": STRUCTURAL_RATIO,
         "test": "one-sided paired sign-flip randomisation test over held-out time blocks"},
        [*warnings, *kind.warnings()], kind_fields, no_verdict, added)
    data = result.as_json()
    if opts.report_dir:
        data["report"] = write_report(Path(opts.report_dir), meas, hold_base, hold_cur, hold_windows, data,
                                      force=opts.report_force)
    return WorkflowResult(data, kind.model, [*head, *summary_lines(data), *tail], result)
