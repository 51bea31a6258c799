"""The discrepancy workflow: simulate, find the disagreement, name the effect, add it, show the gap.

1. Simulate: run the model over the measured recordings' inputs; residual r = measured - predicted.
2. Disagree: windows where the smoothed |r| exceeds 3 x the reference residual's robust sigma,
   with their operating conditions; whiteness and input cross-correlation tests; residual per
   operating condition (the disagreement map).
3. Name: every candidate effect (``effects.py``) is scored on held-out time blocks
   (``scoring.py``) three ways: on the measured blocks with the corrections fitted on measured +
   reference pooled (what differs between them: a residual offset that only the battery voltage
   lines up with), on the measured data alone (structure within them), and on the reference
   alone. NEW: significant (p < alpha, >= min_effect) both pooled and alone, and the mean squared
   residual (rad/s)^2 it removes on the reference is less than STRUCTURAL_RATIO of what it
   removes on the measured data. STRUCTURAL otherwise if it helps the reference. The best new
   effect (pooled score) is named; the dynamic family is decided by identifying the response.
   Effects that change the RESPONSE to a feature both sets share (the same commands, the same
   thermal state) cannot show in the pooled residual score: the ESC start level is identified
   with the dynamics (a coast to zero below it is not a slower spin-down), and motor heating by
   fitting the speed's response to the thermal state on both sets together
   (``effects.identify_heating``), each named when it changed beyond its margin.
4. Add: the network is retrained with the effect's input (fitted parameters) on reference +
   measured recordings, early-stopped on the measured recordings' last part, starting from the
   base model's own weights (the new input's at 0). An effect that maps the command before the
   ESC (the start level) replaces the model's command inputs by the mapped ones, weights carried over.
5. Keep or reject (``acceptance.py``): the retrained network is kept only if it beats the current
   one on data it was not trained on (the holdout; else the measured recordings' early-stopping
   tail) by ACCEPT_MIN_REDUCTION at p < alpha; the first rejection ends the loop, and every
   candidate not added is reported as "considered, not added". Show: holdout RMSE before and
   after, overall and inside the holdout's disagreement windows. Repeat from 2 with the new
   model until nothing new is significant, a candidate is rejected, or ``max_effects``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .. import contract as c
from ..atomic import report_output
from ..core import effect_features as ef
from ..errors import BadInputError
from ..recordings import Signals
from ..training.evaluate import predict_speed
from ..training.train import features_of, train_model
from . import acceptance as acc
from . import effects as fx
from . import residuals as rs
from . import scoring as sc

Progress = Callable[[str], None]

#: Decision thresholds (see the module docstring).
ALPHA = 0.01  #: significance level of the held-out randomisation test
MIN_EFFECT = 0.10  #: least fractional held-out MSE reduction (beyond the null correction)
STRUCTURAL_RATIO = 0.5  #: reference reduction >= this x measured reduction -> structural
#: An effect must beat every other candidate of the same family (dynamics) by this fraction of
#: the held-out MSE to be preferred over a simpler one: lag < delay < asymmetric lag.
VALIDATION_FRACTION = 0.2
#: Measured residual RMSE >= this x the reference's, with no residual feature significant: the
#: response (dynamics, start level) is identified directly all the same.
GAP_RATIO = 1.5


@dataclass
class Options:
    max_effects: int = 3
    restrict: Sequence[str] | None = None
    hidden: int | None = None
    max_epochs: int = 300
    patience: int = 6
    seed: int = 0
    alpha: float = ALPHA
    min_effect: float = MIN_EFFECT
    report_dir: str | None = None
    report_force: bool = False  #: --force: an earlier report at report_dir may be replaced
    warm_start: bool = True  #: retrain from the base model's weights (see warm_start_weights)


@dataclass
class DataSet:
    """Recordings, the current model's prediction on them, and the residual."""

    signals: list[Signals]
    predictions: list[np.ndarray] = field(default_factory=list)
    inputs: list[np.ndarray] = field(default_factory=list)  # model inputs scaled to [-1, 1]

    @property
    def residuals(self) -> list[np.ndarray]:
        return [s.speed - p for s, p in zip(self.signals, self.predictions)]


def check_inputs_computable(model: Any, signals: Sequence[Signals]) -> None:
    """BadInputError naming the input that cannot be computed from the recordings."""
    for name in model.input_names:
        for s in signals:
            try:
                x = features_of(s, [name], model.feature_params())
            except (KeyError, ValueError, BadInputError) as exc:
                raise BadInputError(
                    f"model input '{name}' cannot be computed from {s.path}: {exc}"
                ) from None
            if not np.any(np.isfinite(x)):
                raise BadInputError(f"model input '{name}' cannot be computed from {s.path} (no valid value)")


def run_model(model: Any, signals: Sequence[Signals]) -> DataSet:
    ds = DataSet(list(signals))
    for s in signals:
        ds.predictions.append(predict_speed(model, s))
        X = features_of(s, model.input_names, model.feature_params())
        lo, hi = np.asarray(model.input_min), np.asarray(model.input_max)
        span = np.where(hi > lo, hi - lo, 1.0)
        ds.inputs.append(np.clip(2.0 * (X - lo) / span - 1.0, -1.5, 1.5))
    return ds


