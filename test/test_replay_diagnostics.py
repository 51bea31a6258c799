"""What ``replay`` writes on /diagnostics is what the nodes publish (interfaces.md, Diagnostics):
the absolute topic whatever the namespace, one DiagnosticArray per node, status names carrying
the node's namespace and name, hardware_id naming the motor (or the pack for the battery filter)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bldc_propulsion import contract as c
from bldc_propulsion.bagio import open_recording
from bldc_propulsion.replay import replay_bag
from bldc_propulsion.sim import simulate
from bldc_propulsion.sim.record import write_sim_bag


@pytest.fixture(scope="module")
def run() -> object:
    """3 s of random steps: one DiagnosticArray per node per second."""
    return simulate("random_steps", 3.0, seed=4)


def _diagnostics(path: Path) -> list:
    with open_recording(path) as rec:
        assert rec.topics()[c.bare(c.TOPIC_DIAGNOSTICS_ABSOLUTE)] == c.DIAGNOSTIC_ARRAY
        assert not [t for t in rec.topics() if t.endswith("/diagnostics")]  # never under a namespace
        return [m for _, _, m in rec.messages([c.TOPIC_DIAGNOSTICS_ABSOLUTE])]


@pytest.mark.parametrize("namespace,motor,tachometer,estimator", [
    (None, "motor", "tachometer", "thrust_estimator"),
    ("motor0", "motor0", "motor0/tachometer", "motor0/thrust_estimator"),
])
def test_replay_diagnostics_are_the_nodes(run, tmp_path, namespace, motor, tachometer, estimator):
    write_sim_bag(run, tmp_path / "in", namespace=namespace)
    replay_bag(tmp_path / "in", tmp_path / "out", namespace=namespace)
    arrays = _diagnostics(tmp_path / "out")
    # the battery filter sits at the root (one pack per vehicle, as the quadrotor launch puts it)
    expected = {"battery": {"battery_filter: battery filter"},
                motor: {f"{tachometer}: tachometer", f"{estimator}: thrust estimator", f"{estimator}: wrench"}}
    by_hardware: dict[str, set[str]] = {}
    per_node: dict[str, list[float]] = {}
    for array in arrays:
        hardware = {s.hardware_id for s in array.status}
        assert len(hardware) == 1, hardware  # one node's statuses per message
        (hw,) = hardware
        by_hardware.setdefault(hw, set()).update(s.name for s in array.status)
        stamp = array.header.stamp.sec + array.header.stamp.nanosec * 1e-9
        per_node.setdefault(array.status[0].name.split(":")[0], []).append(stamp)
    # (the estimator's wrench note only with a model that knows no reaction torque)
    assert by_hardware["battery"] == expected["battery"]
    assert by_hardware[motor] - expected[motor] == set()
    assert {f"{tachometer}: tachometer", f"{estimator}: thrust estimator"} <= by_hardware[motor]
    assert set(by_hardware) == {"battery", motor}
    # once a second from each of the three nodes, at the same times
    assert sorted(per_node) == sorted(["battery_filter", tachometer, estimator])
    stamps = list(per_node.values())
    assert len(stamps[0]) >= 2 and all(s == stamps[0] for s in stamps)
    assert np.allclose(np.diff(stamps[0]), 1.0)
