"""The trained network as the model of the discrepancy workflow (``discrepancy --model``).

Its specifics, behind the ``base.ModelKind`` protocol the loop (``workflow.py``) talks to:

- step 1: the network run over the recordings (inputs checked computable);
- step 3: every candidate effect's feature (``effects.py``) scored as a residual correction on
  held-out time blocks (``scoring.py``) three ways: on the measured blocks with the corrections
  fitted on measured + reference pooled (what differs between them: a residual offset that only
  the battery voltage lines up with), on the measured data alone (structure within them), and on
  the reference alone; a residual correction cannot see a changed response (dead time, lag, start
  level, heating), so the kind's ``identify`` applies the identification rules (``identify/``) to
  each round's proposal;
- step 4: the network retrained with the effect's input (fitted parameters) on reference +
  measured recordings, early-stopped on the measured recordings' last part, starting from the
  base model's own weights (the new input's at 0). An effect that maps the command before the
  ESC (the start level, the dead time) replaces the model's command inputs by the mapped ones,
  weights carried over in the new input's units, and the reference recordings are mapped at their
  own identified value;
- step 5 without --holdout: judged on the measured recordings' early-stopping tail (never
  trained on), else on step 3's held-out blocks.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from .. import contract as c
from ..core import effect_features as ef
from ..errors import BadInputError
from ..recordings import Signals
from ..training.evaluate import predict_speed
from ..training.train import features_of, train_model
from . import acceptance as acc
from . import effects as fx
from . import identify as idf
from . import scoring as sc
from .base import Options, Progress, Proposal, Refined, Scores, Trial
from .dataset import DataSet, rmse
from .results import KindFields

if TYPE_CHECKING:
    from ..model import NetworkModel

#: The measured recordings' share kept out of the retraining (early stopping, and the held-out
#: evidence without a --holdout): every VALIDATION_EVERY-th of VALIDATION_CHUNKS equal chunks of
#: each recording, so the early stopping sees the recording's whole range of commands (a last
#: 20 % in one piece can miss what differs: a tail the base model already fits stops every
#: retraining at its first epoch, and the base model comes back unchanged whatever the effect).
VALIDATION_CHUNKS = 10
VALIDATION_EVERY = 5
VALIDATION_FRACTION = 1.0 / VALIDATION_EVERY


def check_inputs_computable(model: NetworkModel, signals: Sequence[Signals]) -> None:
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


def run_model(model: NetworkModel, signals: Sequence[Signals]) -> DataSet:
    ds = DataSet(list(signals))
    for s in signals:
        ds.predictions.append(predict_speed(model, s))
        X = features_of(s, model.input_names, model.feature_params())
        lo, hi = np.asarray(model.input_min), np.asarray(model.input_max)
        span = np.where(hi > lo, hi - lo, 1.0)
        ds.inputs.append(np.clip(2.0 * (X - lo) / span - 1.0, -1.5, 1.5))
    return ds


# --- step 3: scores -------------------------------------------------------------------------------
def score_dataset(ds: DataSet, cands: Sequence[fx.Candidate], speed_scale: float, what: str) -> dict[str, sc.Score]:
    blocks = sc.make_blocks([s.duration_s for s in ds.signals], what)
    labels = sc.block_labels([len(s.t) for s in ds.signals], blocks)
    ctxs = [fx.Context(s, p, speed_scale) for s, p in zip(ds.signals, ds.predictions, strict=True)]
    r = np.concatenate(ds.residuals)
    null_X = np.vstack([fx.null_columns(cx, z) for cx, z in zip(ctxs, ds.inputs, strict=True)])
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
    for ds, what in zip(sets, ("measured", "reference"), strict=True):
        blocks = sc.make_blocks([s.duration_s for s in ds.signals], what)
        lab = sc.block_labels([len(s.t) for s in ds.signals], blocks)
        labels.append(np.where(lab >= 0, lab + first, -1))
        groups.append(np.arange(first, first + int(sum(blocks))))
        first += int(sum(blocks))
    lab = np.concatenate(labels)
    ctxs = [fx.Context(s, p, speed_scale) for ds in sets for s, p in zip(ds.signals, ds.predictions, strict=True)]
    r = np.concatenate([np.concatenate(ds.residuals) for ds in sets])
    inputs = [z for ds in sets for z in ds.inputs]
    null_X = np.vstack([fx.null_columns(cx, z) for cx, z in zip(ctxs, inputs, strict=True)])
    out_m: dict[str, sc.Score] = {}
    out_r: dict[str, sc.Score] = {}
    for cand in cands:
        extras = [np.vstack([cand.columns(cx, prm) for cx in ctxs]) for prm in cand.grid]
        out_m[cand.effect], out_r[cand.effect] = sc.score_candidate_groups(r, lab, null_X, extras, cand.grid, groups)
    return out_m, out_r


def fitted_params(ds: DataSet, cand: fx.Candidate, speed_scale: float) -> dict[str, float]:
    ctxs = [fx.Context(s, p, speed_scale) for s, p in zip(ds.signals, ds.predictions, strict=True)]
    r = np.concatenate(ds.residuals)
    null_X = np.vstack([fx.null_columns(cx, z) for cx, z in zip(ctxs, ds.inputs, strict=True)])
    extras = [np.vstack([cand.columns(cx, prm) for cx in ctxs]) for prm in cand.grid]
    return sc.fit_params(r, null_X, extras, cand.grid)


# --- step 4: add the effect ---------------------------------------------------------------------
def slice_signals(s: Signals, t0: float, t1: float, tag: str) -> Signals:
    """The part t0 <= t <= t1 of a recording (events kept up to t1, so filters keep their history)."""
    sel = (s.t >= t0) & (s.t <= t1)
    pt, pv = s.pwm_events
    vt, vv = s.voltage_events
    st, sv = s.speed_events
    kp = pt <= t1
    kv = vt <= t1
    ks = (st >= t0) & (st <= t1)
    return dataclasses.replace(
        s, path=f"{s.path}#{tag}", sha256=f"{s.sha256}#{tag}", t=s.t[sel], pwm=s.pwm[sel],
        voltage=s.voltage[sel], speed=s.speed[sel],
        thrust=s.thrust[sel] if s.thrust is not None else None,
        current=s.current[sel] if s.current is not None else None,
        pwm_events=(pt[kp], pv[kp]), voltage_events=(vt[kv], vv[kv]), speed_events=(st[ks], sv[ks]),
    )


def split_measured(s: Signals) -> tuple[list[Signals], list[Signals]]:
    """A measured recording's training parts and validation chunks (VALIDATION_CHUNKS)."""
    edges = np.linspace(s.t[0], s.t[-1], VALIDATION_CHUNKS + 1)
    train, val = [], []
    start = edges[0]
    for k in range(VALIDATION_CHUNKS):
        if (k + 1) % VALIDATION_EVERY == 0:
            if edges[k] > start:
                train.append(slice_signals(s, start, edges[k], f"train{k}"))
            val.append(slice_signals(s, edges[k], edges[k + 1], f"validation{k}"))
            start = edges[k + 1]
    if edges[-1] > start:
        train.append(slice_signals(s, start, edges[-1], "train_end"))
    return train, val


