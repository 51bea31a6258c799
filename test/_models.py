"""A small valid speed network shared by the model-file tests (loader, fuzzing, estimator)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bldc_propulsion import contract as c
from bldc_propulsion.model import NetworkModel, save_model
from bldc_propulsion.recordings import load_signals
from bldc_propulsion.sim import simulate
from bldc_propulsion.sim.record import write_sim_bag
from bldc_propulsion.training.fit_physics import train_physics


def good_model() -> NetworkModel:
    """3-4-1 on the paper's inputs with fixed random weights: loads, predicts, round-trips."""
    rng = np.random.default_rng(0)
    return NetworkModel(
        input_names=tuple(c.DEFAULT_INPUTS), input_min=np.array([9.0, 0.05, 0.05]),
        input_max=np.array([13.0, 0.10, 0.10]), output_min=0.0, output_max=900.0,
        W1=rng.normal(0, 0.5, (4, 3)), b1=np.zeros(4), W2=rng.normal(0, 0.5, 4), b2=0.0)


def healthy_physics_model(d: Path) -> Path:
    """A physics model fitted on healthy random-step recordings of the nominal bench (seeds 101
    and 102, written under ``d``): what the health tests monitor their flights with."""
    sigs = []
    for name, dur, seed, soc in (("train", 60.0, 101, 0.7), ("validation", 30.0, 102, 0.6)):
        write_sim_bag(simulate("random_steps", dur, seed, soc=soc), d / name)
        sigs.append(load_signals(d / name))
    path = d / "physics.npz"
    save_model(train_physics([sigs[0]], [sigs[1]], thrust_coefficient=None).model, path)
    return path
