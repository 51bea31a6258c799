"""The thrust_estimator node with a physics model file (rclpy in-process; skipped without it)."""

from __future__ import annotations

import numpy as np
import pytest

from _ros import require_rclpy

rclpy = require_rclpy()

from rclpy.parameter import Parameter  # noqa: E402

from bldc_propulsion import contract as c  # noqa: E402
from bldc_propulsion.model import save_model  # noqa: E402
from bldc_propulsion.nodes.thrust_estimator_node import ThrustEstimatorNode  # noqa: E402
from bldc_propulsion.physics.params import BenchParams  # noqa: E402
from bldc_propulsion.physics.plant_model import PlantModel  # noqa: E402


@pytest.fixture()
def context():
    ctx = rclpy.context.Context()
    rclpy.init(context=ctx)
    yield ctx
    rclpy.try_shutdown(context=ctx)


def test_node_runs_a_physics_model_and_keeps_it_on_a_bad_reload(context, tmp_path):
    good = tmp_path / "physics.npz"
    save_model(PlantModel(BenchParams(sim_step_s=0.005), dict.fromkeys(c.EFFECTS, 1.0), 12.0), good)
    node = ThrustEstimatorNode(context=context, parameter_overrides=[Parameter("model_path", value=str(good))])
    try:
        core = node.core
        assert core.model.kind == "physics"
        core.update_voltage(0.0, 12.0)
        core.update_pwm(0.0, 0.08)
        assert core.predict(1.0).speed_rad_s > 300.0
        # a physics file with an unphysical constant: refused in one line, the good model kept
        bad = tmp_path / "bad.npz"
        with np.load(good) as z:
            arrays = {k: z[k] for k in z.files}
        names = [str(n) for n in arrays["physics_names"]]
        arrays["physics_values"][names.index("motor_kv_rpm_per_v")] = -710.0
        np.savez(bad, **arrays)
        result = node.set_parameters([Parameter("model_path", value=str(bad))])[0]
        assert not result.successful
        assert "bad.npz: physics_values: motor_kv_rpm_per_v -710.0 must be > 0" in result.reason
        assert node.core is core and node.get_parameter("model_path").value == str(good)
    finally:
        node.destroy_node()