def _rmse(residuals: Sequence[np.ndarray], masks: Sequence[np.ndarray] | None = None) -> float:
    parts = []
    for k, r in enumerate(residuals):
        sel = np.isfinite(r)
        if masks is not None:
            sel &= masks[k]
        parts.append(r[sel])
    x = np.concatenate(parts) if parts else np.zeros(0)
    return float(np.sqrt(np.mean(x**2))) if len(x) else float("nan")


# --- step 3: scores -------------------------------------------------------------------------------
def score_dataset(ds: DataSet, cands: Sequence[fx.Candidate], speed_scale: float, what: str) -> dict[str, sc.Score]:
    blocks = sc.make_blocks([s.duration_s for s in ds.signals], what)
    labels = sc.block_labels([len(s.t) for s in ds.signals], blocks)
    ctxs = [fx.Context(s, p, speed_scale) for s, p in zip(ds.signals, ds.predictions)]
    r = np.concatenate(ds.residuals)
    null_X = np.vstack([fx.null_columns(cx, z) for cx, z in zip(ctxs, ds.inputs)])
    out: dict[str, sc.Score] = {}
    for cand in cands:
        extras = [np.vstack([cand.columns(cx, prm) for cx in ctxs]) for prm in cand.grid]
        out[cand.effect] = sc.score_candidate(r, labels, null_X, extras, cand.grid)
    return out


def score_pooled(meas: DataSet, ref: DataSet | None, cands: Sequence[fx.Candidate],
                 speed_scale: float) -> tuple[dict[str, sc.Score], dict[str, sc.Score]]:
    """Scores on held-out blocks of the measured and of the reference data, the corrections
    fitted on both pooled (see ``scoring.score_candidate_groups``)."""
    if ref is None:
        return score_dataset(meas, cands, speed_scale, "measured"), {}
    sets = [meas, ref]
    labels, groups, first = [], [], 0
    for ds, what in zip(sets, ("measured", "reference")):
        blocks = sc.make_blocks([s.duration_s for s in ds.signals], what)
        lab = sc.block_labels([len(s.t) for s in ds.signals], blocks)
        labels.append(np.where(lab >= 0, lab + first, -1))
        groups.append(np.arange(first, first + int(sum(blocks))))
        first += int(sum(blocks))
    lab = np.concatenate(labels)
    ctxs = [fx.Context(s, p, speed_scale) for ds in sets for s, p in zip(ds.signals, ds.predictions)]
    r = np.concatenate([np.concatenate(ds.residuals) for ds in sets])
    null_X = np.vstack([fx.null_columns(cx, z) for cx, z in zip(ctxs, [z for ds in sets for z in ds.inputs])])
    out_m: dict[str, sc.Score] = {}
    out_r: dict[str, sc.Score] = {}
    for cand in cands:
        extras = [np.vstack([cand.columns(cx, prm) for cx in ctxs]) for prm in cand.grid]
        out_m[cand.effect], out_r[cand.effect] = sc.score_candidate_groups(r, lab, null_X, extras, cand.grid, groups)
    return out_m, out_r


def explained_mse(score: sc.Score | None) -> float:
    """Held-out mean squared residual (rad/s)^2 that the effect removes beyond the null."""
    if score is None or not np.isfinite(score.rmse_null):
        return 0.0
    return max(score.fraction, 0.0) * score.rmse_null**2


def fitted_params(ds: DataSet, cand: fx.Candidate, speed_scale: float) -> dict[str, float]:
    ctxs = [fx.Context(s, p, speed_scale) for s, p in zip(ds.signals, ds.predictions)]
    r = np.concatenate(ds.residuals)
    null_X = np.vstack([fx.null_columns(cx, z) for cx, z in zip(ctxs, ds.inputs)])
    extras = [np.vstack([cand.columns(cx, prm) for cx in ctxs]) for prm in cand.grid]
    return sc.fit_params(r, null_X, extras, cand.grid)


def classify(meas: sc.Score, ref: sc.Score | None, alpha: float, min_effect: float) -> str:
    """'new', 'structural' or 'not significant'.

    New: significant with a clear effect size on the measured data, and the mean squared residual
    it removes on the reference is less than STRUCTURAL_RATIO of what it removes on the measured (significant or not: a reference too short or noisy
    to reach significance must not turn a structural effect into a new one).
    """
    sig_meas = meas.p_value < alpha and meas.fraction >= min_effect
    sig_ref = ref is not None and ref.p_value < alpha and ref.fraction >= min_effect
    if sig_meas:
        # compared in absolute terms (rad/s)^2: an effect that removes a 35 rad/s offset on the
        # measured data and 3 rad/s of scatter on the reference is what changed, even though both
        # are a similar fraction of their own residual
        if ref is not None and explained_mse(ref) >= STRUCTURAL_RATIO * explained_mse(meas):
            return "structural"
        return "new"
    if sig_ref:
        return "structural"
    return "not significant"


