"""Rotor speed and thrust estimation for a BLDC motor and propeller (ROS 2 package).

Everything importable from here runs without ROS; only ``bldc_propulsion.nodes`` needs rclpy.
"""

__version__ = "0.1.0"
