"""Held-out evidence decides: an effect is added only if it improves data it was not fitted on.

Step 3 proposes an effect from scores on held-out time blocks; step 4 fits it (network retrained,
physics strength fitted). Whether the fitted effect is KEPT is decided here, on data the fit did
not see, cut into time blocks: the --holdout recordings when given, else held-out data of the measured
recordings (the network's early-stopping tail, never trained on; the physics path's per-fold
refits of step 3). A margin (ACCEPT_MIN_REDUCTION of the held-out mean squared error) and a
significance level (one-sided sign-flip test over the blocks' reductions of their root squared
error) are both required, so a model that moves the holdout 26.33 -> 26.28 rad/s keeps the
effect out and says so ("considered, not added").

The level: on a --holdout, HOLDOUT_ALPHA (0.05). The candidate reaching step 5 has already been
found significant at the workflow's alpha (0.01) on the measured data, so the holdout is a
replication on independent recordings, and the usual discovery/replication design applies: a
false name needs both tests to pass by chance (<= 5 candidates x 0.01 x 0.05 = 0.0025 per
round). At 0.01 the replication would be the weaker link: a dynamic effect changes only the
blocks holding a command step (about a third of a 30 s holdout), and the retrained network moves
the settled ones within the noise either way, so a fit that halves the holdout's mean squared
error gets p = 0.02-0.05 on the randomized benches (network path: dead time and coasting; physics
path: a 13 ms dead time, weak heating). Without a holdout the acceptance figure is the step-3 test itself
or data the fit saw for early stopping, not a replication: the workflow's alpha.

Also here: the refusal of a --holdout that overlaps --measured or --reference (same file or the
same messages), which would make the before/after figure an in-sample one.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, TypedDict

import numpy as np

from ..errors import BadInputError
from ..recordings import Signals
from . import scoring as sc

if TYPE_CHECKING:
    from .physics import FittedValue

#: Least fractional reduction of the held-out mean squared error for an effect to be added. 5 %: ~2.5 % of
#: the RMSE, well above the run-to-run scatter of a retrained network (~0.2 % on the README case) and far
#: below what a real missing effect gives.
ACCEPT_MIN_REDUCTION = 0.05

#: Significance level of the replication on a --holdout (module docstring: why not the workflow's alpha).
HOLDOUT_ALPHA = 0.05


def content_fingerprint(s: Signals) -> str:
    """sha256 of a recording's messages as read (command, voltage and speed samples): equal for a
    renamed or copied bag, whatever its file names."""
    h = hashlib.sha256()
    for a in (*s.pwm_events, *s.voltage_events, s.speed):
        h.update(np.ascontiguousarray(a, dtype=np.float64).tobytes())
    return h.hexdigest()


def check_holdout_disjoint(holdout: Sequence[Signals], **others: Sequence[Signals]) -> None:
    """BadInputError (one line) when a holdout recording is also one of ``others`` (by option
    name, e.g. measured=..., reference=...): same path, same files or same messages."""
    for opt, sigs in others.items():
        seen: dict[object, str] = {}
        for s in sigs:
            seen[str(Path(s.path).resolve())] = s.path
            seen[s.key] = s.path  # the same files and motor (another motor of a flight is other data)
            seen[content_fingerprint(s)] = s.path
        for h in holdout:
            for key, how in ((str(Path(h.path).resolve()), "the same file"), (h.key, "the same files"),
                             (content_fingerprint(h), "the same messages")):
                if key in seen:
                    raise BadInputError(f"--holdout {h.path}: {how} as --{opt} {seen[key]}; the holdout must "
                                        f"be recordings the model is not fitted on")


class AcceptanceJson(TypedDict):
    """``Acceptance.as_json``: the held-out figure as --json, the summary and the report carry it."""

    source: str
    test: str
    rmse_before_rad_s: float
    rmse_after_rad_s: float
    mse_reduction: float
    mse_reduction_pct: float
    p_value: float
    blocks: int
    blocks_improved: int
    min_mse_reduction: float
    alpha: float
    at_bound: str | None
    contradicted: str | None
    accepted: bool


class DecidedBy(TypedDict):
    """``decided_by``: the test that decided a candidate, and its figure."""

    test: str
    source: str
    reduction_pct: float
    p_value: float


class _EvidenceCore(TypedDict):
    verdict: str
    measured: sc.ScoreJson
    measured_alone: sc.ScoreJson
    reference: sc.ScoreJson | None
    p_value: float
    feature: str
    sentence: str


class EvidenceJson(_EvidenceCore, total=False):
    """``results.Evidence.as_json``: one candidate's --json ``evidence`` entry (defined here, where
    it is judged; results imports this module). The optional keys are there once known."""

    verdict_residual: str
    heating: dict[str, float | None]
    dynamics: dict[str, object]
    fitted_parameters: dict[str, float]
    fitted_value: FittedValue
    acceptance: AcceptanceJson
    named: bool
    added_as: str | None
    status: str
    label: str
    decided_by: DecidedBy


class Considered(TypedDict):
    """``considered``: a candidate scored and not added, with its figures and why not."""

    effect: str
    verdict: str
    status: str
    why: str
    decided_by: DecidedBy
    measured_mse_reduction: float | None
    p_value: float | None
    reference_mse_reduction: float | None
    acceptance: AcceptanceJson | None


@dataclass(frozen=True)
class Acceptance:
    """The held-out figure that keeps (or rejects) one fitted effect."""

    effect: str
    source: str  #: what the figure was computed on
    rmse_before: float  #: rad/s, without the effect
    rmse_after: float  #: rad/s, with it
    mse_reduction: float  #: 1 - MSE_after / MSE_before over the held-out data
    p_value: float  #: one-sided sign-flip test over the blocks
    blocks: int
    blocks_improved: int
    margin: float
    alpha: float
    #: a fitted parameter that ended at a bound of its range (in words): not a basis for a verdict
    at_bound: str | None = None
    #: the identification on measured vs reference contradicts it (in words): not added
    contradicted: str | None = None

    @property
    def accepted(self) -> bool:
        return (self.p_value < self.alpha and self.mse_reduction >= self.margin
                and not self.rmse_after > self.rmse_before and self.at_bound is None
                and self.contradicted is None)

    @property
    def test(self) -> str:
        """Which data decided: 'holdout' (the --holdout recordings) or 'measured' (held-out data
        of the measured recordings)."""
        return "holdout" if self.source.startswith("holdout") else "measured"

    def describe(self) -> str:
        verdict = "added" if self.accepted else (
            f"not added ({self.at_bound}: not a basis for a verdict)" if self.at_bound else
            f"not added ({self.contradicted})" if self.contradicted else
            f"not added (needs >= {100 * self.margin:.0f} % and p < {self.alpha:g})")
        return (f"{self.source}: RMSE {self.rmse_before:.2f} -> {self.rmse_after:.2f} rad/s, "
                f"{100 * self.mse_reduction:.1f} % of the mean squared error, {self.blocks_improved} of "
                f"{self.blocks} blocks better, p = {self.p_value:.2g}: {verdict}")

    def as_json(self) -> AcceptanceJson:
        return {"source": self.source, "test": self.test, "rmse_before_rad_s": self.rmse_before,
                "rmse_after_rad_s": self.rmse_after, "mse_reduction": self.mse_reduction,
                "mse_reduction_pct": 100.0 * self.mse_reduction, "p_value": self.p_value, "blocks": self.blocks,
                "blocks_improved": self.blocks_improved, "min_mse_reduction": self.margin, "alpha": self.alpha,
                "at_bound": self.at_bound, "contradicted": self.contradicted, "accepted": self.accepted}


def judge(effect: str, signals: Sequence[Signals], before: Sequence[np.ndarray], after: Sequence[np.ndarray],
          source: str, alpha: float, margin: float = ACCEPT_MIN_REDUCTION) -> Acceptance:
    """Before/after predictions on held-out recordings, compared block by block.

    Blocks as scoring.make_blocks cuts them (BadInputError when too short)."""
    blocks = sc.make_blocks([s.duration_s for s in signals], source)
    labels = sc.block_labels([len(s.t) for s in signals], blocks)
    y = np.concatenate([s.speed for s in signals])
    rb = y - np.concatenate(before)
    ra = y - np.concatenate(after)
    ok = (labels >= 0) & np.isfinite(rb) & np.isfinite(ra)
    K = int(sum(blocks))
    sse_b = np.bincount(labels[ok], rb[ok] ** 2, minlength=K)
    sse_a = np.bincount(labels[ok], ra[ok] ** 2, minlength=K)
    n = np.bincount(labels[ok], minlength=K)
    used = n > 0
    # per block, the reduction of the root of its squared error (its RMS error x sqrt(samples)):
    # the squared-error differences themselves are dominated by the few blocks holding a large
    # transient (README case, 31.97 -> 26.33 rad/s with 19 of 24 blocks better: p = 0.09), their
    # log ratios by the many settled blocks where both models are within the sensor noise
    # (rotor_lag, 55.6 -> 38.6 rad/s with 21 of 29 better: p = 0.16); the roots: 7e-4 and 4e-4
    d = np.sqrt(sse_b[used]) - np.sqrt(sse_a[used])
    total_b, total_a, tot = float(sse_b[used].sum()), float(sse_a[used].sum()), float(n[used].sum())
    return Acceptance(
        effect, source,
        rmse_before=math.sqrt(total_b / tot) if tot else float("nan"),
        rmse_after=math.sqrt(total_a / tot) if tot else float("nan"),
        mse_reduction=1.0 - total_a / total_b if total_b > 0 else 0.0,
        p_value=sc.sign_flip_p(d), blocks=int(used.sum()), blocks_improved=int(np.sum(d > 0)),
        margin=margin, alpha=alpha)


def from_score(effect: str, score: sc.Score, source: str, alpha: float,
               margin: float = ACCEPT_MIN_REDUCTION) -> Acceptance:
    """The acceptance figure of a step-3 held-out block score (no holdout: its per-fold refits are
    the held-out evidence)."""
    return Acceptance(effect, source, score.rmse_null, score.rmse_candidate, score.fraction, score.p_value,
                      score.blocks, score.blocks_improved, margin, alpha)


#: The three things a candidate can end as (console, --json ``status``, the report).
ADDED, STRUCTURAL, NOT_ADDED = "added", "structural", "considered, not added"
#: What an added effect is, in words.
ADDED_LABELS = {"new": "added (new in the measured data)",
                "structural": "added (structural: the model lacks it on its own training data too)"}


def decided_by(ev: EvidenceJson) -> DecidedBy:
    """The test that decided a candidate (its ``evidence`` entry): the held-out acceptance test
    when it was fitted, else the measured data's step-3 score (it was not proposed)."""
    a = ev.get("acceptance")
    if a is not None:
        return {"test": a["test"], "source": a["source"], "reduction_pct": 100.0 * a["mse_reduction"],
                "p_value": a["p_value"]}
    m = ev["measured"]
    return {"test": "measured", "source": "held-out time blocks of the measured data (step 3: not proposed)",
            "reduction_pct": 100.0 * m["mse_reduction"], "p_value": m["p_value"]}


