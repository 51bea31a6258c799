"""Suite-wide setup: ROS 2 discovery kept on this machine, in a domain of this run's own.

Set before any test imports rclpy, and inherited by the node processes the tests start, so
parallel runs (or another ROS program on the machine) never see each other's topics.
"""

from __future__ import annotations

import os

os.environ.setdefault("ROS_DOMAIN_ID", str(1 + os.getpid() % 100))
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
