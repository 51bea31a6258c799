"""rclpy adapters of the cores: battery_filter, tachometer, thrust_estimator, propulsion_all.

Importing this package does not import rclpy: only the node modules do (``params`` does not),
so the rest of bldc_propulsion and its tests run without ROS.
"""
