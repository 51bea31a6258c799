"""rclpy for the node tests: a skip on a developer machine without ROS, a failure in CI.

CI (``CI`` set, as .ci/run runs) installs the ROS 2 Jazzy wheels, so a missing rclpy there is a
broken install, and a node test silently skipped would hide exactly what it exists to find.
"""

from __future__ import annotations

import importlib
import os

import pytest


def require_rclpy():
    """Import rclpy, or skip (developer machine) / fail (CI) saying why."""
    try:
        return importlib.import_module("rclpy")
    except ImportError as e:
        if os.environ.get("CI"):
            pytest.fail(f"rclpy is required in CI (scripts/venv.sh installs it): {e}",
                        pytrace=False)
        pytest.skip(f"rclpy not installed: {e}", allow_module_level=True)
