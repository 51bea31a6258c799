"""`bldc-propulsion train`: the speed network from recordings (training/train.py), its
summary and its report (the paper's Figs. 1, 5-6, 12, 13)."""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .. import contract as c
from ..atomic import REPORT, check_outputs, report_output
from ..errors import BadInputError
from ..priors import MotorPriors, add_prior_arguments, priors_from_args
from .common import EPOCHS, HIDDEN, SEED, CommandResult, add_namespace_argument, number, progress, with_warnings

if TYPE_CHECKING:  # imported where used, so that `--help` does not load numpy, scipy and rosbags
    import numpy as np

    from ..recordings import Signals
    from ..training.fit_physics import PhysicsOutcome
    from ..training.train import ThrustFit, TrainOutcome

NAME = "train"
HELP = "train the speed model (n-H-1 network, Levenberg-Marquardt; or the bench physics) from recordings"
DESCRIPTION = (
    "Train the paper's network (default 3-25-1: filtered battery voltage, PWM, PWM "
    "through a 0.25 s lag) with Levenberg-Marquardt on the training recordings, stop "
    "early on separate validation recordings, and save weights, scaling and "
    "provenance to an .npz model file. With --kind physics, fit the bench's physics "
    "(Kv, CP, effect strengths) instead, judged on the validation recordings. "
    "The thrust coefficient b (thrust = b w^2) comes from, in this order: least squares on the "
    "training recordings' /thrust/measured; --thrust-coefficient; --vehicle-mass-kg with "
    "--motor-count, assuming the vehicle hovers: its mean total thrust while airborne equals "
    "its weight m g, shared equally, so b = m g / (N mean(w^2)) over the samples with the rotor "
    "clearly turning; --propeller-ct with --prop-diameter-in (b = CT rho D^4 / (4 pi^2), sea "
    "level air). Else the model has no b: it predicts speed only, and replay and the nodes "
    "publish no thrust."
)

#: Said when a model gets no b: nothing downstream will have a thrust.
NO_THRUST_WARNING = (
    "no thrust coefficient: the model predicts speed only (replay and the nodes publish no "
    "predicted/thrust); record /thrust/measured, or give --thrust-coefficient, --vehicle-mass-kg "
    "with --motor-count, or --propeller-ct with --prop-diameter-in")
#: LM runs from different initial weights, best on validation kept (see train_model): on the
#: bundled bags one run's chirp error below 0.5 Hz spans 1.7-5.4 % of the range over seeds.
DEFAULT_RESTARTS = 5
#: Most restarts: each is a whole LM training (seconds to minutes at the paper's size).
MAX_RESTARTS = 50


def _inputs(text: str) -> list[str]:
    names = [n.strip() for n in text.split(",") if n.strip()]
    if not names:
        raise argparse.ArgumentTypeError("at least one input name")
    if len(set(names)) != len(names):
        raise argparse.ArgumentTypeError(f"{text!r} names an input twice")
    return names


