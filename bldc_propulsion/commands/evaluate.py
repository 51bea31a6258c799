"""`bldc-propulsion evaluate`: a model's speed error on recordings (training/evaluate.py),
per recording and per command-frequency band, with warnings where the inputs leave the model's
training range, and its report."""

from __future__ import annotations

import argparse
import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, TypedDict

from ..atomic import REPORT, check_outputs, report_output
from ..errors import BadInputError
from .common import CommandResult, add_namespace_argument

if TYPE_CHECKING:  # imported where used, so that `--help` does not load numpy, scipy and rosbags
    import numpy as np

    from ..model import Model
    from ..recordings import Signals
    from ..training.evaluate import BandCoverage, BandCoverageJson, RecordingScore, RecordingScoreJson
    from .health import RecordingHealth

NAME = "evaluate"
HELP = "measure a model's speed error on recordings"
DESCRIPTION = (
    "Run a model over recordings and compare its predicted rotor speed with the "
    "measured one (/rotor/speed if recorded, else decoded from /tachometer/adc): "
    "RMSE, RMSE as % of the speed range, maximum error, and for chirp-like "
    "recordings the error per command frequency band; for a model with an uncertainty "
    "band (trained by this version), the share of measured speeds inside its +-1 sigma band "
    "(about 68 % where it is calibrated) and the mean sigma. Several --model files are "
    "compared side by side (a table per recording and band, and with --report one "
    "figure per recording with every model's prediction). With --health, the health monitor "
    "(`bldc-propulsion health`, the code the node's parameter health runs) over each recording, "
    "for each physics or hybrid model: the changes it names, a line each."
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--model", required=True, action="append", metavar="MODEL.npz",
                   help="model file (.npz) of any kind (network, physics, hybrid); give --model again "
                        "to compare several models side by side on the same recordings")
    p.add_argument("recordings", nargs="+", metavar="BAG", help="recordings to evaluate on")
    p.add_argument("--report", metavar="DIR", help="write PNG figures and index.html to DIR")
    p.add_argument("--force", action="store_true", help="replace an existing report folder (one this tool made)")
    p.add_argument("--health", action="store_true",
                   help="also run the health monitor over each recording (as `bldc-propulsion health` with its "
                        "defaults) for each physics or hybrid --model: a line per change found, --json health "
                        "(per recording: events, monitored_s, threshold, injected_faults); a network has no "
                        "physics to monitor with (refused if no --model has)")
    add_namespace_argument(p)


class BandCoverageOrWhyJson(TypedDict):
    """``Evaluation.band_json``: the band's overall coverage, or why the model has none."""

    band_coverage: BandCoverageJson | None
    band_unavailable: str | None


class _EvaluationJsonCore(BandCoverageOrWhyJson):
    model: str
    kind: str
    rmse_rad_s: float
    thrust_coefficient: float | None
    recordings: list[RecordingScoreJson]


class EvaluationJson(_EvaluationJsonCore, total=False):
    """``Evaluation.as_dict``: one model's figures (``models`` in --json with several)."""

    #: with --health: per recording, the monitor's result (None: the model has no physics)
    health: list[RecordingHealth] | None


class ComparisonRow(TypedDict):
    """``comparison``: one row of the side-by-side table; per model file, None where a band had
    too few samples for it."""

    recording: str
    part: str
    rmse_rad_s: dict[str, float | None]
    rmse_percent_of_range: dict[str, float | None]


class _EvaluateJsonCore(BandCoverageOrWhyJson):
    model: str
    rmse_rad_s: float
    thrust_coefficient: float | None
    recordings: list[RecordingScoreJson]


class EvaluateJson(_EvaluateJsonCore, total=False):
    """What ``evaluate --json`` prints: the first (or only) model's figures; with several
    models, each one's and the side-by-side table; the report's folder with --report."""

    models: list[EvaluationJson]
    comparison: list[ComparisonRow]
    report: str
    warnings: list[str]
    health: list[RecordingHealth] | None  #: --health: the first model's (``EvaluationJson.health``)


