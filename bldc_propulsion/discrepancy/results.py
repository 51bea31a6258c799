"""What the workflow found, as data: per-candidate evidence, the rounds, the result; and the two
ways it is shown to people (summary lines, the report's index.html). ``as_json()`` gives the
``--json`` object (keys: ../shared/interfaces.md and docs/architecture.md); the summary and the
report are written from that same object, so every figure is one number everywhere."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, TypedDict

import numpy as np

from ..atomic import report_output
from . import acceptance as acc
from . import residuals as rs
from . import scoring as sc
from .dataset import DataSet, rmse
from .physics import FittedValue, value_text

if TYPE_CHECKING:
    from ..model import RangeJson
    from ..physics.config import ConfigJson
    from ..physics.fit import FitFlagJson

#: An effect is new only if the share of the residual it removes on the reference is less than
#: this fraction of the share it removes on the measured data (else structural).
STRUCTURAL_RATIO = 0.5


def sentence(effect: str, feature: str, meas: sc.Score, ref: sc.Score | None, verdict: str, noun: str) -> str:
    """A candidate's step-3 finding in words (``noun``: the model as the kind names it)."""
    ref_txt = (f"{100 * max(ref.fraction, 0):.0f} % on the reference data (p = {ref.p_value:.2g}), "
               f"{max(ref.fraction, 0) / max(meas.fraction, 1e-12):.2g} times the share it removes on the measured data"
               if ref is not None else "the reference data were not available")
    core = (f"{effect}: {feature} removes {100 * meas.fraction:.0f} % of {noun}'s remaining residual on "
            f"held-out time blocks of the measured data ({meas.blocks_improved} of {meas.blocks} blocks "
            f"better, p = {meas.p_value:.2g})")
    if verdict == "new":
        return f"{core} but only {ref_txt}" if ref is not None else f"{core}; {ref_txt}"
    if verdict == "structural":
        return (f"{core} and {ref_txt}: {noun} lacks it on its own reference data too "
                f"(structural, not new in the measured data)")
    return f"{core}; on the measured data: {verdict} (that test proposes, the held-out one decides)"


@dataclass
class Evidence:
    """One candidate effect in one round: its scores, verdict, and (once fitted) its fit and the
    held-out figure that kept or rejected it."""

    effect: str
    verdict: str  #: new, structural, not significant, not new (identified: ... changed / dynamics unchanged / ...)
    measured: sc.Score
    measured_alone: sc.Score
    reference: sc.Score | None
    feature: str
    sentence: str
    noun: str = "the model"
    verdict_residual: str | None = None  #: the scores' verdict when the identification overrode it
    heating: dict[str, float | None] | None = None  #: identify.Heating.as_dict(), when identified
    dynamics: dict[str, object] | None = None  #: identify.Dynamics of both sets, when identified
    fitted_parameters: dict[str, float] | None = None
    fitted_value: FittedValue | None = None  #: physics: the fitted value in physical units
    acceptance: acc.Acceptance | None = None
    named: bool = False  #: added to the model (new or structural: ``added_as``)
    added_as: str | None = None  #: 'new' or 'structural' once added

    def proposed(self, min_effect: float) -> bool:
        """Whether step 4 fits it: new or structural on the measured data, or removing
        ``min_effect`` of their residual whatever its p (a large share that is not significant
        may still hold on the held-out data, which decide)."""
        return self.verdict in ("new", "structural") or self.measured.fraction >= min_effect

    def override(self, verdict: str, text: str) -> None:
        """The identification's verdict replaces the scores' (kept in ``verdict_residual``)."""
        self.verdict_residual, self.verdict, self.sentence = self.verdict, verdict, text

    def refit(self, parameters: dict[str, float], feature: str, value: FittedValue | None) -> None:
        """The effect's fitted parameters (step 4, or refitted in a later round): the feature and,
        unless the identification wrote it, the sentence say the same number."""
        self.fitted_parameters, self.fitted_value = parameters, value
        if self.verdict_residual is None:
            self.sentence = sentence(self.effect, feature, self.measured, self.reference,
                                     self.added_as or self.verdict, self.noun)
        self.feature = feature

    def as_json(self) -> acc.EvidenceJson:
        out: acc.EvidenceJson = {
            "verdict": self.verdict,
            "measured": self.measured.as_dict(),
            "measured_alone": self.measured_alone.as_dict(),
            "reference": self.reference.as_dict() if self.reference is not None else None,
            "p_value": self.measured.p_value,
            "feature": self.feature,
            "sentence": self.sentence,
        }
        # the optional keys, each once known (a TypedDict's keys are set by name)
        if self.verdict_residual is not None:
            out["verdict_residual"] = self.verdict_residual
        if self.heating is not None:
            out["heating"] = self.heating
        if self.dynamics is not None:
            out["dynamics"] = self.dynamics
        if self.fitted_parameters is not None:
            out["fitted_parameters"] = self.fitted_parameters
        if self.fitted_value is not None:
            out["fitted_value"] = self.fitted_value
        if self.acceptance is not None:
            out["acceptance"] = self.acceptance.as_json()
        if self.named:
            out["named"] = True
            out["added_as"] = self.added_as
        out["status"], out["label"] = acc.status(out)
        out["decided_by"] = acc.decided_by(out)
        return out


