"""`bldc-propulsion discrepancy`: arguments, loading, and the summary for people and scripts
(the workflow itself is discrepancy/workflow.py, one loop for both model kinds)."""

from __future__ import annotations

import argparse
import dataclasses
import os
from collections.abc import Callable
from typing import TYPE_CHECKING, TypeVar, cast

from .. import contract as c
from ..atomic import REPORT, check_outputs

# The workflow (scipy, rosbags) is imported inside the functions that run it, so that `--help`
# stays quick; its decision thresholds, the options' defaults, come from a module that imports nothing.
from ..discrepancy.defaults import ALPHA, MIN_EFFECT
from ..errors import BadInputError
from ..priors import MotorPriors, add_prior_arguments, priors_from_args
from ..specs import spec_path
from .common import EPOCHS, HIDDEN, SEED, CommandResult, add_namespace_argument, number, progress

if TYPE_CHECKING:
    from ..discrepancy.workflow import WorkflowResult
    from ..model import HybridModel, Model, NetworkModel
    from ..physics.config import PhysicsConfig
    from ..physics.plant_model import PlantModel
    from ..recordings import Signals
    from ..training.train import ThrustFit

#: The model a discrepancy run hands back (a network, or the bench physics).
_M = TypeVar("_M")


def _effects(text: str) -> list[str]:
    names = [n.strip() for n in text.split(",") if n.strip()]
    if not names:
        raise argparse.ArgumentTypeError("at least one effect name")
    return names


NAME = "discrepancy"
HELP = "find where a model and measurements disagree, name the missing effect, add it"
DESCRIPTION = (
    "Run a model (trained network or bench physics) over measured recordings, find "
    "where and when it disagrees with the measured speed, test which physical effect "
    "explains the disagreement (battery_voltage, rotor_lag, input_delay, "
    "esc_deadband, spin_down_asymmetry, motor_heating), add the best one to the "
    "model, and show the error shrink on held-out recordings."
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--model", metavar="MODEL.npz",
                     help="model file (.npz from `train`): a network is retrained with the effect's input; a "
                          "physics model takes the --physics path (as --physics MODEL.npz); a hybrid its "
                          "physics part, with a warning (the network's correction is left out)")
    src.add_argument("--physics", nargs="?", const="", metavar="CONFIG",
                     help="the bench physics as the model: without CONFIG the package's nominal bench "
                          "with every effect OFF; CONFIG is a JSON file {\"params\": {BenchParams field: "
                          "value}, \"effects\": {name: strength}, \"supply_v\": V} in which effects not listed are "
                          "OFF and supply_v (the stiff supply when battery_voltage is off) defaults to the "
                          "measured median (what -o writes), or a physics model .npz. Kv and CP are calibrated "
                          "on the measured data first. With --motor-kv, --prop-diameter-in, ... the bench is "
                          "resized to your motor first and its Kv and CP are judged against what you stated; a "
                          "CONFIG's constants win where both give one (with a warning)")
    p.add_argument("--measured", nargs="+", required=True, metavar="BAG",
                   help="recordings the model is to be checked against")
    p.add_argument("--reference", nargs="+", metavar="BAG",
                   help="the model's own reference recordings (default: its training recordings, "
                        "from the model's metadata)")
    p.add_argument("--holdout", nargs="+", metavar="BAG",
                   help="recordings kept out of everything, for the before/after RMSE")
    p.add_argument("--max-effects", type=number(int, 1, len(c.EFFECTS)), default=3,
                   help="most effects to add (default 3)")
    p.add_argument("--effects", type=_effects, metavar="NAME,...",
                   help="only consider these effects (default: all of " + ", ".join(c.EFFECTS) + ")")
    p.add_argument("--alpha", type=number(float, 0.0, 0.5, lo_open=True), default=ALPHA,
                   help=f"significance level (default {ALPHA})")
    p.add_argument("--min-reduction", type=number(float, 0.0, 1.0), default=MIN_EFFECT,
                   help=f"least held-out MSE reduction to call an effect (default {MIN_EFFECT})")
    p.add_argument("--hidden", type=HIDDEN,
                   help="hidden neurons of the retrained model (--model only; default: as the model)")
    p.add_argument("--max-epochs", type=EPOCHS, help="epoch limit of the retraining (--model only; default 300)")
    p.add_argument("--seed", type=SEED, help="seed of the retraining (--model only; default 0)")
    p.add_argument("--report", metavar="DIR", help="write the disagreement map, before/after figures, index.html")
    p.add_argument("-o", "--output", metavar="NEW",
                   help="save the model with the effect(s) added (.npz; with --physics a physics model "
                        ".npz or a CONFIG .json)")
    p.add_argument("--force", action="store_true",
                   help="replace an existing output of the same kind (a model / CONFIG written by this "
                        "tool, a report folder it made)")
    add_namespace_argument(p)
    # the user's motor: where the physics fit starts, what its Kv and CP are judged against
    add_prior_arguments(p, thrust=False)