def sentence(effect: str, cand: fx.Candidate, params: dict[str, float], meas: sc.Score,
             ref: sc.Score | None, verdict: str) -> str:
    ref_txt = (f"{100 * max(ref.fraction, 0):.0f} % on the reference data (p = {ref.p_value:.2g}), "
               f"{explained_mse(ref) / max(explained_mse(meas), 1e-12):.2g} times the mean squared residual "
               f"(rad/s)^2 it removes on the measured data"
               if ref is not None else "the reference data were not available")
    if verdict == "new":
        return (f"{effect}: {cand.describe(params)} removes {100 * meas.fraction:.0f} % of the model's "
                f"remaining residual on held-out time blocks of the measured data "
                f"({meas.blocks_improved} of {meas.blocks} blocks better, p = {meas.p_value:.2g}) "
                f"but only {ref_txt}")
    if verdict == "structural":
        return (f"{effect}: {cand.describe(params)} removes {100 * meas.fraction:.0f} % of the held-out "
                f"residual on the measured data and {ref_txt}: the model lacks it on its own "
                f"training data too (structural, not new in the measured data)")
    return (f"{effect}: {cand.describe(params)} removes {100 * meas.fraction:.0f} % of the held-out "
            f"residual (p = {meas.p_value:.2g}): not significant")


# --- step 4: add the effect ---------------------------------------------------------------------
def slice_signals(s: Signals, t0: float, t1: float, tag: str) -> Signals:
    """The part t0 <= t <= t1 of a recording (events kept up to t1, so filters keep their history)."""
    sel = (s.t >= t0) & (s.t <= t1)
    pt, pv = s.pwm_events
    vt, vv = s.voltage_events
    kp = pt <= t1
    kv = vt <= t1
    return dataclasses.replace(
        s, path=f"{s.path}#{tag}", sha256=f"{s.sha256}#{tag}", t=s.t[sel], pwm=s.pwm[sel],
        voltage=s.voltage[sel], speed=s.speed[sel],
        thrust=s.thrust[sel] if s.thrust is not None else None,
        current=s.current[sel] if s.current is not None else None,
        pwm_events=(pt[kp], pv[kp]), voltage_events=(vt[kv], vv[kv]),
    )


def retrain(model: Any, cand: fx.Candidate, params: dict[str, float], reference: Sequence[Signals],
            measured: Sequence[Signals], opts: Options, progress: Progress,
            reference_params: dict[str, float] | None = None) -> Any:
    """The network with the effect's input added, trained on reference + measured recordings.

    ``reference_params``: the effect's parameters identified on the reference itself; with a
    candidate that can (``on_reference``), the reference recordings get the added input at their
    own parameter, so the two sets do not pull the network towards a compromise."""
    inputs = list(model.input_names)
    feature_params = {k: dict(v) for k, v in (model.feature_params() or {}).items()}
    rename = {old: new for old, new in cand.replaces.items() if old in inputs}
    if rename:
        inputs = [rename.get(x, x) for x in inputs]
        for new in rename.values():
            p = {k: v for k, v in (params or {}).items() if k in ef.DEFAULT_PARAMS.get(new, {})}
            if "tau_s" in ef.DEFAULT_PARAMS.get(new, {}):
                p["tau_s"] = float(model.pwm_tau_s)  # the model's own low-pass, on the mapped command
            feature_params[new] = p
    if cand.input_name not in inputs:
        inputs.append(cand.input_name)
    if params:
        feature_params[cand.input_name] = cand.model_params(params)
    train, val = list(reference), []
    pwm_free = set(inputs) <= {c.INPUT_BATTERY_VOLTAGE, *rename.values(), cand.input_name}
    if cand.on_reference is not None and reference_params and params and pwm_free:
        # only when every command-derived input is the effect's own: the mapping would distort others
        train = [cand.on_reference(s, params, reference_params) for s in reference]
        progress(f"the reference recordings get {cand.input_name} at their own identified {reference_params}")
    for s in measured:
        cut = s.t[0] + (1.0 - VALIDATION_FRACTION) * (s.t[-1] - s.t[0])
        train.append(slice_signals(s, s.t[0], cut, "train"))
        val.append(slice_signals(s, cut, s.t[-1], "validation"))
    hidden = opts.hidden or int(np.asarray(model.W1).shape[0])
    base_hidden = int(np.asarray(model.W1).shape[0])
    warm = opts.warm_start and hidden == base_hidden
    progress(f"retraining {len(inputs)}-{hidden}-1 on {', '.join(inputs)} "
             f"({len(train)} training parts, {len(val)} validation parts"
             + (", starting from the model's own weights with the new input's weights at 0"
                + (", " + ", ".join(f"{k}'s carried over to {v}" for k, v in rename.items()) if rename else "")
                + ")" if warm else ")"))
    kw: dict[str, Any] = {
        "inputs": inputs, "hidden": hidden, "seed": opts.seed, "pwm_tau_s": float(model.pwm_tau_s),
        "feature_params": feature_params, "thrust_coefficient": float(model.thrust_coefficient),
        "max_epochs": opts.max_epochs, "patience": opts.patience,
    }
    if not warm:
        return train_model(train, val, **kw).model
    phi0 = warm_start_weights(model, inputs, train, {c.INPUT_PWM_FILTERED: {"tau_s": float(model.pwm_tau_s)},
                                                     **feature_params}, rename)
    return train_model(train, val, phi0=phi0, **kw).model


