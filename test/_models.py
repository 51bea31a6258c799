"""A small valid speed network shared by the model-file tests (loader, fuzzing, estimator)."""

from __future__ import annotations

import numpy as np

from bldc_propulsion import contract as c
from bldc_propulsion.model import NetworkModel


def good_model() -> NetworkModel:
    """3-4-1 on the paper's inputs with fixed random weights: loads, predicts, round-trips."""
    rng = np.random.default_rng(0)
    return NetworkModel(
        input_names=tuple(c.DEFAULT_INPUTS), input_min=np.array([9.0, 0.05, 0.05]),
        input_max=np.array([13.0, 0.10, 0.10]), output_min=0.0, output_max=900.0,
        W1=rng.normal(0, 0.5, (4, 3)), b1=np.zeros(4), W2=rng.normal(0, 0.5, 4), b2=0.0)
