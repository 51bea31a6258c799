"""`bldc-propulsion evaluate`: a model's speed error on recordings (training/evaluate.py),
per recording and per command-frequency band, with warnings where the inputs leave the model's
training range, and its report."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np

from ..atomic import REPORT, check_outputs, report_output
from ..model import load_model
from ..recordings import Signals, load_signals
from ..training.evaluate import evaluate
from .common import CommandResult, add_namespace_argument

NAME = "evaluate"
HELP = "measure a model's speed error on recordings"
DESCRIPTION = (
    "Run a model over recordings and compare its predicted rotor speed with the "
    "measured one (/rotor/speed if recorded, else decoded from /tachometer/adc): "
    "RMSE, RMSE as %% of the speed range, maximum error, and for chirp-like "
    "recordings the error per command frequency band."
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--model", required=True, help="model file (.npz) from `train`")
    p.add_argument("recordings", nargs="+", metavar="BAG", help="recordings to evaluate on")
    p.add_argument("--report", metavar="DIR", help="write PNG figures and index.html to DIR")
    p.add_argument("--force", action="store_true", help="replace an existing report folder (one this tool made)")
    add_namespace_argument(p)


def run(args: argparse.Namespace) -> CommandResult:
    check_outputs([(args.report, REPORT, "--report")], force=args.force,
                  inputs=[args.model, *args.recordings])
    model = load_model(args.model)
    signals = [load_signals(p, namespace=args.namespace) for p in args.recordings]
    rmse, scores, preds = evaluate(model, signals)
    data: dict[str, Any] = {
        "model": str(args.model),
        "rmse_rad_s": rmse,
        "recordings": [s.as_dict() for s in scores],
    }
    lines = [f"model {args.model}: overall RMSE {rmse:.2f} rad/s"]
    for s in scores:
        lines.append(
            f"  {s.path}: RMSE {s.rmse_rad_s:.2f} rad/s ({s.rmse_percent_of_range:.2f} % of the "
            f"{s.speed_range_rad_s:.0f} rad/s range), max error {s.max_error_rad_s:.1f} rad/s"
            + (f"; thrust RMSE {s.thrust_rmse_n:.3f} N" if s.thrust_rmse_n is not None else "")
        )
        for b in s.bands:
            lines.append(
                f"      command {b['low_hz']:.1f}-{b['high_hz']:.1f} Hz: RMSE {b['rmse_rad_s']:.2f} rad/s "
                f"({b['rmse_percent_of_range']:.2f} %)"
            )
    if args.report:
        data["report"] = write_evaluation_report(Path(args.report), signals, preds, scores, force=args.force)
        lines.append(f"  figures in {data['report']}")
    warnings = [w for s in scores if s.out_of_range and (w := s.out_of_range.warning())]
    data["warnings"] = warnings
    return CommandResult(data, "\n".join(lines), warnings=warnings)


# --- report ---------------------------------------------------------------------------------
def write_evaluation_report(path: Path, signals: list[Signals], preds: list[np.ndarray], scores: list[Any],
                            force: bool = False) -> str:
    """Figures and tables of an evaluation, written whole to ``path`` (atomic.report_output)."""
    with report_output(path, force=force) as d:
        _evaluation_report(d, signals, preds, scores)
    return str(path)


def _evaluation_report(d: Path, signals: list[Signals], preds: list[np.ndarray], scores: list[Any]) -> None:
    from ..training import report

    figs: list[tuple[str, str]] = []
    for k, (sig, pred) in enumerate(zip(signals, preds)):
        name = f"fig13_{k}.png"
        report.fig_validation(sig.t, sig.pwm, sig.voltage, sig.speed, pred, d / name, title=sig.path)
        figs.append((name, f"predicted vs measured speed: {sig.path}"))
        name = f"scatter_{k}.png"
        report.fig_prediction_scatter(sig.speed, pred, d / name, recording=sig.path)
        figs.append((name, f"predicted vs measured: {sig.path}"))
    bands = []
    for k, s in enumerate(scores):
        if s.bands:
            name = f"band_error_{k}.png"
            report.fig_band_error(s.bands, d / name, recording=s.path)
            figs.append((name, f"speed error per command frequency band: {s.path}"))
            bands += [{"recording": s.path, "band (Hz)": f"{b['low_hz']:.1f}-{b['high_hz']:.1f}",
                       "samples": b["samples"], "RMSE (rad/s)": b["rmse_rad_s"],
                       "% of speed range": b["rmse_percent_of_range"]} for b in s.bands]
    rows = [{k: v for k, v in s.as_dict().items() if k not in ("bands", "out_of_training_range")}
            | {"outside training range %": 100 * s.out_of_range.fraction if s.out_of_range else None}
            for s in scores]
    tables = [("per recording", rows)] + ([("error per command frequency band", bands)] if bands else [])
    report.write_index(d, "bldc_propulsion evaluation report", figs, tables)