@dataclass
class Evaluation:
    """One model's evaluation on the command's recordings (training/evaluate.py ``evaluate``)."""

    path: str
    model: Model
    rmse_rad_s: float
    scores: list[RecordingScore]
    predictions: list[np.ndarray]
    #: --health: per recording the monitor's result (None: the model has no physics) and the
    #: timeline's lines (or why not run); None: not asked
    health: tuple[list[RecordingHealth] | None, list[str]] | None = None

    @property
    def label(self) -> str:
        """Its name in side-by-side tables and figures: kind and file name."""
        return f"{self.model.kind} ({Path(self.path).name})"

    @property
    def band(self) -> BandCoverage | None:
        """The one-sigma band's coverage over every recording together; None: no band."""
        parts = [s.band for s in self.scores if s.band is not None]
        return sum(parts[1:], parts[0]) if parts else None

    def band_json(self) -> BandCoverageOrWhyJson:
        """``band_coverage`` (overall: percent inside +-1 sigma, mean sigma, samples) or None,
        and ``band_unavailable``: why there is none (None: there is one)."""
        from ..core.uncertainty import band_of

        band = self.band
        return {"band_coverage": band.as_dict() if band else None,
                "band_unavailable": None if band else band_of(self.model)[1]}

    def as_dict(self) -> EvaluationJson:
        out: EvaluationJson = {"model": self.path, "kind": self.model.kind, "rmse_rad_s": self.rmse_rad_s,
                               "thrust_coefficient": self.model.thrust_coefficient, **self.band_json(),
                               "recordings": [s.as_dict() for s in self.scores]}
        if self.health is not None:
            out["health"] = self.health[0]
        return out

    def health_lines(self) -> list[str]:
        """--health: the monitor's timeline per recording, as the health command prints it."""
        if self.health is None:
            return []
        return [f"  health monitor ({self.label}):", *("    " + line for line in self.health[1])]

    def lines(self) -> list[str]:
        band = self.band
        out = [f"model {self.path} ({self.model.kind}): overall RMSE {self.rmse_rad_s:.2f} rad/s"
               + ("; thrust unavailable: the model has no thrust coefficient"
                  if self.model.thrust_coefficient is None else "")
               + (f"; {_coverage(band)}" if band else "; no uncertainty band")]
        for s in self.scores:
            out.append(
                f"  {s.path}: RMSE {s.rmse_rad_s:.2f} rad/s ({s.rmse_percent_of_range:.2f} % of the "
                f"{s.speed_range_rad_s:.0f} rad/s range), max error {s.max_error_rad_s:.1f} rad/s"
                + (f"; thrust RMSE {s.thrust_rmse_n:.3f} N" if s.thrust_rmse_n is not None else "")
                + (f"; {_coverage(s.band)}" if s.band else "")
            )
            for b in s.bands:
                out.append(
                    f"      command {_band(b)} Hz: RMSE {b['rmse_rad_s']:.2f} rad/s "
                    f"({b['rmse_percent_of_range']:.2f} %)"
                )
        return out


def _band(b: dict[str, float]) -> str:
    return f"{b['low_hz']:.1f}-{b['high_hz']:.1f}"


def _coverage(band: BandCoverage) -> str:
    """The one-sigma band's coverage, as the text says it."""
    return f"{band.percent:.1f} % inside the +-1 sigma band (mean sigma {band.mean_sigma_rad_s:.2f} rad/s)"


def _check_distinct(paths: list[str]) -> None:
    seen: set[str] = set()
    for p in paths:
        if os.path.realpath(p) in seen:
            raise BadInputError(f"--model {p}: given twice")
        seen.add(os.path.realpath(p))


def run(args: argparse.Namespace) -> CommandResult:
    from ..model import load_model
    from ..recordings import gap_warnings, load_signals
    from ..training.evaluate import evaluate

    check_outputs([(args.report, REPORT, "--report")], force=args.force,
                  inputs=[*args.model, *args.recordings])
    _check_distinct(args.model)
    models = [load_model(p) for p in args.model]
    if args.health:
        _check_health_models(args.model, models)
    signals = [load_signals(p, namespace=args.namespace) for p in args.recordings]
    evals = [Evaluation(str(p), m, *evaluate(m, signals)) for p, m in zip(args.model, models, strict=True)]
    if args.health:
        _monitor(evals, signals)
    first = evals[0]  # the contract's keys: the first (or only) model's figures
    data: EvaluateJson = {"model": first.path, "rmse_rad_s": first.rmse_rad_s,
                            "thrust_coefficient": first.model.thrust_coefficient, **first.band_json(),
                            "recordings": [s.as_dict() for s in first.scores]}
    if args.health:
        data["health"] = first.health[0] if first.health is not None else None
    lines = [line for e in evals for line in (*e.lines(), *e.health_lines())]
    rows = comparison(evals) if len(evals) > 1 else []
    if rows:
        data["models"] = [e.as_dict() for e in evals]
        data["comparison"] = rows
        lines += comparison_lines(evals, rows)
    if args.report:
        data["report"] = write_evaluation_report(Path(args.report), signals, evals, rows, force=args.force)
        lines.append(f"  figures in {data['report']}")
    warnings = gap_warnings(signals) + [(f"{e.path}: " if len(evals) > 1 else "") + w
                                        for e in evals for s in e.scores
                                        if s.out_of_range and (w := s.out_of_range.warning())]
    data["warnings"] = warnings
    return CommandResult(data, "\n".join(lines), warnings=warnings)


