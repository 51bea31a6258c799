"""propulsion_all: a misspelt parameter is one warning for the process (issue 32, item 5).

``-p`` and a launch's parameters reach every node of the process, so each node used to warn:
nine identical lines on a quadrotor. The nodes are built in-process, as the executable does.
"""

from __future__ import annotations

import pytest

from _ros import require_rclpy


@pytest.mark.parametrize("motors", [1, 3])
def test_a_misspelt_parameter_warns_once_for_the_process(capfd, motors):
    rclpy = require_rclpy()
    from bldc_propulsion.nodes.all_in_one import build_nodes

    context = rclpy.context.Context()
    rclpy.init(args=["--ros-args", "-p", "blads:=3", "-p", "zzz:=1", "-p", "timeout_s:=0.5"],
               context=context)
    capfd.readouterr()
    try:
        nodes = build_nodes(motors, context=context)
        assert len(nodes) == 1 + 2 * motors
        # timeout_s is the tachometer's: known in the process, no warning from the other nodes
        assert all(n.get_parameter("timeout_s").value == 0.5 for n in nodes if n.get_name() == "tachometer")
        for node in nodes:
            node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)
    err = capfd.readouterr().err
    warnings = [line for line in err.splitlines() if "unknown parameter" in line]
    assert [w.split("]: ", 1)[1].split(":")[0] for w in warnings] == [
        "unknown parameter 'blads' ignored", "unknown parameter 'zzz' ignored"], err
    assert warnings[0].endswith("did you mean 'blades'?"), warnings[0]  # the nearest of any node
    assert all("[WARN]" in w and "[propulsion_all]" in w for w in warnings), warnings