def retrain(model: NetworkModel, cand: fx.Candidate, params: dict[str, float], reference: Sequence[Signals],
            measured: Sequence[Signals], opts: Options, progress: Progress,
            reference_params: dict[str, float] | None = None) -> NetworkModel:
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
            own = (*ef.DEFAULT_PARAMS.get(new, {}), *ef.OPTIONAL_PARAMS.get(new, ()))
            p = {k: v for k, v in (params or {}).items() if k in own}
            if "tau_s" in ef.DEFAULT_PARAMS.get(new, {}):
                p["tau_s"] = float(model.pwm_tau_s)  # the model's own low-pass, on the mapped command
            feature_params[new] = p
    if cand.input_name not in inputs:
        inputs.append(cand.input_name)
    if params:
        feature_params[cand.input_name] = cand.model_params(params)
    lag_delayed = _lag_on_the_delayed_command(inputs, feature_params)
    train, val = list(reference), []
    pwm_free = set(inputs) <= {c.INPUT_BATTERY_VOLTAGE, *rename.values(), cand.input_name, *lag_delayed}
    if cand.on_reference is not None and reference_params and params and pwm_free:
        # only when every command-derived input is the effect's own: the mapping would distort others
        train = [cand.on_reference(s, params, reference_params) for s in reference]
        progress(f"the reference recordings get {cand.input_name} at their own identified {reference_params}")
    for s in measured:
        parts, held = split_measured(s)
        train += parts
        val += held
    hidden = opts.hidden or int(np.asarray(model.W1).shape[0])
    base_hidden = int(np.asarray(model.W1).shape[0])
    warm = opts.warm_start and hidden == base_hidden
    progress(f"retraining {len(inputs)}-{hidden}-1 on {', '.join(inputs)} "
             + f"({len(train)} training parts, {len(val)} validation parts"
             + (", starting from the model's own weights with the new input's weights at 0"
                + (", " + ", ".join(f"{k}'s carried over to {v}" for k, v in rename.items()) if rename else "")
                + ")" if warm else ")"))
    # (train_model's keyword arguments by name, each of its own type)
    kw: dict[str, Any] = {
        "inputs": inputs, "hidden": hidden, "seed": opts.seed, "pwm_tau_s": float(model.pwm_tau_s),
        "feature_params": feature_params, "thrust_coefficient": model.thrust_coefficient,
        "max_epochs": opts.max_epochs, "patience": opts.patience,
    }
    # (train_model makes a network: a hybrid comes from fit_physics.train_hybrid)
    if not warm:
        return cast("NetworkModel", train_model(train, val, **kw).model)
    units = {old: cand.carried_as(params or {}) for old in rename} if cand.carried_as else None
    phi0 = warm_start_weights(model, inputs, train, {c.INPUT_PWM_FILTERED: {"tau_s": float(model.pwm_tau_s)},
                                                     **feature_params}, rename, units)
    return cast("NetworkModel", train_model(train, val, phi0=phi0, **kw).model)