def _check_health_models(paths: list[str], models: list[Model]) -> None:
    """--health needs at least one model with physics; one line naming --model otherwise."""
    from ..core.health import physics_part

    if not any(physics_part(m) is not None for m in models):
        raise BadInputError(f"--health: --model {paths[0]} is a {models[0].kind} model: the health monitor needs a "
                            "physics or hybrid model (the faults' signatures come from its physics)")


def _monitor(evals: list[Evaluation], signals: list[Signals]) -> None:
    """--health: each physics or hybrid model's monitor over every recording (a network's: none,
    and its lines say why)."""
    from ..core.health import physics_part
    from .health import monitor_recordings

    for e in evals:
        if physics_part(e.model) is not None:
            e.health = monitor_recordings(e.model, signals)
        else:
            e.health = (None, [f"not run: a {e.model.kind} model has no physics to give the faults' signatures"])


def comparison(evals: list[Evaluation]) -> list[ComparisonRow]:
    """The side-by-side table: one row per recording (``part`` "whole") and per command band of
    a chirp recording, each model's RMSE (rad/s) and its % of the recording's speed range,
    keyed by the model's file. A band a model has too few samples in is None for it."""
    rows: list[ComparisonRow] = []
    for k, sig_score in enumerate(evals[0].scores):
        parts: dict[str, dict[str, tuple[float, float]]] = {"whole": {}}  # model -> (rmse, percent)
        for e in evals:
            s = e.scores[k]
            parts["whole"][e.path] = (s.rmse_rad_s, s.rmse_percent_of_range)
            for b in s.bands:
                parts.setdefault(f"command {_band(b)} Hz", {})[e.path] = (b["rmse_rad_s"], b["rmse_percent_of_range"])
        for part, by_model in parts.items():
            rows.append({
                "recording": sig_score.path, "part": part,
                "rmse_rad_s": {e.path: by_model.get(e.path, (None, None))[0] for e in evals},
                "rmse_percent_of_range": {e.path: by_model.get(e.path, (None, None))[1] for e in evals},
            })
    return rows


def _cell(rmse: float | None, percent: float | None) -> str:
    return "-" if rmse is None else f"{rmse:.2f} ({percent:.2f} %)"


def comparison_lines(evals: list[Evaluation], rows: list[ComparisonRow]) -> list[str]:
    """The side-by-side table as text: RMSE rad/s (% of the speed range) per model."""
    first = max(len(r["recording"]) if r["part"] == "whole" else len(r["part"]) + 2 for r in rows)
    width = max(18, *(len(e.label) + 2 for e in evals))
    out = ["side by side: RMSE rad/s (% of the recording's speed range)",
           f"  {'recording':{first}s}" + "".join(f"{e.label:>{width}s}" for e in evals)]
    for r in rows:
        name = r["recording"] if r["part"] == "whole" else "  " + r["part"]
        out.append(f"  {name:{first}s}" + "".join(
            f"{_cell(r['rmse_rad_s'][e.path], r['rmse_percent_of_range'][e.path]):>{width}s}" for e in evals))
    return out


# --- report ---------------------------------------------------------------------------------
def write_evaluation_report(path: Path, signals: list[Signals], evals: list[Evaluation],
                            rows: list[ComparisonRow], force: bool = False) -> str:
    """Figures and tables of an evaluation, written whole to ``path`` (atomic.report_output):
    one model's figures, or with several models the side-by-side table (``rows``, from
    ``comparison``) and one figure per recording with the measured speed and every model's
    prediction."""
    with report_output(path, force=force) as d:
        if len(evals) == 1:
            _evaluation_report(d, signals, evals[0].predictions, evals[0].scores,
                               evals[0].model.thrust_coefficient, evals[0].rmse_rad_s)
        else:
            _comparison_report(d, signals, evals, rows)
    return str(path)