def warm_start_weights(model: Any, inputs: Sequence[str], train: Sequence[Signals],
                       params: dict[str, dict[str, float]], rename: dict[str, str] | None = None) -> np.ndarray:
    """The base network's weights re-expressed in the scaling train_model will use for ``train``,
    with zero weights for the added input(s): the retraining starts from the model as it was.
    ``rename`` maps a base input to the input that replaces it (its weights carry over).

    Starting there (not from random weights) keeps what the model knew where the new data say
    nothing: a network retrained from scratch on a discharge recorded at one command level
    extrapolates the voltage dependence to the other levels arbitrarily."""
    from ..training.network import minmax_fit, pack
    from ..training.train import stack

    X, y = stack(train, inputs, params)
    lo_new, hi_new = minmax_fit(X)
    span_new = hi_new - lo_new
    ymin, ymax = float(np.min(y)), float(np.max(y))
    W1o, b1o = np.asarray(model.W1, float), np.asarray(model.b1, float)
    lo_o, hi_o = np.asarray(model.input_min, float), np.asarray(model.input_max, float)
    span_o = hi_o - lo_o
    H = W1o.shape[0]
    W1 = np.zeros((H, len(inputs)))
    b1 = b1o.copy()
    rename = rename or {}
    for jo, name in enumerate(model.input_names):
        j = list(inputs).index(rename.get(name, name))
        a = span_new[j] / span_o[jo]
        cst = (2.0 * (lo_new[j] - lo_o[jo]) + span_new[j]) / span_o[jo] - 1.0
        W1[:, j] = W1o[:, jo] * a
        b1 += W1o[:, jo] * cst
    sy_o = float(model.output_max) - float(model.output_min)
    sy_n = ymax - ymin
    W2 = np.asarray(model.W2, float).reshape(-1) * sy_o / sy_n
    b2 = (float(model.b2) + 1.0) * sy_o / sy_n + 2.0 * (float(model.output_min) - ymin) / sy_n - 1.0
    return pack(W1, b1, W2, b2)


def check_holdout(holdout: Sequence[Signals], measured: Sequence[Signals], reference: Sequence[Signals]) -> None:
    """The holdout must be data nothing is fitted on: refused (one line) when it overlaps the
    measured or the reference recordings; BadInputError too when it is too short to block."""
    if holdout:
        acc.check_holdout_disjoint(holdout, measured=measured, reference=reference)
        sc.make_blocks([s.duration_s for s in holdout], "holdout")


def network_acceptance(effect: str, hold_cur: DataSet, hold_new: DataSet, have_holdout: bool, meas_cur: DataSet,
                       meas_new: DataSet, score: sc.Score, opts: Options) -> acc.Acceptance:
    """Does the retrained network beat the current one on data it was not trained on: the
    holdout; without one, the measured recordings' last VALIDATION_FRACTION (early stopping only),
    or, when that is too short to block, step 3's held-out blocks."""
    if have_holdout:
        return acc.judge(effect, hold_cur.signals, hold_cur.predictions, hold_new.predictions, "holdout", opts.alpha)
    tails, before, after = [], [], []
    for s, pb, pa in zip(meas_cur.signals, meas_cur.predictions, meas_new.predictions):
        cut = s.t[0] + (1.0 - VALIDATION_FRACTION) * (s.t[-1] - s.t[0])
        sel = s.t >= cut
        tails.append(slice_signals(s, cut, s.t[-1], "validation"))
        before.append(pb[sel])
        after.append(pa[sel])
    try:
        return acc.judge(effect, tails, before, after, f"the measured recordings' last "
                         f"{100 * VALIDATION_FRACTION:.0f} % (early stopping only, not trained on)", opts.alpha)
    except BadInputError:
        return acc.from_score(effect, score, "held-out blocks of the measured data (step 3)", opts.alpha)


# --- the loop ------------------------------------------------------------------------------------
@dataclass
class WorkflowResult:
    data: dict[str, Any]
    model: Any  # final model (the base model if nothing was added)
    lines: list[str]


def windows_of(ds: DataSet, threshold: float) -> tuple[list[rs.Window], list[np.ndarray]]:
    wins: list[rs.Window] = []
    masks = []
    for s, r in zip(ds.signals, ds.residuals):
        w, m = rs.find_windows(s.path, s.t, r, s.pwm, s.voltage, threshold)
        wins += w
        masks.append(m)
    return wins, masks


def check_effect_names(names: Sequence[str] | None) -> list[str]:
    """``names`` as a list; BadInputError naming the first one that is not an effect of the contract."""
    for name in names or []:
        if name not in c.EFFECTS:
            raise BadInputError(f"--effects {name}: unknown effect (known: {', '.join(c.EFFECTS)})")
    return list(names or [])