def reference_paths(model: Model, model_path: str) -> tuple[list[str], list[str]]:
    """The model's training recordings from its metadata: (found, missing). A relative path is
    tried as written (relative to the working directory), relative to the model file, and
    where it was when the model was trained."""
    sources = (model.metadata or {}).get("sources", {}).get("train", [])
    found, missing = [], []
    for src in sources:
        path = src.get("path") if isinstance(src, dict) else str(src)
        if not path:
            continue
        path = path.split("#", 1)[0]  # a part of a recording (discrepancy retraining)
        candidates = [path, os.path.join(os.path.dirname(os.path.abspath(model_path)), path)]
        if isinstance(src, dict) and src.get("abs_path"):
            candidates.append(str(src["abs_path"]))  # where it was at training time
        hit = next((p for p in candidates if os.path.exists(spec_path(p))), None)  # PATH@NS: specs.py
        if hit is None:
            missing.append(path)
        elif hit not in found:
            found.append(hit)
    return found, missing


def _recordings(args: argparse.Namespace, ref_paths: list[str]) -> tuple[list[Signals], list[Signals], list[Signals]]:
    """The measured, reference and holdout recordings, read through the cores."""
    from ..discrepancy.workflow import check_holdout
    from ..recordings import load_all, load_signals, unique

    ns = args.namespace
    measured = load_all(args.measured, "measured", ns)
    # a model trained on the bench and measured on a vehicle: its reference recordings are read
    # under the namespace where they have it, else at the root (bench recordings)
    reference = unique([load_signals(p, namespace=ns if _has_namespace(p, ns) else None) for p in ref_paths],
                       "reference")
    holdout = load_all(args.holdout, "holdout", ns) if args.holdout else []
    check_holdout(holdout, measured, reference)  # before any output: the refusal is one line
    progress(f"read {len(measured)} measured, {len(reference)} reference and "
             f"{len(holdout)} holdout recording(s)")
    return measured, reference, holdout


def _has_namespace(path: str, namespace: str | None) -> bool:
    """The recording has the motor topics under ``namespace`` (not only at the root)."""
    from ..bagio import open_recording

    if namespace is None:
        return False
    with open_recording(path, namespace) as rec:
        return rec.has(c.TOPIC_PWM)


