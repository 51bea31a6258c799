"""Runs of True in a boolean array, as [start, stop) index pairs: the one idiom behind every span
the package finds (import-csv's contradicted spans, the discrepancy windows, the health monitor's
stretches, the tachometer's runs of finite samples).

By hand, not ``scipy.ndimage.label``: two numpy lines, where the library would load
scipy.ndimage into the tachometer node for them (the tests check it against the library).
"""

from __future__ import annotations

import numpy as np


def true_runs(flags: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(starts, stops) of every run of True in the 1-D ``flags``: ``flags[starts[k]:stops[k]]``
    is all True, and the samples just outside it are False or past an end."""
    edges = np.diff(np.concatenate(([0], np.asarray(flags, dtype=bool).astype(np.int8), [0])))
    return np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)


def true_run_pairs(flags: np.ndarray) -> list[tuple[int, int]]:
    """``true_runs`` as a list of (start, stop) ints."""
    starts, stops = true_runs(flags)
    return list(zip(starts.tolist(), stops.tolist(), strict=True))
