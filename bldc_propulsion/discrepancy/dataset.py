"""Recordings with the current model's prediction on them and the residual (what the loop, the
model kinds and the results all read)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ..recordings import Signals


@dataclass
class DataSet:
    """Recordings, the current model's prediction on them, and the residual."""

    signals: list[Signals]
    predictions: list[np.ndarray] = field(default_factory=list)
    inputs: list[np.ndarray] = field(default_factory=list)  #: network inputs scaled to [-1, 1]

    @property
    def residuals(self) -> list[np.ndarray]:
        return [s.speed - p for s, p in zip(self.signals, self.predictions, strict=True)]


def rmse(residuals: Sequence[np.ndarray], masks: Sequence[np.ndarray] | None = None) -> float:
    """Root mean square of the finite residual samples (inside ``masks`` when given)."""
    parts = []
    for k, r in enumerate(residuals):
        sel = np.isfinite(r)
        if masks is not None:
            sel &= masks[k]
        parts.append(r[sel])
    x = np.concatenate(parts) if parts else np.zeros(0)
    return float(np.sqrt(np.mean(x**2))) if len(x) else float("nan")