def run(args: argparse.Namespace) -> CommandResult:
    from ..discrepancy.workflow import Options, check_effect_names, run_workflow
    from ..model import MODEL, load_model, save_model
    from ..physics.config import CONFIG
    from ..recordings import gap_warnings
    from ..training.evaluate import input_range

    check_effect_names(args.effects)
    if args.max_effects < 1:
        raise BadInputError(f"--max-effects {args.max_effects}: must be at least 1")
    if not 0.0 < args.alpha < 1.0:
        raise BadInputError(f"--alpha {args.alpha}: must be between 0 and 1")
    # any kind: a physics model (or a hybrid's physics part) goes down the physics path
    model = load_model(args.model) if args.model is not None else None
    physics = model is None or model.kind != c.NETWORK
    priors = priors_from_args(args)
    if not physics and priors.stated:
        raise BadInputError(f"{priors.motor_options()[0]}: states the motor a physics fit starts from, so it goes "
                            f"with --physics or a physics/hybrid --model, not the network {args.model}")
    check_outputs([(args.output, CONFIG if physics and not _is_npz(args.output) else MODEL, "-o"),
                   (args.report, REPORT, "--report")], force=args.force,
                  inputs=[*args.measured, *(args.reference or []), *(args.holdout or []),
                          args.model, args.physics])
    if physics:
        return run_physics(args, priors, model)
    assert model is not None  # not physics: a network --model
    warnings: list[str] = []
    if args.reference:
        ref_paths = list(args.reference)
    else:
        ref_paths, missing = reference_paths(model, args.model)
        if missing:
            warnings.append(f"{len(missing)} of the model's training recordings not found "
                            f"(e.g. {missing[0]}); give --reference")
    measured, reference, holdout = _recordings(args, ref_paths)
    warnings += gap_warnings([*measured, *reference, *holdout])
    ranges = [input_range(model, s) for s in [*measured, *holdout]]
    warnings += [w for r in ranges if (w := r.warning())]
    opts = Options(max_effects=args.max_effects, restrict=args.effects, hidden=args.hidden,
                   max_epochs=300 if args.max_epochs is None else args.max_epochs,
                   seed=0 if args.seed is None else args.seed, alpha=args.alpha,
                   min_effect=args.min_reduction, report_dir=args.report,
                   report_force=args.force)
    # (not physics: the file's kind says it is a network)
    result = run_workflow(cast("NetworkModel", model), measured, reference, holdout, opts, progress)
    data = result.data
    data["out_of_training_range"] = {r.where: r.as_dict() for r in ranges}

    def save() -> None:
        result.model.metadata["discrepancy"] = {
            "base_model": str(args.model),
            "added": [{"effect": n, "input": data["added_inputs"][k],
                       "parameters": data["evidence"][n].get("fitted_parameters", {})}
                      for k, n in enumerate(data["added"])],
        }
        save_model(result.model, args.output, force=args.force)

    return _finish(args, result, save, "the model", warnings)


def run_physics(args: argparse.Namespace, priors: MotorPriors, loaded: Model | None = None) -> CommandResult:
    """``--physics [CONFIG]``, or ``--model`` of kind physics or hybrid (``loaded``): the bench
    physics as the model (see discrepancy/physics_kind.py). A hybrid's physics part is checked:
    the workflow fits physical effects, and a network correction on top would hide the very
    disagreement it looks for; so it says so, and -o is a physics model or CONFIG."""
    from ..discrepancy.workflow import Options, run_physics_workflow
    from ..model import save_model
    from ..physics.config import save_config, supply_tau_s
    from ..physics.plant_model import PlantModel
    from ..recordings import gap_warnings

    where = "--physics" if loaded is None else f"the {loaded.kind} model {args.model}"
    for flag, value in (("--hidden", args.hidden), ("--max-epochs", args.max_epochs), ("--seed", args.seed)):
        if value is not None:
            raise BadInputError(f"{flag}: retrains a network, so it goes with a network --model, not {where}")
    warnings: list[str] = []
    if loaded is None:
        base, model = args.physics or None, _physics_input(args.physics)  # a bad CONFIG fails before any work
    else:
        base = str(args.model)
        # (the file's kind says which: a hybrid, or a physics model)
        plant = cast("HybridModel", loaded).plant if loaded.kind == c.HYBRID else cast("PlantModel", loaded)
        model = _physics_of(plant, base)
        if loaded.kind == c.HYBRID:
            out = f"; -o {args.output} gets a physics model" if args.output else ""
            warnings.append(f"--model {args.model}: a hybrid: its physics part is checked, without the "
                            f"network's correction{out}")
    measured, reference, holdout = _recordings(args, list(args.reference or []))
    warnings += gap_warnings([*measured, *reference, *holdout])
    if loaded is None and not _is_npz(args.physics):
        # the start: the stated motor under the CONFIG (which wins where both give a constant), sized
        # at the measured recordings' voltage; neither given: the nominal bench
        from ..physics.config import NOMINAL_START_WARNING, median_voltage, start_model

        model, notes, start_warnings = start_model(args.physics or None, priors, median_voltage(measured))
        # (from the nominal bench, every fit flag says so: "nominal (no CONFIG given)")
        warnings += [w for w in start_warnings if w != NOMINAL_START_WARNING]
        for line in notes:
            progress(f"start: {line}")
    else:
        warnings += _model_vs_priors(model, priors, where)
    opts = Options(max_effects=args.max_effects, restrict=args.effects, alpha=args.alpha,
                   min_effect=args.min_reduction, report_dir=args.report,
                   report_force=args.force)
    result = run_physics_workflow(model, measured, reference, holdout, opts, progress)
    data = result.data

    def save() -> None:
        provenance = {"base": base,
                      "added": [{"effect": n, **data["evidence"][n]["fitted_parameters"]} for n in data["added"]],
                      "measured": [str(p) for p in args.measured]}
        if _is_npz(args.output):
            m = result.model
            thrust = _thrust_of(loaded, [*reference, *measured])
            provenance["thrust_fit"] = thrust.as_metadata()
            warnings.extend(thrust.warnings)
            if thrust.coefficient is None:
                warnings.append(f"-o {args.output}: no thrust coefficient: no /thrust/measured in the recordings "
                                "and no model's b to keep, so the model predicts speed only")
            # (supply_v is set: the workflow runs the model with_supply)
            save_model(PlantModel(m.params, m.effects, cast(float, m.supply_v), thrust.coefficient,
                                  metadata={"discrepancy": provenance},
                                  supply_tau_s=supply_tau_s(measured[0])), args.output, force=args.force)
        else:
            save_config(result.model, args.output, args.force, provenance)

    return _finish(args, result, save, "the physics model" if _is_npz(args.output) else "the physics config",
                   warnings)


