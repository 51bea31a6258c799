"""``runs.true_runs`` against scipy.ndimage's labelling (the reference) and hand-made cases."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from bldc_propulsion.runs import true_run_pairs, true_runs


def reference(flags: np.ndarray) -> list[tuple[int, int]]:
    labels, _ = ndimage.label(flags)
    return [(s[0].start, s[0].stop) for s in ndimage.find_objects(labels)]


def test_hand_made_cases():
    assert true_run_pairs(np.array([0, 1, 1, 0, 1], dtype=bool)) == [(1, 3), (4, 5)]
    assert true_run_pairs(np.ones(3, dtype=bool)) == [(0, 3)]
    assert true_run_pairs(np.zeros(3, dtype=bool)) == []
    assert true_run_pairs(np.zeros(0, dtype=bool)) == []
    starts, stops = true_runs(np.array([1.0, 0.0, 2.0]))  # any truthy values
    assert starts.tolist() == [0, 2] and stops.tolist() == [1, 3]


def test_random_arrays_match_scipy():
    rng = np.random.default_rng(0)
    for n in (1, 2, 7, 100, 1000):
        for p in (0.1, 0.5, 0.9):
            flags = rng.random(n) < p
            assert true_run_pairs(flags) == reference(flags)