@dataclass
class Disagreement:
    """Step 2: where the model and the measured data disagree, and the residual tests."""

    threshold: float  #: rad/s: THRESHOLD_SIGMAS x the robust sigma of the reference residual
    windows: list[rs.Window]
    tests: Any  #: residuals.residual_tests on the measured data
    tests_ref: Any  #: the same on the reference data, or None
    conditions: Any  #: residuals.condition_bins on the measured data (the disagreement map)


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
             f"measured residual RMSE {_rmse(meas.residuals):.2f} rad/s"
             + (f", reference {_rmse(ref.residuals):.2f} rad/s" if ref else ""))
    return Disagreement(threshold, windows, tests(meas), tests(ref) if ref else None, conditions)


def run_workflow(model: Any, measured: Sequence[Signals], reference: Sequence[Signals],
                 holdout: Sequence[Signals], opts: Options, progress: Progress) -> WorkflowResult:
    restrict = check_effect_names(opts.restrict) or None
    check_inputs_computable(model, [*measured, *reference, *holdout])
    warnings: list[str] = []
    if not reference:
        warnings.append("no reference recordings (give --reference or keep the model's training "
                        "recordings where its metadata says): new and structural findings cannot be told apart")
    in_sample_holdout = not holdout
    if in_sample_holdout:
        warnings.append("no --holdout recordings: before/after RMSE is on the measured recordings, "
                        "which the new model was trained on (optimistic)")
    hold = list(holdout) if holdout else list(measured)
    check_holdout(holdout, measured, reference)

    # step 1
    progress(f"step 1: running the model over {len(measured)} measured recording(s)")
    meas = run_model(model, measured)
    ref = run_model(model, reference) if reference else None
    hold_base = run_model(model, hold)
    hold_cur = hold_base
    speed_scale = max(float(model.output_max), 1.0)

    # step 2
    found = find_disagreement(meas, ref, progress)

    named: list[str] = []
    structural: list[dict[str, Any]] = []
    evidence: dict[str, Any] = {}
    iterations: list[dict[str, Any]] = []
    current = model
    cur_meas, cur_ref = meas, ref
    added_inputs: list[str] = []
    dyn: tuple[fx.Dynamics, fx.Dynamics] | None = None
    while True:
        cands = [cd for cd in fx.candidates_for(current.input_names, restrict) if cd.effect not in named]
        if not cands:
            break
        progress(f"step 3: scoring {len(cands)} candidate effect(s) on held-out time blocks")
        # measured: corrections fitted on measured + reference pooled (a re-weighting of the model
        # cannot then absorb what differs between them); reference: fitted on the reference
        # alone (what the effect would do for the model on its own training data)
        s_meas, _ = score_pooled(cur_meas, cur_ref, cands, speed_scale)
        s_ref = score_dataset(cur_ref, cands, speed_scale, "reference") if cur_ref else {}
        # and the measured data alone: a new effect must also explain structure WITHIN the
        # measured data (the reference residual is in-sample for the network, so the pooled
        # score alone would take any out-of-sample error for a difference)
        s_own = score_dataset(cur_meas, cands, speed_scale, "measured") if cur_ref else s_meas
        round_ev: dict[str, Any] = {}
        best: tuple[float, fx.Candidate] | None = None
        for cand in cands:
            m, r = s_meas[cand.effect], s_ref.get(cand.effect)
            verdict = classify(m, r, opts.alpha, opts.min_effect)
            own = s_own[cand.effect]
            if verdict == "new" and not (own.p_value < opts.alpha and own.fraction >= opts.min_effect):
                verdict = "not significant"
            params = m.params
            text = sentence(cand.effect, cand, params, m, r, verdict)
            round_ev[cand.effect] = {
                "verdict": verdict,
                "measured": m.as_dict(),
                "measured_alone": own.as_dict(),
                "reference": r.as_dict() if r is not None else None,
                "p_value": m.p_value,
                "feature": cand.describe(params),
                "sentence": text,
            }
            progress(f"  {cand.effect:20s} measured {100 * m.fraction:6.1f} % (p {m.p_value:.2g})"
                     + (f" alone {100 * own.fraction:6.1f} % (p {own.p_value:.2g})" if cur_ref else "")
                     + (f"  reference {100 * r.fraction:6.1f} % (p {r.p_value:.2g})" if r else "")
                     + f"  -> {verdict}")
            if verdict == "new" and (best is None or m.fraction > best[0]):
                best = (m.fraction, cand)
            if verdict == "structural" and cand.effect not in [x["effect"] for x in structural]:
                structural.append({"effect": cand.effect, "sentence": text,
                                   "measured_mse_reduction": m.fraction,
                                   "reference_mse_reduction": r.fraction if r else None})
        for k, v in round_ev.items():
            if k not in evidence or k not in named:
                evidence[k] = v
        iterations.append({"evidence": round_ev})
        dyn_params: dict[str, float] | None = None
        ref_params: dict[str, float] | None = None  # the effect's parameters identified on the reference
        heat_cand = next((cd for cd in cands if cd.effect == "motor_heating"), None)
        if heat_cand is not None and cur_ref is not None and best is None:
            # a changed response to the same thermal state: the feature (driven by the command) is
            # the same on both sets, so the pooled residual score cannot see it; identified on the
            # speed directly, the measured and the reference sets fitted together
            heat = fx.identify_heating(measured, reference)
            round_ev["motor_heating"]["heating"] = heat.as_dict()
            progress(f"  identified heating: {heat.describe()}")
            if heat.changed:
                ev = round_ev["motor_heating"]
                ev["verdict_residual"] = ev["verdict"]
                ev["verdict"] = "new"
                ev["sentence"] = f"motor_heating: {heat.describe()}"
                best = (s_own["motor_heating"].fraction, heat_cand)
                dyn_params = {"tau_s": fx.HEATING_TAU_S}
        if best is not None and best[1].effect not in fx.DYNAMIC_EFFECTS and cur_ref is not None:
            pass
        elif cur_ref is not None and (
                any(s_own[k].p_value < opts.alpha and s_own[k].fraction >= opts.min_effect
                    for k in round_ev if k in fx.DYNAMIC_EFFECTS)
                or (best is None and _rmse(cur_meas.residuals) >= GAP_RATIO * _rmse(cur_ref.residuals))):
            # (judged on the measured data alone: which dynamic effect changed is decided by
            # identifying the response directly, not by the pooled residual correction)
            # the measured residual has significant dynamic structure, or is far larger than the
            # reference's with no residual feature to explain it (a changed static map, as a start
            # level, re-weights into the null columns); whether anything is NEW is decided below
            # by comparing the identified response with the reference's
            if best is None or best[1].effect not in fx.DYNAMIC_EFFECTS:
                best = max(((s_own[k].fraction, cd) for cd in cands for k in [cd.effect]
                            if k in fx.DYNAMIC_EFFECTS and s_own[k].p_value < opts.alpha),
                           key=lambda x: x[0], default=None)
            gap_txt = (f"({best[1].effect}'s feature removes {100 * best[0]:.0f} % of it, "
                       f"p = {s_own[best[1].effect].p_value:.2g})" if best is not None else
                       f"(its RMSE is {_rmse(cur_meas.residuals):.1f} rad/s vs {_rmse(cur_ref.residuals):.1f} "
                       f"rad/s on the reference)")
            # lag, dead time and spin-down all change the response to a command change, and a
            # residual explained by one is partly explained by the others: which one CHANGED is
            # decided by identifying the response itself on the measured and the reference data
            if dyn is None:
                progress("  a dynamic effect is new: identifying dead time and spin-up/spin-down "
                         "time constants on the measured and the reference recordings")
                dyn = (fx.identify_dynamics(measured), fx.identify_dynamics(reference))
                if any(cd.effect == "esc_deadband" for cd in cands):
                    for dy, sigs in zip(dyn, (measured, reference)):
                        dy.start_level = fx.identify_start_level(sigs, dy)
            offered = {cd.effect for cd in cands}
            choice, why = fx.which_dynamic(dyn[0], dyn[1], exclude=[*named, *(set(c.EFFECTS) - offered)])
            dynamics_info = {"measured": dyn[0].as_dict(), "reference": dyn[1].as_dict(),
                             "changed": choice, "because": why}
            progress(f"  identified dynamics: {why}")
            if choice is None:
                # the response to the command did not change: the residual's dynamic structure
                # is the model's own (it is there on the reference too), not a new effect
                for k in fx.DYNAMIC_EFFECTS:
                    if k in round_ev and round_ev[k]["verdict"] in ("new", "structural"):
                        round_ev[k]["verdict"] = "not new (identified dynamics unchanged)"
                        round_ev[k]["dynamics"] = dynamics_info
                others = [(s_meas[cd.effect].fraction, cd) for cd in cands
                          if cd.effect not in fx.DYNAMIC_EFFECTS and round_ev[cd.effect]["verdict"] == "new"]
                best = max(others, key=lambda x: x[0]) if others else None
            elif choice not in named:
                cand_c = next((cd for cd in cands if cd.effect == choice), None)
                if cand_c is not None:
                    ev = round_ev[choice]
                    ev["verdict_residual"] = ev["verdict"]
                    ev["verdict"] = "new"
                    ev["sentence"] = (f"{choice}: {why}; the model's residual on the measured data "
                                      f"follows the command {gap_txt}")
                    best = (s_own[choice].fraction, cand_c)
            if best is not None and choice == best[1].effect:
                m = dyn[0]
                dyn_params = {"rotor_lag": {"tau_s": max(m.tau_up_s, 0.02)},
                              "spin_down_asymmetry": {"tau_up_s": max(m.tau_up_s, 0.02),
                                                      "tau_down_s": max(m.tau_down_s, 0.04)},
                              "esc_deadband": {"threshold": m.start_level},
                              # the model already has the reference's own dead time: add the change
                              "input_delay": {"delay_s": max(m.delay_s - dyn[1].delay_s, 0.01)},
                              }.get(choice)
                if choice == "esc_deadband":
                    ref_params = {"threshold": dyn[1].start_level}
            if best is not None:
                round_ev[best[1].effect]["dynamics"] = dynamics_info
        if best is None or len(named) >= opts.max_effects:
            if best is None:
                progress("  no new effect is significant")
            break
        cand = best[1]
        if dyn_params is not None:
            params = dyn_params
        else:
            params = fitted_params(cur_meas, cand, speed_scale) if len(cand.grid) > 1 else {}
        evidence[cand.effect]["fitted_parameters"] = params
        progress(f"  proposed: {round_ev[cand.effect]['sentence']}")
        progress(f"step 4: adding {cand.effect} as input '{cand.input_name}' {params or ''}")
        new_model = retrain(current, cand, params, reference, measured, opts, progress, ref_params)
        hold_new = run_model(new_model, hold)
        meas_new = run_model(new_model, measured)
        judged = network_acceptance(cand.effect, hold_cur, hold_new, bool(holdout), cur_meas, meas_new,
                                     s_own[cand.effect], opts)
        evidence[cand.effect]["acceptance"] = judged.as_json()
        iterations[-1].update({
            "proposed": cand.effect, "input": cand.input_name, "parameters": params,
            "holdout_rmse_rad_s": _rmse(hold_new.residuals), "acceptance": judged.as_json(),
        })
        progress(f"step 5: {judged.describe()}")
        if not judged.accepted:
            # the best candidate does not help data it was not fitted on: weaker ones will not either
            break
        named.append(cand.effect)
        evidence[cand.effect]["named"] = True
        iterations[-1]["named"] = cand.effect
        added_inputs.append(cand.input_name)
        current, hold_cur = new_model, hold_new
        if len(named) >= opts.max_effects:
            break
        cur_meas = meas_new
        cur_ref = run_model(current, reference) if reference else None

    # step 5: the gap
    hold_final = hold_cur
    hold_windows, hold_masks = windows_of(hold_base, found.threshold)
    structural = [x for x in structural if x["effect"] not in named]
    data: dict[str, Any] = {
        "named": named,
        "structural": structural,
        "considered_not_added": acc.considered(evidence, named),
        **gap_fields(hold_base, hold_final, hold_masks),
        **shared_fields(hold, found, hold_windows, reference, measured, opts, in_sample_holdout),
        "evidence": evidence,
        "iterations": iterations,
        "added_inputs": added_inputs,
        "warnings": warnings,
        "model": None,
    }
    if opts.report_dir:
        data["report"] = write_report(Path(opts.report_dir), meas, hold_base, hold_final, found.windows,
                                      hold_windows, data, force=opts.report_force)
    lines = summary_lines(data)
    return WorkflowResult(data, current, lines)