#: The network's options and their defaults; with --kind physics they are refused (given
#: explicitly, they would be silently ignored).
NETWORK_DEFAULTS: dict[str, object] = {"inputs": list(c.DEFAULT_INPUTS), "hidden": c.PAPER_HIDDEN, "seed": 0,
                                    "restarts": DEFAULT_RESTARTS, "max_epochs": 1000, "patience": 6}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("train", nargs="+", metavar="TRAIN_BAG", help="training recordings")
    p.add_argument("--validation", nargs="+", required=True, metavar="BAG",
                   help="validation recordings (separate experiments; they stop the training)")
    p.add_argument("-o", "--output", required=True, help="model file to write (.npz)")
    p.add_argument("--kind", choices=("network", "physics", "hybrid"), default="network",
                   help="network: the paper's n-H-1 network (default); physics: the bench's ESC, motor, "
                        "rotor and thermal physics, Kv, CP and the effects' strengths fitted by least "
                        "squares, the ESC's braking chosen on the validation recordings; hybrid: that "
                        "physics plus a network (inputs physics_speed and --inputs) trained on what it "
                        "gets wrong")
    p.add_argument("--physics-config", metavar="CONFIG",
                   help="--kind physics/hybrid: start the fit from this physics CONFIG (JSON, as `discrepancy "
                        "--physics CONFIG` reads it) instead of the stated motor (--motor-kv, --prop-diameter-in, "
                        "...) or the simulator's 12 in bench; where it and a stated prior both give a constant, "
                        "the CONFIG wins (with a warning)")
    p.add_argument("--inputs", type=_inputs,
                   help="comma-separated model inputs (default: battery_voltage,pwm,pwm_filtered)")
    p.add_argument("--hidden", type=HIDDEN, help="hidden neurons, 1..200 (default 25)")
    p.add_argument("--seed", type=SEED, help="seed of the initial weights (default 0)")
    p.add_argument("--restarts", type=number(int, 1, MAX_RESTARTS),
                   help=f"train from the initial weights of seeds SEED, SEED+1, ... and keep the one with "
                        f"the least validation cost (default {DEFAULT_RESTARTS})")
    p.add_argument("--max-epochs", type=EPOCHS, help="epoch limit (default 1000)")
    p.add_argument("--patience", type=EPOCHS,
                   help="stop after this many epochs without validation improvement (default 6)")
    p.add_argument("--report", metavar="DIR", help="write PNG figures and index.html to DIR")
    p.add_argument("--force", action="store_true",
                   help="replace an existing model file (a model only) and report folder (one this tool made)")
    add_namespace_argument(p)
    add_prior_arguments(p)  # what the user states of motor, propeller, vehicle; b among them


def _check_disjoint(train: list[str], validation: list[str]) -> None:
    both = {os.path.realpath(p) for p in train} & {os.path.realpath(p) for p in validation}
    if both:
        raise BadInputError(
            f"{sorted(both)[0]}: given for both training and validation (they must be separate recordings)"
        )


def _network_options(args: argparse.Namespace) -> None:
    """The network's options: refused with --kind physics, else their defaults filled in."""
    for name, default in NETWORK_DEFAULTS.items():
        if getattr(args, name) is None:
            setattr(args, name, default)
        elif args.kind == "physics":
            raise BadInputError(f"--{name.replace('_', '-')}: trains a network, so it goes with --kind network")
    if c.INPUT_PHYSICS_SPEED in args.inputs:
        raise BadInputError(f"--inputs {c.INPUT_PHYSICS_SPEED}: the physics model's speed is no input of a network")
    if args.kind == "network" and getattr(args, "physics_config", None):
        raise BadInputError(f"--physics-config {args.physics_config}: the physics fit's start, so it goes with "
                            "--kind physics or hybrid")
    if args.kind == "network":  # a network has no Kv or pitch: given, they would be silently ignored
        for name in PHYSICS_PRIORS:
            if getattr(args, name, None) is not None:
                raise BadInputError(f"--{name.replace('_', '-')}: a prior of the physics fit, so it goes with "
                                    "--kind physics or hybrid (a network has no motor constants)")


#: Prior options only the physics fit uses (--prop-diameter-in also gives b with --propeller-ct).
PHYSICS_PRIORS = ("motor_kv", "pole_count", "cells", "prop_pitch_in")