@dataclass
class Round:
    """One pass of steps 3-5: every candidate's evidence, and the one proposed."""

    evidence: dict[str, Evidence]
    proposed: str | None = None
    parameters: dict[str, float] | None = None
    holdout_rmse: float | None = None
    acceptance: acc.Acceptance | None = None
    named: str | None = None
    extra: dict[str, str] = field(default_factory=dict)  #: kind-specific (the network's added input)
    #: every candidate fitted this round, in the order tried (the last is ``proposed``)
    trials: list[dict[str, object]] = field(default_factory=list)

    def as_json(self) -> dict[str, object]:
        out: dict[str, object] = {"evidence": {k: v.as_json() for k, v in self.evidence.items()},
                                  "trials": list(self.trials)}
        if self.proposed is not None:
            out.update(proposed=self.proposed, **self.extra, parameters=self.parameters,
                       holdout_rmse_rad_s=self.holdout_rmse,
                       acceptance=self.acceptance.as_json() if self.acceptance else None)
        if self.named is not None:
            out["named"] = self.named
        return out


@dataclass
class Disagreement:
    """Step 2: where the model and the measured data disagree, and the residual tests."""

    threshold: float  #: rad/s: THRESHOLD_SIGMAS x the robust sigma of the reference residual
    windows: list[rs.Window]
    tests: rs.ResidualTests  #: residuals.residual_tests on the measured data
    tests_ref: rs.ResidualTests | None  #: the same on the reference data, or None
    conditions: dict[str, list[dict[str, float | str]]]  #: residuals.condition_bins on the measured data (the map)


class StructuralJson(TypedDict):
    """An effect found structural on the measured data (step 3), as --json ``structural`` lists it."""

    effect: str
    sentence: str
    measured_mse_reduction: float
    reference_mse_reduction: float | None


class GapJson(TypedDict):
    """``gap_fields``: step 5's figures (rad/s)."""

    holdout_rmse_before: float
    holdout_rmse_after: float
    holdout_rmse_in_windows_before: float | None
    holdout_rmse_in_windows_after: float | None


class DecisionJson(TypedDict):
    """The deciding rule's levels, as --json ``decision`` states them."""

    alpha: float
    holdout_alpha: float | None
    min_mse_reduction: float
    structural_ratio: float
    test: str


class ResidualTestsPair(TypedDict):
    """The residual tests on the measured data and on the reference (None without one)."""

    measured: rs.ResidualTestsJson
    reference: rs.ResidualTestsJson | None


class _ReferenceFitCore(TypedDict):
    constants: dict[str, float]
    strengths: dict[str, float]
    in_base: dict[str, str]  #: base effect -> its fitted value in words
    rmse_rad_s: float
    at_bound: list[str]
    implausible: list[str]