def gap_fields(hold_base: DataSet, hold_final: DataSet, hold_masks: Sequence[np.ndarray]) -> dict[str, Any]:
    """Step 5's figures: holdout RMSE before and after, overall and inside the holdout's windows."""
    any_win = any(m.any() for m in hold_masks)
    return {
        "holdout_rmse_before": _rmse(hold_base.residuals),
        "holdout_rmse_after": _rmse(hold_final.residuals),
        "holdout_rmse_in_windows_before": _rmse(hold_base.residuals, hold_masks) if any_win else None,
        "holdout_rmse_in_windows_after": _rmse(hold_final.residuals, hold_masks) if any_win else None,
    }


def shared_fields(hold: Sequence[Signals], found: Disagreement, hold_windows: Sequence[rs.Window],
                  reference: Sequence[Signals], measured: Sequence[Signals], opts: Options,
                  in_sample: bool) -> dict[str, Any]:
    """The --json fields both model kinds (network, physics) report the same way."""
    return {
        "holdout_in_sample": in_sample,
        "holdout_recordings": [s.path for s in hold],
        "windows": [w.as_dict() for w in found.windows],
        "holdout_windows": [w.as_dict() for w in hold_windows],
        "window_threshold_rad_s": found.threshold,
        "residual_tests": {"measured": found.tests.as_dict(),
                           "reference": found.tests_ref.as_dict() if found.tests_ref else None},
        "conditions": found.conditions,
        "reference_recordings": [s.path for s in reference],
        "measured_recordings": [s.path for s in measured],
        "decision": {"alpha": opts.alpha, "min_mse_reduction": opts.min_effect,
                     "structural_ratio": STRUCTURAL_RATIO,
                     "test": "one-sided paired sign-flip randomisation test over held-out time blocks"},
    }