def run(args: argparse.Namespace) -> CommandResult:
    from ..model import MODEL, save_model
    from ..recordings import gap_warnings, load_all
    from ..training.train import stated_thrust

    _network_options(args)
    priors = priors_from_args(args)  # options that go together, checked before any work
    out = Path(args.output)
    check_outputs([(out, MODEL, "-o"), (args.report, REPORT, "--report")], force=args.force,
                  inputs=[*args.train, *args.validation, args.physics_config])
    _check_disjoint(args.train, args.validation)
    if args.physics_config:  # a bad CONFIG is refused here, not after the first progress lines
        from ..physics.config import load_config

        load_config(args.physics_config, option="--physics-config")
    # every check that reads the inputs comes before the first progress line, so that bad
    # input gives one line on stderr and nothing else
    train = load_all(args.train, "training", args.namespace)
    validation = load_all(args.validation, "validation", args.namespace)
    by_key = {s.key: s.path for s in train}
    for s in validation:
        if s.key in by_key:
            raise BadInputError(f"{s.path}: same recording as training recording {by_key[s.key]}")
    stated = stated_thrust(priors, train)  # b the user stated (hover: from the training recordings)
    progress(f"read {len(train)} training and {len(validation)} validation recordings")

    gap_lines = gap_warnings([*train, *validation])
    if args.kind == "physics":
        return with_warnings(_run_physics(args, out, train, validation, stated, priors), gap_lines)
    hybrid = args.kind == "hybrid"
    inputs = [c.INPUT_PHYSICS_SPEED, *args.inputs] if hybrid else list(args.inputs)
    outcome, physics_warnings = _train_network(args, train, validation, stated, priors)
    meta = outcome.model.metadata
    warnings = [*gap_lines, *_run_warnings(meta, hybrid, out)]
    warnings += physics_warnings  # the physics part's start and fit flags
    thrust_line, thrust_warnings = _thrust_summary(outcome.thrust)
    warnings += thrust_warnings
    save_model(outcome.model, out, force=args.force)
    data: dict[str, object] = {
        "model": str(out),
        "kind": args.kind,
        "inputs": inputs,
        "hidden": args.hidden,
        "epochs": meta["epochs"],
        "best_epoch": meta["best_epoch"],
        "stop_reason": meta["stop_reason"],
        "train_cost": meta["train_cost"],
        "validation_cost": meta["validation_cost"],
        "train_rmse_rad_s": outcome.train_rmse_rad_s,
        "validation_rmse_rad_s": outcome.validation_rmse_rad_s,
        **rmse_percent_of_range(outcome),
        "thrust_coefficient": outcome.thrust.coefficient,
        "thrust_fit": outcome.thrust.as_metadata(),
        "samples": meta["samples"],
        "best_seed": meta["best_seed"],
        "restarts": meta["restarts"],
    }
    if args.report:
        data["report"] = write_training_report(Path(args.report), outcome, force=args.force)
    text = "\n".join([
        ("physics fitted, then " if hybrid else "")
        + f"trained {len(inputs)}-{args.hidden}-1 on {', '.join(inputs)}: "
        f"{meta['epochs']} epochs, best {meta['best_epoch']} ({meta['stop_reason']})"
        + (f"; seed {meta['best_seed']} had the least validation cost of {args.restarts} runs"
           if args.restarts > 1 else ""),
        f"  RMSE training {outcome.train_rmse_rad_s:.2f} rad/s, validation {outcome.validation_rmse_rad_s:.2f} rad/s "
        f"({meta['samples']['train']} / {meta['samples']['validation']} samples)",
        thrust_line,
        f"  saved {out}" + (f"; figures in {data['report']}" if args.report else ""),
    ])
    data["warnings"] = warnings
    return CommandResult(data, text, warnings=warnings)


def _train_network(args: argparse.Namespace, train: list[Signals], validation: list[Signals],
                   stated: ThrustFit | None, priors: MotorPriors) -> tuple[TrainOutcome, list[str]]:
    """The network (--kind network), or the physics and then the network on its error (--kind
    hybrid), with the epochs reported as they go; and the physics part's warnings."""
    from ..training.train import train_model

    run = [0]

    def report_epoch(epoch: int, cost: float, val: float, mu: float) -> None:
        if epoch == 0 and args.restarts > 1:
            run[0] += 1
            progress(f"run {run[0]} of {args.restarts} (seed {args.seed + run[0] - 1})")
        progress(f"epoch {epoch:4d}  cost {cost:.6g}  validation {val:.6g}  mu {mu:.3g}")

    network = {"hidden": args.hidden, "seed": args.seed, "max_epochs": args.max_epochs,
               "patience": args.patience, "progress": report_epoch, "restarts": args.restarts}
    if args.kind != "hybrid":
        return train_model(train, validation, inputs=list(args.inputs), thrust_coefficient=stated, **network), []
    # the physics first; the network learns what it gets wrong
    from ..training.fit_physics import train_hybrid, train_physics

    physics = train_physics(train, validation, thrust_coefficient=stated, priors=priors,
                            config=args.physics_config, progress=progress)
    progress(f"physics: RMSE training {physics.train_rmse_rad_s:.2f} rad/s, validation "
             f"{physics.validation_rmse_rad_s:.2f} rad/s; training the network on its error")
    return train_hybrid(physics, inputs=args.inputs, **network), physics.warnings