class ReferenceFitJson(_ReferenceFitCore, total=False):
    """The physics kind's fit on the reference recordings (--json ``reference_fit``)."""

    speed_noise_rad_s: float  #: once the reference is judged explained or not
    #: effects the CONFIG left off that the base was completed with: all of them when the base did
    #: not explain the reference (``PhysicsKind._complete_base``), else those the reference alone
    #: shows, in the order they were added (``PhysicsKind._shown_by_reference``)
    completed: list[str]


class KindFields(TypedDict, total=False):
    """A model kind's own --json fields (``ModelKind.finish``): the network's, or the physics'."""

    added_inputs: list[str]  #: network
    holdout_rmse_uncalibrated: float  #: physics, and below
    reference_fit: ReferenceFitJson | None
    calibrated_base: ConfigJson
    physics: ConfigJson
    fit_flags: list[FitFlagJson]


class _ResultCore(TypedDict):
    named: list[str]
    added: list[str]
    added_structural: list[str]
    no_verdict: str | None
    structural: list[StructuralJson]
    considered_not_added: list[acc.Considered]
    verdicts: dict[str, dict[str, object]]
    holdout_in_sample: bool
    holdout_recordings: list[str]
    windows: list[rs.WindowJson]
    holdout_windows: list[rs.WindowJson]
    window_threshold_rad_s: float
    residual_tests: ResidualTestsPair
    conditions: dict[str, list[dict[str, float | str]]]
    reference_recordings: list[str]
    measured_recordings: list[str]
    decision: DecisionJson
    evidence: dict[str, acc.EvidenceJson]
    iterations: list[dict[str, object]]
    model: str | None  #: where -o saved the model, once saved


class ResultJson(_ResultCore, GapJson, KindFields, total=False):
    """``Result.as_json``: the --json object of ``discrepancy`` (the summary and the report are
    written from it); the command adds the keys below."""

    warnings: list[str]
    report: str
    out_of_training_range: dict[str, RangeJson]


@dataclass
class Result:
    """Everything one discrepancy run found (``as_json``: the --json object)."""

    named: list[str]
    structural: list[StructuralJson]
    evidence: dict[str, Evidence]
    rounds: list[Round]
    gap: GapJson  #: holdout RMSE before/after, overall and in its windows
    found: Disagreement
    hold_windows: list[rs.Window]
    recordings: dict[str, list[str]]  #: reference, measured, holdout paths
    holdout_in_sample: bool
    decision: DecisionJson
    warnings: list[str]
    kind_fields: KindFields = field(default_factory=lambda: KindFields())
    #: why nothing was scored or named (the reference is not explained), None when the loop ran
    no_verdict: str | None = None
    #: every effect added, in order: ``named`` (new in the measured data) and structural ones
    added: list[str] = field(default_factory=list)

    def as_json(self) -> ResultJson:
        evidence = {k: v.as_json() for k, v in self.evidence.items()}
        found = self.found
        added = list(self.added or self.named)
        return {
            "named": list(self.named),
            "added": added,
            "added_structural": [k for k in added if k not in self.named],
            "no_verdict": self.no_verdict,
            "structural": [x for x in self.structural if x["effect"] not in added],
            "considered_not_added": acc.considered(evidence, added),
            "verdicts": {k: {"status": v["status"], "label": v["label"], **v["decided_by"]}
                         for k, v in evidence.items()},
            **self.gap,
            "holdout_in_sample": self.holdout_in_sample,
            "holdout_recordings": self.recordings["holdout"],
            "windows": [w.as_dict() for w in found.windows],
            "holdout_windows": [w.as_dict() for w in self.hold_windows],
            "window_threshold_rad_s": found.threshold,
            "residual_tests": {"measured": found.tests.as_dict(),
                               "reference": found.tests_ref.as_dict() if found.tests_ref else None},
            "conditions": found.conditions,
            "reference_recordings": self.recordings["reference"],
            "measured_recordings": self.recordings["measured"],
            "decision": self.decision,
            "evidence": evidence,
            "iterations": [r.as_json() for r in self.rounds],
            **self.kind_fields,
            "warnings": list(self.warnings),
            "model": None,
        }