def _thrust_of(loaded: object, signals: list[Signals]) -> ThrustFit:
    """b of a physics model that ``discrepancy`` writes: measured thrust in the recordings, else
    the b of the model it started from, else none. Never the CT of the CONFIG or of the
    simulator's 12 in bench: that is a number nobody measured or stated for this propeller."""
    from ..training.train import ThrustFit, fit_thrust_coefficient

    kept = getattr(loaded, "thrust_coefficient", None) if loaded is not None else None
    stated = None if kept is None else ThrustFit(float(kept), None, 0, "kept from the model file")
    return fit_thrust_coefficient(signals, stated)


def _model_vs_priors(model: PhysicsConfig, priors: MotorPriors, where: str) -> list[str]:
    """A model file's constants win over stated priors (it was fitted); one warning per stated
    Kv or CP the model's value is outside the prior's range of (``physics.sizing.physics_start``)."""
    from ..physics.sizing import physics_start

    start = physics_start(priors) if priors.stated else None
    if start is None:
        return []
    out = [f"{', '.join(priors.motor_options())}: {where} gives every constant; the stated motor is not its start"]
    for name, (lo, hi) in start.ranges.items():
        value = float(getattr(model.params, name))
        if not lo <= value <= hi:
            out.append(f"{where}: {name} {value:.4g} is outside {lo:.4g}-{hi:.4g} around the stated "
                       f"{getattr(start.params, name):.4g} ({start.stated[name]}): another motor or propeller, or "
                       "a fit that stands in for something else")
    return out


def _is_npz(path: str | None) -> bool:
    return bool(path) and str(path).lower().endswith(".npz")


def _physics_input(path: str) -> PhysicsConfig:
    """``--physics CONFIG``: a JSON CONFIG, or a physics model file (.npz)."""
    from ..model import load_model
    from ..physics.config import load_config

    if not _is_npz(path):
        return load_config(path)
    return _physics_of(cast("PlantModel", load_model(path, kinds=(c.PHYSICS,))), path)  # kinds: a physics model


def _physics_of(m: PlantModel, source: str) -> PhysicsConfig:
    """The workflow's physics model of a model file's plant (``physics.plant_model.PlantModel``),
    on the nominal bench's constants where the file has none."""
    from ..physics.config import PhysicsConfig, load_config

    nominal = load_config(None).params
    return PhysicsConfig(dataclasses.replace(nominal, **dataclasses.asdict(m.params)), dict(m.effects), m.supply_v,
                         source=source)


def _finish(args: argparse.Namespace, result: WorkflowResult[_M], save: Callable[[], None], what: str,
            warnings: list[str]) -> CommandResult:
    """Step 4's output for either model kind: ``save()`` the model with the added effects (new
    and structural) to -o (nothing is written when nothing was added), then the summary and every
    warning."""
    data = result.data
    lines = list(result.lines)
    if args.output:
        if data["added"]:
            save()
            data["model"] = str(args.output)
            lines.append(f"saved {what} with {', '.join(data['added'])} added to {args.output}")
        else:
            lines.append(f"nothing added: {args.output} not written")
    warnings = [*warnings, *data.pop("warnings", [])]
    data["warnings"] = warnings
    return CommandResult(data, "\n".join(lines), warnings=warnings)
