"""What the one loop (``workflow.py``) and the model kinds (``network.py``, ``physics_kind.py``)
share: the options, a data set with its residual, and the protocol a model kind implements.

A model kind is asked, in this order: ``start`` (step 1: the model on the measured, reference
and holdout recordings, calibrated where it calibrates), ``candidates`` and ``score`` (step 3:
each effect it can add, scored on held-out time blocks), ``add`` (step 4: the effect fitted
into a trial model), ``heldout`` (step 5 without a --holdout: the kind's own held-out evidence),
``keep`` (the trial becomes the model), ``finish`` (its own result fields and summary lines).
Between scoring and adding, ``identify`` refines the round's proposal (``Proposal`` ->
``Refined``): the network identifies the response its residual corrections cannot see
(``identify.refine``), the physics fits each effect's strength in the model itself and keeps the
proposal as it is.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Generic, Protocol, TypeVar

from ..recordings import Signals
from . import acceptance as acc
from . import scoring as sc
from .dataset import DataSet
from .defaults import ALPHA, MIN_EFFECT  # the decision thresholds (see workflow.py)
from .physics import FittedValue
from .results import Evidence, KindFields

Progress = Callable[[str], None]

#: What a kind's trial holds (the network: the retrained ``model.NetworkModel``; the physics: its
#: ``physics.fit.Fit``): only the kind that made it reads it back.
FitT = TypeVar("FitT")
#: The model a kind hands back at the end (``model.NetworkModel``; ``physics.config.PhysicsConfig``).
ModelT_co = TypeVar("ModelT_co", covariant=True)


@dataclass
class Options:
    max_effects: int = 3
    restrict: Sequence[str] | None = None
    hidden: int | None = None
    max_epochs: int = 300
    #: early stopping of step 4's retraining: epochs without a better validation cost before it
    #: stops. Not the paper's 6 (MATLAB's max_fail, for training from random weights): a retraining
    #: starts from the converged model with the new input's weights at 0, and its validation cost
    #: first rises for 10-25 epochs while the weights rebalance (a foreign bench's rotor lag: best
    #: at epoch 3, beaten from epoch 26 on, a third lower at 32), so 6 returned the starting model
    #: whatever the input, and the holdout then judged the input on an untrained network
    patience: int = 30
    seed: int = 0
    alpha: float = ALPHA
    #: level of the --holdout replication test (acceptance.HOLDOUT_ALPHA; never below alpha)
    holdout_alpha: float = acc.HOLDOUT_ALPHA
    min_effect: float = MIN_EFFECT
    report_dir: str | None = None
    report_force: bool = False  #: --force: an earlier report at report_dir may be replaced
    warm_start: bool = True  #: retrain from the base model's weights (network.warm_start_weights)

    @property
    def replication_alpha(self) -> float:
        """The level a --holdout is judged at: holdout_alpha, never stricter than alpha."""
        return max(self.alpha, self.holdout_alpha)


@dataclass
class Scores:
    """A candidate's step-3 scores: on the measured data (for the network, its residual
    correction fitted on measured + reference pooled), on the measured data alone, and on the
    reference alone (None without reference recordings)."""

    measured: sc.Score
    measured_alone: sc.Score
    reference: sc.Score | None
    feature: str  #: the candidate's feature at its step-3 parameters, in words


@dataclass
class Trial(Generic[FitT]):
    """Step 4: a model with one more effect, fitted, not yet kept."""

    model: FitT
    hold: DataSet  #: its predictions on the holdout (the measured recordings without one)
    parameters: dict[str, float]  #: the fitted parameters (--json ``fitted_parameters``)
    feature: str  #: the fitted feature in words
    value: FittedValue | None = None  #: the fitted value in physical units (physics.fitted_value)
    #: fitted quantities at a bound of their range or implausibly far from the CONFIG, in words
    #: (physics.fit.FitFlag): the fit is not a basis for a verdict
    flags: list[str] = field(default_factory=list)
    extra: dict[str, str] = field(default_factory=dict)  #: kind-specific fields of the round


@dataclass
class Proposal:
    """A round's proposal as the scores made it: every candidate's evidence (the identification
    may change its verdicts in place), the effect the scores propose, and the effects added in
    earlier rounds (never proposed again)."""

    evidence: dict[str, Evidence]
    best: str | None
    added: Sequence[str]


@dataclass
class Refined:
    """A round's proposal after the kind's identification: the effect tried first, and its
    parameters when the identification fixed them (else the kind fits them)."""

    best: str | None
    params: dict[str, float] | None = None
    reference_params: dict[str, float] | None = None  #: the effect's parameters on the reference itself


class ModelKind(Protocol[ModelT_co, FitT]):
    """A model the loop can check against measurements and extend by one effect at a time."""

    #: the model as the sentences name it ("the model", "the calibrated physics model")
    noun: str
    #: what the holdout-less before/after figure was fitted on (for the warning)
    fitted_on: str
    #: the warning when there are no reference recordings
    no_reference: str

    def start(self, measured: Sequence[Signals], reference: Sequence[Signals], hold: Sequence[Signals],
              progress: Progress) -> tuple[DataSet, DataSet | None, DataSet]:
        """Step 1: the model's prediction on the measured, reference and holdout recordings."""

    def warnings(self) -> list[str]:
        """What the kind found doubtful so far (fits at a bound, implausible constants)."""

    def no_verdict(self) -> str | None:
        """Why no effect may be named at all after step 1 (the reference is not explained), or None."""

    def candidates(self, restrict: Sequence[str], named: Sequence[str]) -> list[str]:
        """The effects the current model can still add."""

    def score(self, names: Sequence[str], progress: Progress) -> dict[str, Scores]:
        """Step 3: each candidate scored on held-out time blocks."""

    def identify(self, proposal: Proposal, progress: Progress) -> Refined:
        """Between steps 3 and 4: the round's proposal refined by what the kind identifies beyond
        its scores (the effect tried first, at the parameters the identification fixed)."""

    def add(self, name: str, params: dict[str, float] | None, reference_params: dict[str, float] | None,
            scores: Scores, hold: Sequence[Signals], progress: Progress) -> Trial[FitT]:
        """Step 4: the effect added (at ``params`` when the identification fixed them)."""

    def heldout(self, name: str, trial: Trial[FitT], scores: Scores, alpha: float) -> acc.Acceptance:
        """Step 5 without --holdout: the trial judged on the kind's own held-out data."""

    def contradicted(self, name: str) -> str | None:
        """Why the kind's identification on measured vs reference contradicts adding ``name``
        whatever the held-out figure (in words), or None."""

    def keep(self, trial: Trial[FitT]) -> None:
        """The trial becomes the current model."""

    @property
    def model(self) -> ModelT_co:
        """The current model."""

    def fitted(self, name: str) -> tuple[dict[str, float], str, FittedValue | None] | None:
        """A named effect's parameters, feature and physical value in the CURRENT model (the
        one number reported everywhere), or None when they do not change after it is added."""

    def finish(self, named: Sequence[str]) -> tuple[KindFields, list[str], list[str]]:
        """The kind's own --json fields, summary lines before and after the shared ones."""
