"""Grid fits do not let float rounding choose between grid points the data cannot tell apart."""

from __future__ import annotations

import numpy as np

from bldc_propulsion.discrepancy import scoring


def _case(noise_on_second: float) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
    rng = np.random.default_rng(4)
    null_X = rng.normal(size=(400, 2))
    extra = rng.normal(size=(400, 1))
    r = null_X @ np.array([0.5, -0.2]) + 0.8 * extra[:, 0] + 0.01 * rng.normal(size=400)
    # the same column twice, the second a rounding error away (what an unseen parameter gives)
    return r, null_X, [extra, extra * (1.0 + noise_on_second)]


def test_tied_grid_points_go_to_the_first_whichever_rounds_lower():
    grid = [{"tau_up_s": 0.05}, {"tau_up_s": 0.12}]
    for noise in (1e-15, -1e-15, 3e-13, -3e-13):
        r, null_X, extras = _case(noise)
        assert scoring.fit_params(r, null_X, extras, grid) == {"tau_up_s": 0.05}, noise


def test_a_real_difference_still_wins():
    rng = np.random.default_rng(5)
    null_X = rng.normal(size=(400, 2))
    good, bad = rng.normal(size=(400, 1)), rng.normal(size=(400, 1))
    r = null_X @ np.array([0.5, -0.2]) + 0.8 * good[:, 0] + 0.01 * rng.normal(size=400)
    grid = [{"x": 1.0}, {"x": 2.0}]
    assert scoring.fit_params(r, null_X, [bad, good], grid) == {"x": 2.0}