def status(ev: EvidenceJson) -> tuple[str, str]:
    """(status, label): ADDED with its ADDED_LABELS, STRUCTURAL (present on the reference too, not
    added) or NOT_ADDED."""
    if ev.get("named"):
        return ADDED, ADDED_LABELS[ev.get("added_as") or "new"]
    if ev["verdict"] == "structural":
        return STRUCTURAL, "structural (the model lacks it on its own training data too), not added"
    return NOT_ADDED, NOT_ADDED


def considered(evidence: Mapping[str, EvidenceJson], named: Sequence[str]) -> list[Considered]:
    """Every candidate that was scored and not added, with its figures and why not."""
    out: list[Considered] = []
    for name, ev in evidence.items():
        if name in named or ev.get("named"):
            continue
        m = ev.get("measured") or {}
        ref: sc.ScoreJson | dict[str, float] = ev.get("reference") or {}  # {}: no reference data
        acc = ev.get("acceptance")
        if acc is not None and acc.get("at_bound"):
            why = f"fitted, but {acc['at_bound']}: not a basis for a verdict"
        elif acc is not None and acc.get("contradicted"):
            why = f"fitted, but {acc['contradicted']}"
        elif acc is not None and not acc["accepted"]:
            why = f"fitted, but it did not improve the {acc['test']} data enough"
        elif acc is not None:
            why = "fitted and passed, but another was added first"
        elif ev["verdict"].startswith("not new"):
            why = ev["verdict"]
        else:
            why = "not proposed (the loop stopped first, or too small a share on the measured data)"
        st, _ = status(ev)
        out.append({"effect": name, "verdict": ev["verdict"], "status": st, "why": why,
                    "decided_by": decided_by(ev),
                    "measured_mse_reduction": m.get("mse_reduction"), "p_value": m.get("p_value"),
                    "reference_mse_reduction": ref.get("mse_reduction"),
                    "acceptance": acc})
    return out


def decided_text(d: DecidedBy) -> str:
    """The deciding test's figure, one way everywhere: '<test> test: 23.3 %, p = 5e-05'."""
    return f"{d['test']} test: {d['reduction_pct']:.1f} %, p = {d['p_value']:.2g}"


def considered_lines(items: Sequence[Considered]) -> list[str]:
    """The console lines of ``considered``."""
    lines = []
    for x in items:
        ref = x["reference_mse_reduction"]
        fig = decided_text(x["decided_by"])
        if x["decided_by"]["test"] != "measured":
            measured = 100 * (x["measured_mse_reduction"] or 0.0)
            fig += f"; measured (proposal only): {measured:.1f} %, p = {x['p_value']:.2g}"
        fig += f"; reference {100 * ref:.1f} %" if ref is not None else ""
        acc = x["acceptance"]
        lines.append(f"{x['status']}: {x['effect']} ({x['why']}; {fig}"
                     + (f"; {acc['source']} RMSE {acc['rmse_before_rad_s']:.2f} -> {acc['rmse_after_rad_s']:.2f} "
                        f"rad/s" if acc else "") + ")")
    return lines