def gap_fields(hold_base: DataSet, hold_final: DataSet, hold_masks: Sequence[np.ndarray]) -> GapJson:
    """Step 5's figures: holdout RMSE before and after, overall and inside the holdout's windows."""
    any_win = any(m.any() for m in hold_masks)
    return {
        "holdout_rmse_before": rmse(hold_base.residuals),
        "holdout_rmse_after": rmse(hold_final.residuals),
        "holdout_rmse_in_windows_before": rmse(hold_base.residuals, hold_masks) if any_win else None,
        "holdout_rmse_in_windows_after": rmse(hold_final.residuals, hold_masks) if any_win else None,
    }


# --- for people --------------------------------------------------------------------------------------
def kept_text(kept: acc.AcceptanceJson) -> str:
    """The held-out figure that kept an effect, with the margin and significance it had to meet."""
    return (f"on {kept['source']}: RMSE {kept['rmse_before_rad_s']:.2f} -> {kept['rmse_after_rad_s']:.2f} rad/s, "
            f"{100 * kept['mse_reduction']:.1f} % of the mean squared error ({kept['blocks_improved']} of "
            f"{kept['blocks']} blocks better, p = {kept['p_value']:.2g}; needed >= "
            f"{100 * kept['min_mse_reduction']:.0f} % and p < {kept['alpha']:g})")


def summary_lines(data: ResultJson) -> list[str]:
    """The summary for people: new effects, then structural ones, each added or not with the
    figure of the test that decided (the same statuses and % as --json and the report)."""
    lines = []
    added = data.get("added", data["named"])
    structural_added = [k for k in added if k not in data["named"]]
    if data["named"]:
        lines.append("new effect(s) found in the measured data, added: " + ", ".join(data["named"]))
    if structural_added:
        lines.append("structural effect(s) added (the model lacks them on its own training data too): "
                     + ", ".join(structural_added))
    for name in added:
        ev = data["evidence"][name]
        lines.append(f"{ev['label']}: {name}")
        lines.append("  " + ev["sentence"])
        if ev.get("fitted_value"):
            lines.append(f"    fitted: {value_text(ev['fitted_value'])} (strength "
                         f"{ev['fitted_value']['strength']:.3g})")
        if ev.get("acceptance"):
            lines.append(f"    decided by the {ev['acceptance']['test']} test: " + kept_text(ev["acceptance"]))
    if not added:
        if data.get("no_verdict"):
            lines.append(f"no effect is named: {data['no_verdict']}")
        elif data["structural"]:
            lines.append("nothing added: nothing new in the measured data, and what the model lacks on its own "
                         "reference data too did not pass the deciding test (below)")
        else:
            lines.append("nothing added: no effect improves data it was not fitted on")
    items = data.get("considered_not_added", [])
    lines += acc.considered_lines([x for x in items if x["status"] == acc.STRUCTURAL])
    lines += acc.considered_lines([x for x in items if x["status"] != acc.STRUCTURAL])
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
                 hold_windows: Sequence[rs.Window], data: ResultJson, force: bool = False) -> str:
    """Disagreement map and before/after figures (training/report.py) and an index.html,
    written whole to ``final`` (atomic.report_output)."""
    with report_output(final, force=force) as d:
        _write_report(d, meas, hold_base, hold_final, hold_windows, data)
    return str(final)