def _lag_on_the_delayed_command(inputs: Sequence[str], feature_params: dict[str, dict[str, float]]) -> list[str]:
    """Where the model has a dead time and a lag (``ef.DELAYABLE_LAGS``: the rotor's, or the
    spin-down's), the lag acts on the command as the ESC gets it (its ``delay_s``, set in place):
    a lag on the undelayed command would carry the timing the dead time removes, and a dead time
    added after a lag could not show. The lags it set."""
    if ef.PWM_DELAYED not in inputs:
        return []
    delay = dict(ef.DEFAULT_PARAMS[ef.PWM_DELAYED], **feature_params.get(ef.PWM_DELAYED, {}))["delay_s"]
    lags = [name for name in ef.DELAYABLE_LAGS if name in inputs]
    for name in lags:
        feature_params[name] = {**feature_params.get(name, {}), "delay_s": float(delay)}
    return lags


def warm_start_weights(model: NetworkModel, inputs: Sequence[str], train: Sequence[Signals],
                       params: dict[str, dict[str, float]], rename: dict[str, str] | None = None,
                       units: dict[str, tuple[float, float]] | None = None) -> np.ndarray:
    """The base network's weights re-expressed in the scaling train_model will use for ``train``,
    with zero weights for the added input(s): the retraining starts from the model as it was.
    ``rename`` maps a base input to the input that replaces it (its weights carry over);
    ``units[base] = (a, b)`` when the base input is ``a * replacement + b`` (other units), so
    the network starts as the same function of the same physical command (without it, a
    dead time's PWM levels fed to weights made for the scaled command started the retraining
    from a network hundreds of rad/s off, which it did not always recover from).

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
    rename, units = rename or {}, units or {}
    for jo, name in enumerate(model.input_names):
        j = list(inputs).index(rename.get(name, name))
        # base raw = ua * new raw + ub, new raw = lo_new + (x_new + 1) span_new / 2, and the base
        # network sees 2 (base raw - lo_o) / span_o - 1 = a * x_new + cst
        ua, ub = units.get(name, (1.0, 0.0))
        a = ua * span_new[j] / span_o[jo]
        cst = (2.0 * (ua * lo_new[j] + ub - lo_o[jo]) + ua * span_new[j]) / span_o[jo] - 1.0
        W1[:, j] = W1o[:, jo] * a
        b1 += W1o[:, jo] * cst
    sy_o = float(model.output_max) - float(model.output_min)
    sy_n = ymax - ymin
    W2 = np.asarray(model.W2, float).reshape(-1) * sy_o / sy_n
    b2 = (float(model.b2) + 1.0) * sy_o / sy_n + 2.0 * (float(model.output_min) - ymin) / sy_n - 1.0
    return pack(W1, b1, W2, b2)


class NetworkKind:
    """``base.ModelKind`` for a trained network (``model.NetworkModel``)."""

    noun = "the model"
    fitted_on = "which the new model was trained on"
    no_reference = ("no reference recordings (give --reference or keep the model's training recordings where "
                    "its metadata says): new and structural findings cannot be told apart")

    def __init__(self, model: NetworkModel, opts: Options) -> None:
        self._model = model
        self.opts = opts
        self.speed_scale = max(float(model.output_max), 1.0)
        self.added_inputs: list[str] = []
        self._pending: dict[str, DataSet] = {}

    @property
    def model(self) -> NetworkModel:
        return self._model

    def start(self, measured: Sequence[Signals], reference: Sequence[Signals], hold: Sequence[Signals],
              progress: Progress) -> tuple[DataSet, DataSet | None, DataSet]:
        check_inputs_computable(self._model, [*measured, *reference, *hold])
        self.measured, self.reference = list(measured), list(reference)
        progress(f"step 1: running the model over {len(measured)} measured recording(s)")
        self.cur_meas = run_model(self._model, measured)
        self.cur_ref = run_model(self._model, reference) if reference else None
        self.identification = idf.Identification(measured, reference, self.opts.alpha, self.opts.min_effect)
        return self.cur_meas, self.cur_ref, run_model(self._model, hold)

    def no_verdict(self) -> str | None:
        return None

    def warnings(self) -> list[str]:
        return []

    def candidates(self, restrict: Sequence[str], named: Sequence[str]) -> list[str]:
        return [cd.effect for cd in fx.candidates_for(self._model.input_names, restrict) if cd.effect not in named]

    def identify(self, proposal: Proposal, progress: Progress) -> Refined:
        """The identification rules (``identify.refine``) on the current model's residual: its
        scores are residual corrections, which cannot see a changed response (dead time, lag,
        start level, heating)."""
        rmse_ref = rmse(self.cur_ref.residuals) if self.cur_ref else float("nan")
        return idf.refine(proposal, self.identification, (rmse(self.cur_meas.residuals), rmse_ref), progress)

    def score(self, names: Sequence[str], progress: Progress) -> dict[str, Scores]:
        cands = [fx.CANDIDATES[n] for n in names]
        # measured: corrections fitted on measured + reference pooled (a re-weighting of the model
        # cannot then absorb what differs between them); reference: fitted on the reference
        # alone (what the effect would do for the model on its own training data)
        s_meas, _ = score_pooled(self.cur_meas, self.cur_ref, cands, self.speed_scale)
        s_ref = score_dataset(self.cur_ref, cands, self.speed_scale, "reference") if self.cur_ref else {}
        # and the measured data alone: a new effect must also explain structure WITHIN the
        # measured data (the reference residual is in-sample for the network, so the pooled
        # score alone would take any out-of-sample error for a difference)
        s_own = score_dataset(self.cur_meas, cands, self.speed_scale, "measured") if self.cur_ref else s_meas
        return {cd.effect: Scores(s_meas[cd.effect], s_own[cd.effect], s_ref.get(cd.effect),
                                  cd.describe(s_meas[cd.effect].params)) for cd in cands}

    def add(self, name: str, params: dict[str, float] | None, reference_params: dict[str, float] | None,
            scores: Scores, hold: Sequence[Signals], progress: Progress) -> Trial[NetworkModel]:
        cand = fx.CANDIDATES[name]
        if params is None:
            params = fitted_params(self.cur_meas, cand, self.speed_scale) if len(cand.grid) > 1 else {}
        progress(f"step 4: adding {name} as input '{cand.input_name}' {params or ''}")
        new = retrain(self._model, cand, params, self.reference, self.measured, self.opts, progress,
                      reference_params)
        self._pending = {"meas": run_model(new, self.measured)}
        return Trial(new, run_model(new, hold), params, cand.describe(params) if params else scores.feature,
                     extra={"input": cand.input_name})

    def heldout(self, name: str, trial: Trial[NetworkModel], scores: Scores, alpha: float) -> acc.Acceptance:
        """The measured recordings' validation chunks (early stopping only, ``split_measured``),
        or, when they are too short to block, step 3's held-out blocks."""
        chunks, before, after = [], [], []
        new = self._pending["meas"]
        for s, pb, pa in zip(self.cur_meas.signals, self.cur_meas.predictions, new.predictions, strict=True):
            for v in split_measured(s)[1]:
                sel = (s.t >= v.t[0]) & (s.t <= v.t[-1])
                chunks.append(v)
                before.append(pb[sel])
                after.append(pa[sel])
        try:
            return acc.judge(name, chunks, before, after, f"the measured recordings' validation chunks "
                             f"({100 * VALIDATION_FRACTION:.0f} %, early stopping only, not trained on)", alpha)
        except BadInputError:
            return acc.from_score(name, scores.measured, "held-out blocks of the measured data (step 3)", alpha)

    def contradicted(self, name: str) -> str | None:
        return None  # the identification already decided what was proposed (identify.refine)

    def keep(self, trial: Trial[NetworkModel]) -> None:
        self._model = trial.model
        self.added_inputs.append(trial.extra["input"])
        self.cur_meas = self._pending["meas"]
        self.cur_ref = run_model(self._model, self.reference) if self.reference else None

    def fitted(self, name: str) -> None:
        return None  # an added input's parameters are not refitted later

    def finish(self, named: Sequence[str]) -> tuple[KindFields, list[str], list[str]]:
        return {"added_inputs": list(self.added_inputs)}, [], []
