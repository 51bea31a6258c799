"""The package installs both ways: ament_python metadata for colcon, and ROS-free imports."""

from __future__ import annotations

import ast
import os
import re
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from bldc_propulsion import cli

ROOT = Path(__file__).resolve().parents[1]


def test_package_xml_is_format_3_with_the_dependencies():
    root = ET.parse(ROOT / "package.xml").getroot()
    assert root.get("format") == "3"
    assert root.findtext("name") == "bldc_propulsion"
    exec_deps = {e.text for e in root.findall("exec_depend")}
    assert {"rclpy", "std_msgs", "sensor_msgs", "diagnostic_msgs", "python3-numpy", "python3-scipy"} <= exec_deps
    test_deps = {e.text for e in root.findall("test_depend")}
    assert "python3-pytest" in test_deps
    # no linter declared that no test runs: ruff and mypy (scripts/lint.sh) do that job in CI
    assert not {"ament_copyright", "ament_flake8", "ament_pep257"} & test_deps
    assert root.find("export/build_type").text == "ament_python"
    assert (ROOT / "resource" / "bldc_propulsion").is_file()


def test_setup_py_installs_data_files_and_entry_points():
    tree = ast.parse((ROOT / "setup.py").read_text())
    text = (ROOT / "setup.py").read_text()
    for needle in ("resource/", "package.xml", "launch/*.launch.py", "config/*.yaml"):
        assert needle in text
    assert any(isinstance(n, ast.Call) and getattr(n.func, "id", "") == "setup" for n in ast.walk(tree))
    version = ET.parse(ROOT / "package.xml").getroot().findtext("version")
    assert f'version="{version}"' in text  # package.xml and setup.py agree


def test_lint_config_targets_the_python_setup_py_requires():
    """ruff's target-version and mypy's python_version say the same oldest Python as setup.py
    (a newer target would let syntax through that the oldest supported Python cannot run)."""
    oldest = re.search(r'python_requires=">=3\.(\d+)"', (ROOT / "setup.py").read_text()).group(1)
    toml = (ROOT / "pyproject.toml").read_text()
    assert re.findall(r'^target-version = "py3(\d+)"$', toml, re.M) == [oldest]
    assert re.findall(r'^python_version = "3\.(\d+)"$', toml, re.M) == [oldest]
    assert not re.search(r"^\[(build-system|project)\]", toml, re.M)  # setup.py stays the build


def test_importing_everything_but_the_nodes_never_needs_rclpy():
    modules = [
        "bldc_propulsion.cli", "bldc_propulsion.bagio", "bldc_propulsion.replay",
        "bldc_propulsion.sim", "bldc_propulsion.core.battery_filter", "bldc_propulsion.core.tachometer",
        "bldc_propulsion.core.estimator", "bldc_propulsion.model", "bldc_propulsion.training.train",
        "bldc_propulsion.nodes",
    ]
    code = (
        "import sys, importlib\n"
        f"for m in {modules!r}: importlib.import_module(m)\n"
        "bad = [m for m in sys.modules if m.startswith(('rclpy', 'rcl_interfaces', 'launch'))]\n"
        "assert not bad, bad\n"
    )
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    subprocess.run([sys.executable, "-c", code], check=True, env=env, cwd=ROOT)


@pytest.mark.parametrize("command", list(cli._SUBCOMMANDS))
def test_every_subcommand_explains_itself(command, capsys):
    with pytest.raises(SystemExit) as exit_info:
        cli.main([command, "--help"])
    assert exit_info.value.code == 0
    out = capsys.readouterr().out
    assert f"bldc-propulsion {command}" in out and "--json" in out
    assert len(out.split()) > 40  # a description in a user's words, not just the flags


def test_every_subcommand_has_a_ros2_run_name():
    text = (ROOT / "setup.py").read_text()
    for command in cli._SUBCOMMANDS:
        assert f'"{command}"' in text
        assert hasattr(cli, f"main_{command.replace('-', '_')}")