def _run_warnings(meta: dict[str, Any], hybrid: bool, out: Path) -> list[str]:
    """What the LM runs' histories (in ``meta``, the model's JSON metadata) say: BadInputError when
    the kept network is its initial weights (nothing was learnt), a warning when the hybrid's
    correction stayed 0 or some runs never improved."""
    runs = len(meta["restarts"])
    warnings = []
    if meta["best_epoch"] == 0 and hybrid:  # its initial weights: the physics alone
        warnings.append("the network did not improve on the physics on the validation recordings: "
                        "the hybrid's correction is 0 (the physics model alone)")
    elif meta["best_epoch"] == 0:  # the kept network is its initial weights: nothing was learnt
        raise BadInputError(
            f"-o {out}: not written: no training run improved on its initial weights (validation "
            f"cost {meta['validation_cost']:.4g} at epoch 0 in the best of {runs} run(s)); check that the "
            "validation recordings are the same bench and signals as the training ones "
            "(`bldc-propulsion info`), or give more --restarts")
    stuck = sum(1 for r in meta["restarts"] if r["best_epoch"] == 0)
    if stuck and not warnings:
        warnings.append(f"{stuck} of {runs} training runs never improved on their initial weights "
                        "(the kept run did)")
    return warnings


def _thrust_summary(fit: ThrustFit) -> tuple[str, list[str]]:
    """The summary's line on b (where it came from, or that there is none) and the warnings to
    print with it: the fit's, and without b that nothing downstream will have a thrust."""
    if fit.coefficient is None:
        return f"  no thrust coefficient ({fit.source}): speed only", [*fit.warnings, NO_THRUST_WARNING]
    residual = f", residual {fit.residual_rms_n:.3f} N RMS" if fit.residual_rms_n is not None else ""
    return f"  thrust coefficient b = {fit.coefficient:.4g} N s^2/rad^2 ({fit.source}{residual})", list(fit.warnings)


def _run_physics(args: argparse.Namespace, out: Path, train: list[Signals], validation: list[Signals],
                 stated: ThrustFit | None, priors: MotorPriors) -> CommandResult:
    """``--kind physics``: training/fit_physics.py; ``stated``: the b the user stated."""
    from ..model import save_model
    from ..training.fit_physics import train_physics

    outcome = train_physics(train, validation, thrust_coefficient=stated, priors=priors,
                            config=args.physics_config, progress=progress)
    m, fit = outcome.model, outcome.thrust
    thrust_line, thrust_warnings = _thrust_summary(fit)
    save_model(m, out, force=args.force)
    data: dict[str, object] = {
        "model": str(out),
        "kind": "physics",
        "fit": m.metadata["fit"],
        "constants": outcome.candidates[0]["constants"],
        "effects": m.effects,
        "train_rmse_rad_s": outcome.train_rmse_rad_s,
        "validation_rmse_rad_s": outcome.validation_rmse_rad_s,
        **rmse_percent_of_range(outcome),
        "candidates": outcome.candidates,
        "thrust_coefficient": fit.coefficient,
        "thrust_fit": fit.as_metadata(),
    }
    if args.report:
        data["report"] = write_training_report(Path(args.report), outcome, force=args.force)
    consts = ", ".join(f"{k} {v:.4g}" for k, v in outcome.candidates[0]["constants"].items())
    strengths = ", ".join(f"{k} {v:.2f}" for k, v in m.effects.items())
    warnings = [*outcome.warnings, *thrust_warnings]  # the start's, and the kept fit's flags
    refused = sum(1 for d in outcome.candidates if d["refused"])  # contradicted the stated motor
    text = "\n".join([
        f"fitted the bench physics ({m.metadata['fit']}, kept by the validation recordings among "
        f"{len(outcome.candidates) - refused} fits"
        + (f"; {refused} more contradicted the stated motor" if refused else "") + f"): {consts}",
        f"  effect strengths: {strengths}",
        f"  RMSE training {outcome.train_rmse_rad_s:.2f} rad/s, validation {outcome.validation_rmse_rad_s:.2f} rad/s",
        thrust_line,
        f"  saved {out}" + (f"; figures in {data['report']}" if args.report else ""),
    ])
    data["warnings"] = warnings
    return CommandResult(data, text, warnings=warnings)