def _write_report(d: Path, meas: DataSet, hold_base: DataSet, hold_final: DataSet,
                  hold_windows: Sequence[rs.Window], data: ResultJson) -> None:
    from ..training import report as rp

    figs = []
    pwm = np.concatenate([s.pwm for s in meas.signals])
    rate = np.concatenate([rs.pwm_rate(s.t, s.pwm) for s in meas.signals])
    volt = np.concatenate([s.voltage for s in meas.signals])
    res = np.concatenate(meas.residuals)
    rp.fig_disagreement_map(pwm, rate, res, d / "disagreement_map.png", voltage=volt)
    figs.append(("disagreement_map.png", "mean residual (measured - model) per PWM level and rate, "
                 "and vs battery voltage, on the measured recordings"))
    for k, (s, pb, pa) in enumerate(zip(hold_base.signals, hold_base.predictions, hold_final.predictions, strict=True)):
        name = f"before_after_{k}.png"
        spans = [(w.t_start_s, w.t_end_s) for w in hold_windows if w.path == s.path]
        rp.fig_before_after(s.t, s.speed, pb, pa, d / name, windows=spans, recording=s.path)
        figs.append((name, f"{s.path}: model before and after adding "
                           f"{', '.join(data.get('added', data['named'])) or 'nothing'}"))

    def pct(x: float | None) -> str:
        return "" if x is None else f"{100 * x:.1f} %"

    # one row per candidate: what it ended as and the test that decided, then the measured data's
    # proposal and the reference's share (in % like the console)
    rows = [{"effect": k, "status": v["label"], "decided by": v["decided_by"]["test"],
             "reduction (deciding test)": f"{v['decided_by']['reduction_pct']:.1f} %",
             "p (deciding test)": f"{v['decided_by']['p_value']:.2g}",
             "measured: reduction": pct(v["measured"]["mse_reduction"]),
             "measured: p": f"{v['measured']['p_value']:.2g}",
             "reference: reduction": pct(None if v["reference"] is None else v["reference"]["mse_reduction"]),
             "reference: p": "" if v["reference"] is None else f"{v['reference']['p_value']:.2g}",
             "feature": v["feature"]}
            for k, v in data["evidence"].items()]
    gap = [{"holdout RMSE before": data["holdout_rmse_before"], "after": data["holdout_rmse_after"],
            "in windows before": data["holdout_rmse_in_windows_before"],
            "in windows after": data["holdout_rmse_in_windows_after"]}]
    # a named effect's fitted value and held-out figure as the summary states them (the same text)
    added = []
    for name in data.get("added", data["named"]):
        ev = data["evidence"][name]
        row: dict[str, object] = {"effect": name, "status": ev["label"], "feature": ev["feature"]}
        if ev.get("fitted_value"):
            row["fitted value"] = value_text(ev["fitted_value"])
            row["strength"] = f"{ev['fitted_value']['strength']:.3g}"
        if ev.get("acceptance"):
            row[f"decided by the {ev['acceptance']['test']} test"] = kept_text(ev["acceptance"])
        added.append(row)
    skipped = [{"effect": x["effect"], "status": x["status"], "why": x["why"], "decided by": x["decided_by"]["test"],
                "reduction (deciding test)": f"{x['decided_by']['reduction_pct']:.1f} %",
                "p (deciding test)": f"{x['decided_by']['p_value']:.2g}",
                "measured: reduction (proposal only)": pct(x["measured_mse_reduction"]),
                "reference: reduction": pct(x["reference_mse_reduction"])}
               for x in data.get("considered_not_added", [])]
    tables: list[tuple[str, Sequence[Mapping[str, object]]]] = [
        ("candidate effects: what each ended as, and the test that decided", rows),
        ("added: the test that decided each", added),
        ("not added (structural, or considered, not added)", skipped), ("the gap", gap)]
    flags = data.get("fit_flags") or []
    if flags:
        tables.append(("fit flags: a fitted quantity at a bound of its range, or implausibly far from the CONFIG",
                       [{"fit": f["fit"], "quantity": f["quantity"], "fitted": f"{f['value']:.4g}",
                         "CONFIG": f"{f['config']:.4g}" + ("" if f["config_given"] else " (nominal, no CONFIG given)"),
                         "why": f["why"], "not a basis for a verdict": f["not_a_basis_for_a_verdict"]}
                        for f in flags]))
    if data.get("warnings"):
        tables.append(("warnings", [{"warning": w} for w in data["warnings"]]))
    new = ", ".join(data["named"])
    structural = ", ".join(k for k in data.get("added", []) if k not in data["named"])
    parts = [*([f"new: {new}"] if new else []), *([f"structural, added: {structural}"] if structural else [])]
    title = "; ".join(parts)
    rp.write_index(d, "discrepancy: " + (title or "nothing added"), figs, tables)