def _comparison_report(d: Path, signals: list[Signals], evals: list[Evaluation],
                       rows: list[ComparisonRow]) -> None:
    from ..training import report

    figs: list[tuple[str, str]] = []
    for k, sig in enumerate(signals):
        name = f"compare_{k}.png"
        report.fig_compare(sig.t, sig.pwm, sig.speed, [(e.label, e.predictions[k]) for e in evals], d / name,
                           recording=sig.path)
        figs.append((name, f"measured speed and every model's prediction: {sig.path}"))
    side = [{"recording": r["recording"], "part": r["part"]}
            | {f"{e.label} RMSE (rad/s)": r["rmse_rad_s"][e.path] for e in evals}
            | {f"{e.label} % of range": r["rmse_percent_of_range"][e.path] for e in evals}
            for r in rows]
    per_model = [{"model": e.path, "kind": e.model.kind} | score_row(s) for e in evals for s in e.scores]
    headline = []
    for e in evals:
        thrust = [f"{s.path} {s.thrust_rmse_n:.3f} N" for s in e.scores if s.thrust_rmse_n is not None]
        headline.append((e.label, f"speed RMSE {e.rmse_rad_s:.2f} rad/s overall; in % of the range: "
                         + ", ".join(f"{s.path} {s.rmse_percent_of_range:.2f}" for s in e.scores)
                         + (f"; thrust RMSE: {', '.join(thrust)}" if thrust else "; no thrust")))
    report.write_index(d, "bldc_propulsion evaluation report: models side by side", figs,
                       [("side by side: RMSE per recording and per command frequency band", side),
                        ("per model and recording", per_model)],
                       headline=headline)


def score_row(s: RecordingScore) -> dict[str, object]:
    """One recording's figures as a report table's row, with headers a reader understands
    (the --json keys say the same with units in their names)."""
    return {"recording": s.path, "RMSE (rad/s)": s.rmse_rad_s, "% of speed range": s.rmse_percent_of_range,
            "max error (rad/s)": s.max_error_rad_s, "speed range (rad/s)": s.speed_range_rad_s,
            "samples": s.samples, "thrust RMSE (N)": s.thrust_rmse_n,
            "thrust % of range": s.thrust_rmse_percent_of_range, "thrust range (N)": s.thrust_range_n,
            "no thrust because": s.thrust_unavailable,
            "inside +-1 sigma %": s.band.percent if s.band else None,
            "mean sigma (rad/s)": s.band.mean_sigma_rad_s if s.band else None,
            "outside training range %": 100 * s.out_of_range.fraction if s.out_of_range else None}


def _evaluation_report(d: Path, signals: list[Signals], preds: list[np.ndarray], scores: list[RecordingScore],
                       coefficient: float | None = None, overall_rmse_rad_s: float | None = None) -> None:
    """One model's report: per recording the paper's Fig. 13, a scatter, the thrust against the
    load cell where both a measured thrust and the model's b exist, the error per band of a
    chirp; the headline states each recording's speed and thrust error as the summary does."""
    from ..training import report

    figs: list[tuple[str, str]] = []
    headline: list[tuple[str, str]] = []
    if overall_rmse_rad_s is not None:
        headline.append(("overall speed RMSE", f"{overall_rmse_rad_s:.2f} rad/s"))
    for k, (sig, pred, s) in enumerate(zip(signals, preds, scores, strict=True)):
        name = f"fig13_{k}.png"
        report.fig_validation(sig.t, sig.pwm, sig.voltage, sig.speed, pred, d / name, title=sig.path)
        figs.append((name, f"Fig. 13: PWM, voltage, measured and predicted speed and their error: {sig.path}"))
        headline.append((f"speed, {sig.path}", f"RMSE {s.rmse_rad_s:.2f} rad/s ({s.rmse_percent_of_range:.2f} % of "
                                               f"the {s.speed_range_rad_s:.0f} rad/s range), max error "
                                               f"{s.max_error_rad_s:.1f} rad/s"))
        if sig.thrust is not None and coefficient is not None:
            name = f"thrust_{k}.png"
            predicted = coefficient * pred**2
            report.fig_thrust(sig.t, sig.thrust, predicted, d / name, recording=sig.path, coefficient=coefficient)
            figs.append((name, f"measured vs predicted thrust (b·ω²) and the thrust error: {sig.path}"))
            headline.append((f"thrust, {sig.path}", report.thrust_error_text(sig.thrust, predicted)))
        else:
            headline.append((f"thrust, {sig.path}", f"no figure: {s.thrust_unavailable}"))
        name = f"scatter_{k}.png"
        report.fig_prediction_scatter(sig.speed, pred, d / name, recording=sig.path)
        figs.append((name, f"predicted vs measured: {sig.path}"))
    bands = []
    for k, s in enumerate(scores):
        if s.bands:
            name = f"band_error_{k}.png"
            report.fig_band_error(s.bands, d / name, recording=s.path)
            figs.append((name, f"speed error per command frequency band: {s.path}"))
            bands += [{"recording": s.path, "band (Hz)": _band(b),
                       "samples": b["samples"], "RMSE (rad/s)": b["rmse_rad_s"],
                       "% of speed range": b["rmse_percent_of_range"]} for b in s.bands]
    rows = [score_row(s) for s in scores]
    tables = [("per recording", rows)] + ([("error per command frequency band", bands)] if bands else [])
    report.write_index(d, "bldc_propulsion evaluation report", figs, tables, headline=headline)