# --- report ---------------------------------------------------------------------------------
def speed_range_rad_s(signals: list[Signals]) -> float:
    """Range (max - min) of the measured speed over all of ``signals`` together (rad/s)."""
    import numpy as np

    w = np.concatenate([s.speed for s in signals]) if signals else np.zeros(0)
    w = w[np.isfinite(w)]
    return float(np.ptp(w)) if len(w) else float("nan")


def rmse_percent_of_range(outcome: TrainOutcome | PhysicsOutcome) -> dict[str, float | None]:
    """The training and validation RMSE in % of the speed range of their recordings (--json's
    ``train_rmse_percent_of_range``, ``validation_rmse_percent_of_range``): comparable across
    benches of different top speeds, as evaluate's % of range is."""
    out: dict[str, float | None] = {}
    for key, rmse, signals in (("train", outcome.train_rmse_rad_s, outcome.train),
                               ("validation", outcome.validation_rmse_rad_s, outcome.validation)):
        span = speed_range_rad_s(signals)
        out[f"{key}_rmse_percent_of_range"] = 100.0 * rmse / span if span > 0 else None
    return out


def write_training_report(path: Path, outcome: TrainOutcome | PhysicsOutcome, force: bool = False) -> str:
    """Figures of a training run, written whole to ``path`` (atomic.report_output)."""
    with report_output(path, force=force) as d:
        _training_report(d, outcome)
    return str(path)


def training_headline(outcome: TrainOutcome | PhysicsOutcome) -> list[tuple[str, str]]:
    """What a reader of the training page needs first, in the summary's figures: the model,
    the RMSE on training and validation recordings (rad/s and % of their speed range), and b
    with where it came from, or that it is not known."""
    m, fit = outcome.model, outcome.thrust
    pct = rmse_percent_of_range(outcome)
    rows: list[tuple[str, str]] = []
    if hasattr(outcome, "lm"):  # a network or a hybrid
        meta = m.metadata
        rows.append(("model", f"{m.kind} {len(m.input_names)}-{meta['hidden']}-1 on {', '.join(m.input_names)}: "
                              f"{meta['epochs']} epochs, best {meta['best_epoch']} ({meta['stop_reason']})"))
    else:
        rows.append(("model", f"{m.kind}: the bench physics fitted ({m.metadata.get('fit', '')})"))
    for key, label, rmse, signals in (("train", "training", outcome.train_rmse_rad_s, outcome.train),
                                      ("validation", "validation", outcome.validation_rmse_rad_s, outcome.validation)):
        p = pct[f"{key}_rmse_percent_of_range"]
        rows.append((f"{label} RMSE", f"{rmse:.2f} rad/s"
                     + (f" ({p:.2f} % of the {speed_range_rad_s(signals):.0f} rad/s range)" if p is not None else "")
                     + f" on {len(signals)} recording(s)"))
    if fit.coefficient is None:
        rows.append(("thrust coefficient b", f"not known ({fit.source}): the model predicts speed only"))
    else:
        residual = f", residual {fit.residual_rms_n:.3f} N RMS" if fit.residual_rms_n is not None else ""
        rows.append(("thrust coefficient b", f"{fit.coefficient:.4g} N s²/rad² (from {fit.source}{residual})"))
    return rows


