"""A gap in the measured speed (a telemetry dropout, a tachometer that lost the blades) is not
measured: NaN on the grid, left out of training and scoring, and named in one warning line.

Against known truth: the simulator's speed recorded as rotor/speed with a window of it dropped,
beside the same recording without the drop; hand-built sample times for the rule itself.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from _models import good_model
from _truth_bags import write_bag
from bldc_propulsion import cli
from bldc_propulsion.bagio import GAP_FACTOR
from bldc_propulsion.model import save_model
from bldc_propulsion.recordings import (
    DECODED_SPEED_GAP_S,
    RECORDED_SPEED_GAP_S,
    gap_warnings,
    load_signals,
    speed_gaps,
)
from bldc_propulsion.training.evaluate import evaluate

BUNDLED = Path(__file__).resolve().parents[1] / "bags"
GAP = (2.0, 3.5)  #: rotor/speed dropped here: random steps move the speed by ~170 rad/s inside it


def test_the_rule_on_hand_built_sample_times():
    t = np.r_[np.arange(0.0, 1.0, 0.01), np.arange(1.5, 2.0, 0.01)]  # 100 Hz, a 0.51 s hole
    assert speed_gaps(t, RECORDED_SPEED_GAP_S) == [(pytest.approx(0.99), pytest.approx(1.5))]
    assert speed_gaps(t, DECODED_SPEED_GAP_S) == []  # the tachometer's floor: a slow first revolution
    fast = np.r_[np.arange(0.0, 1.0, 0.001), np.arange(1.05, 2.0, 0.001)]  # 1 kHz: 50 ms is no gap
    assert RECORDED_SPEED_GAP_S > 0.051 and speed_gaps(fast, RECORDED_SPEED_GAP_S) == []
    slow = np.arange(0.0, 20.0, 0.1)  # 10 Hz telemetry: its own pace is no gap ...
    assert speed_gaps(slow, RECORDED_SPEED_GAP_S) == []
    late = np.r_[slow[:50], slow[50:] + 0.45]  # ... a dropout of GAP_FACTOR intervals is
    assert late[50] - late[49] > GAP_FACTOR * 0.1
    assert speed_gaps(late, RECORDED_SPEED_GAP_S) == [(pytest.approx(4.9), pytest.approx(5.45))]
    assert speed_gaps(np.array([0.0, 5.0]), RECORDED_SPEED_GAP_S) == []  # too few to tell a pace


@pytest.fixture(scope="module")
def bags(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("gap_bags")
    return {"full": write_bag(d / "full", "random_steps", 3, thrust=False),
            "gap": write_bag(d / "gap", "random_steps", 3, thrust=False, speed_gap=GAP),
            "val": write_bag(d / "val", "random_steps", 4, thrust=False)}


def test_the_grid_is_nan_inside_the_gap_and_the_measurement_elsewhere(bags):
    full, gap = load_signals(bags["full"]), load_signals(bags["gap"])
    assert full.speed_gaps == () and len(gap.speed_gaps) == 1
    before, after = gap.speed_gaps[0]
    assert before < GAP[0] <= GAP[1] <= after < GAP[1] + 0.01
    inside = (gap.t > before) & (gap.t < after)
    assert np.array_equal(~np.isfinite(gap.speed), inside)
    np.testing.assert_array_equal(gap.speed[~inside], full.speed[~inside])
    assert np.ptp(full.speed[inside]) > 100.0  # what a straight line through the gap would have missed
    (line,) = gap_warnings([full, gap])
    assert line.startswith(f"{gap.path}: the measured speed (rotor/speed (recorded)) has 1 gap(s)")
    assert f"the longest {after - before:.2f} s from {before:.2f} s" in line


def test_the_bundled_tachometer_bags_have_no_gap():
    for name in ("validation", "triangle_half"):  # the longest decoded intervals among them (0.52-0.55 s)
        assert load_signals(BUNDLED / name).speed_gaps == ()


def run_cli(capsys, *args: object) -> tuple[int, dict, str]:
    code = cli.main([str(a) for a in args])
    out = capsys.readouterr()
    return code, json.loads(out.out) if out.out.strip() else {}, out.err


def test_evaluate_scores_only_what_was_measured_and_says_so(capsys, bags, tmp_path):
    model = good_model()
    path = tmp_path / "network.npz"
    save_model(model, path)
    full = load_signals(bags["full"])
    _, _, (pred,) = evaluate(model, [full])
    gap = load_signals(bags["gap"])
    outside = np.isfinite(gap.speed)
    expected = float(np.sqrt(np.mean((pred - full.speed)[outside] ** 2)))
    code, data, err = run_cli(capsys, "evaluate", "--model", path, bags["gap"], "--json")
    assert code == 0, err
    assert data["rmse_rad_s"] == pytest.approx(expected, rel=1e-9)
    assert data["rmse_rad_s"] != pytest.approx(float(np.sqrt(np.mean((pred - full.speed) ** 2))), rel=1e-3)
    assert any("1 gap(s)" in w and str(bags["gap"]) in w for w in data["warnings"])
    assert "warning: " + data["warnings"][0] in err


def test_train_learns_around_the_gap_and_says_so(capsys, bags, tmp_path):
    code, data, err = run_cli(capsys, "train", bags["gap"], "--validation", bags["val"], "-o", tmp_path / "m.npz",
                              "--hidden", "3", "--max-epochs", "8", "--restarts", "1", "--json")
    assert code == 0, err
    assert np.isfinite(data["train_rmse_rad_s"]) and np.isfinite(data["validation_rmse_rad_s"])
    assert sum("1 gap(s)" in w for w in data["warnings"]) == 1


def test_info_states_the_gap(capsys, bags):
    code, data, err = run_cli(capsys, "info", bags["gap"], "--json")
    assert code == 0, err
    (rec,) = data["recordings"]
    sp = rec["speed_rad_s"]
    assert [t["gaps"] for t in rec["topics"] if t["topic"] == "/rotor/speed"] == [1]  # the topic's gaps are these
    assert sp["gaps"] == 1 and sp["gaps_s"] == pytest.approx(GAP[1] - GAP[0] + 0.005, abs=0.006)
    code = cli.main(["info", str(bags["gap"])])
    assert code == 0
    assert "; 1 gap(s), 1.50 s not measured" in capsys.readouterr().out