def summary_lines(data: dict[str, Any]) -> list[str]:
    lines = []
    if data["named"]:
        lines.append("new effect(s) found in the measured data: " + ", ".join(data["named"]))
        for name in data["named"]:
            lines.append("  " + data["evidence"][name]["sentence"])
            kept = data["evidence"][name].get("acceptance")
            if kept:
                lines.append(f"    added because on {kept['source']}: RMSE {kept['rmse_before_rad_s']:.2f} -> "
                             f"{kept['rmse_after_rad_s']:.2f} rad/s, {100 * kept['mse_reduction']:.1f} % of the mean "
                             f"squared error ({kept['blocks_improved']} of {kept['blocks']} blocks better, "
                             f"p = {kept['p_value']:.2g})")
    else:
        lines.append("no effect improves data it was not fitted on: nothing named")
    for s in data["structural"]:
        lines.append("structural (also on the reference data): " + s["sentence"])
    lines += acc.considered_lines([x for x in data.get("considered_not_added", []) if x["verdict"] != "structural"])
    lines.append(f"{len(data['windows'])} disagreement window(s) in the measured data "
                 f"(smoothed |residual| > {data['window_threshold_rad_s']:.1f} rad/s)")
    for w in data["windows"][:5]:
        cnd = w["conditions"]
        lines.append(f"  {Path(w['path']).name} {w['t_start_s']:.1f}-{w['t_end_s']:.1f} s: "
                     f"RMS {w['rms_residual_rad_s']:.1f} rad/s at PWM {cnd['pwm']:.3f} ({cnd['pwm_direction']}), "
                     f"{cnd['battery_voltage_v']:.2f} V, {cnd['time_under_load_s']:.0f} s under load")
    wt = data["residual_tests"]["measured"]
    if wt.get("whiteness"):
        lines.append(f"residual whiteness: Ljung-Box p = {wt['whiteness']['ljung_box_p']:.2g} "
                     f"({wt['whiteness']['lags_outside_bounds']}/{wt['whiteness']['lags_tested']} lags outside "
                     f"+/-{wt['bound_95']:.3f})")
    hold = "holdout" if not data["holdout_in_sample"] else "measured (in-sample)"
    lines.append(f"{hold} RMSE {data['holdout_rmse_before']:.2f} -> {data['holdout_rmse_after']:.2f} rad/s"
                 + (f"; inside its disagreement windows {data['holdout_rmse_in_windows_before']:.2f} -> "
                    f"{data['holdout_rmse_in_windows_after']:.2f} rad/s"
                    if data["holdout_rmse_in_windows_before"] is not None else ""))
    return lines