def _training_report(d: Path, outcome: TrainOutcome | PhysicsOutcome) -> None:
    """The training page: headline (``training_headline``), then the model against each
    validation recording (Fig. 13), its thrust against the load cell where thrust is recorded
    and the model has b, the learning curve (Fig. 12, a network's), the battery filter on the
    first training recording (Figs. 1-2) and a training recording's command and speed (Figs. 5-6)."""
    from ..training import report
    from ..training.evaluate import predict_speed

    figs: list[tuple[str, str]] = []
    headline = training_headline(outcome)
    notes: list[str] = []
    preds = [predict_speed(outcome.model, sig) for sig in outcome.validation]
    for k, (sig, pred) in enumerate(zip(outcome.validation, preds, strict=True)):
        name = f"fig13_validation_{k}.png"
        report.fig_validation(sig.t, sig.pwm, sig.voltage, sig.speed, pred, d / name, title=sig.path)
        figs.append((name, f"Fig. 13: PWM, voltage, measured and predicted speed and their error on validation "
                           f"recording {sig.path}"))
    b = outcome.model.thrust_coefficient
    with_thrust = [(sig, pred, "validation") for sig, pred in zip(outcome.validation, preds, strict=True)
                   if sig.thrust is not None]
    if not with_thrust:  # b was fitted on the training recordings' thrust: show how well it fits there
        with_b = next((s for s in outcome.train if s.thrust is not None), None)
        with_thrust = [(with_b, predict_speed(outcome.model, with_b), "training")] if with_b is not None else []
    if b is None:
        notes.append("no thrust figure: the model has no thrust coefficient b")
    elif not with_thrust:
        notes.append("no thrust figure: no training or validation recording has /thrust/measured")
    else:
        for k, (sig, pred, role) in enumerate(with_thrust):
            name = f"thrust_{role}_{k}.png"
            predicted = b * pred**2
            report.fig_thrust(sig.t, sig.thrust, predicted, d / name, recording=sig.path, coefficient=b)
            figs.append((name, f"measured vs predicted thrust (b·ω²) and the thrust error on {role} recording "
                               f"{sig.path}"))
            headline.append((f"thrust, {role} {sig.path}", report.thrust_error_text(sig.thrust, predicted)))
    if hasattr(outcome, "lm"):  # a network (a physics model has no epochs)
        h = outcome.lm.history
        report.fig_training(h.train_cost, h.val_cost, outcome.lm.best_epoch, d / "fig12_training.png")
        figs.append(("fig12_training.png", "Fig. 12: learning curve, training and validation cost per epoch"))
    else:
        notes.append("no learning curve: a physics fit has no epochs (least squares on the constants)")
    first = outcome.train[0]
    raw = _raw_battery(first)
    if raw is not None:
        report.fig_battery_filter(raw[0], raw[1], raw[2], d / "fig01_battery_filter.png",
                                  pwm_t=first.t, pwm=first.pwm, recording=first.path)
        figs.append(("fig01_battery_filter.png", f"Figs. 1-2: raw vs filtered battery voltage, and the PWM "
                                                 f"command ({first.path})"))
    # the paper's Figs. 5-6 show a ramp: a training recording with ramps if there is one
    ramp = next((s for s in outcome.train if report.describe_command(s.t, s.pwm).startswith("ramps")),
                outcome.train[0])
    report.fig_ramp(ramp.t, ramp.pwm, ramp.speed, d / "fig05_ramp.png", recording=ramp.path)
    figs.append(("fig05_ramp.png", f"Figs. 5-6: PWM command ({report.describe_command(ramp.t, ramp.pwm)}) and "
                                   f"measured speed ({ramp.path})"))
    report.write_index(d, f"bldc_propulsion training report: {outcome.model.kind} model", figs,
                       headline=headline, notes=notes)


def _raw_battery(sig: Signals) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(t, raw battery V with divider undone, filtered V) for Fig. 1, when battery/adc exists."""
    import numpy as np

    from ..bagio import open_recording
    from ..core.battery_filter import BatteryFilterConfig

    with open_recording(sig.path, sig.namespace) as rec:
        if not rec.has(c.TOPIC_BATTERY_ADC):
            return None
        t, adc = rec.scalars(c.TOPIC_BATTERY_ADC)
    ratio = BatteryFilterConfig().divider_ratio
    return t, adc * ratio, np.interp(t, *sig.voltage_events)