def write_report(final: Path, meas: DataSet, hold_base: DataSet, hold_final: DataSet,
                 windows: Sequence[rs.Window], hold_windows: Sequence[rs.Window], data: dict[str, Any],
                 force: bool = False) -> str:
    """Disagreement map and before/after figures (training/report.py) and an index.html,
    written whole to ``final`` (atomic.report_output)."""
    with report_output(final, force=force) as d:
        _write_report(d, meas, hold_base, hold_final, hold_windows, data)
    return str(final)


def _write_report(d: Path, meas: DataSet, hold_base: DataSet, hold_final: DataSet,
                  hold_windows: Sequence[rs.Window], data: dict[str, Any]) -> None:
    from ..training import report as rp

    figs = []
    pwm = np.concatenate([s.pwm for s in meas.signals])
    rate = np.concatenate([rs.pwm_rate(s.t, s.pwm) for s in meas.signals])
    volt = np.concatenate([s.voltage for s in meas.signals])
    res = np.concatenate(meas.residuals)
    rp.fig_disagreement_map(pwm, rate, res, d / "disagreement_map.png", voltage=volt)
    figs.append(("disagreement_map.png", "mean residual (measured - model) per PWM level and rate, "
                 "and vs battery voltage, on the measured recordings"))
    for k, (s, pb, pa) in enumerate(zip(hold_base.signals, hold_base.predictions, hold_final.predictions)):
        name = f"before_after_{k}.png"
        spans = [(w.t_start_s, w.t_end_s) for w in hold_windows if w.path == s.path]
        rp.fig_before_after(s.t, s.speed, pb, pa, d / name, windows=spans, recording=s.path)
        figs.append((name, f"{s.path}: model before and after adding {', '.join(data['named']) or 'nothing'}"))
    rows = [{"effect": k, "verdict": v["verdict"],
             "measured reduction": v["measured"]["mse_reduction"], "measured p": v["measured"]["p_value"],
             "reference reduction": (v["reference"] or {}).get("mse_reduction"),
             "reference p": (v["reference"] or {}).get("p_value"), "feature": v["feature"]}
            for k, v in data["evidence"].items()]
    gap = [{"holdout RMSE before": data["holdout_rmse_before"], "after": data["holdout_rmse_after"],
            "in windows before": data["holdout_rmse_in_windows_before"],
            "in windows after": data["holdout_rmse_in_windows_after"]}]
    added = [{"effect": k, **{f"held-out {x}": v for x, v in data["evidence"][k]["acceptance"].items()}}
             for k in data["named"] if data["evidence"][k].get("acceptance")]
    skipped = [{"effect": x["effect"], "why": x["why"], "held-out MSE reduction": x["measured_mse_reduction"],
                "p": x["p_value"], "reference MSE reduction": x["reference_mse_reduction"],
                "tried on held-out data": (x["acceptance"] or {}).get("mse_reduction")}
               for x in data.get("considered_not_added", [])]
    rp.write_index(d, "discrepancy: " + (", ".join(data["named"]) or "nothing new named"), figs,
                   [("candidate effects (held-out scores)", rows), ("added: the held-out figure that kept each", added),
                    ("considered, not added", skipped), ("the gap", gap)])
