"""ament_python package that also installs with `pip install -e .` in a plain venv."""

from glob import glob

from setuptools import find_packages, setup

package_name = "bldc_propulsion"

# `ros2 run bldc_propulsion <name>`: every subcommand of the `bldc-propulsion` entry point,
# plus the rclpy nodes.
SUBCOMMANDS = ["info", "simulate", "train", "evaluate", "replay", "discrepancy", "health", "import-csv", "import-log"]
NODES = {
    "battery_filter": "bldc_propulsion.nodes.battery_filter_node:main",
    "tachometer": "bldc_propulsion.nodes.tachometer_node:main",
    "thrust_estimator": "bldc_propulsion.nodes.thrust_estimator_node:main",
    "propulsion_all": "bldc_propulsion.nodes.all_in_one:main",
}

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/launch", glob("launch/*.launch.py")),
        ("share/" + package_name + "/config", glob("config/*.yaml")),
    ],
    install_requires=["setuptools", "numpy", "scipy", "rosbags>=0.10", "matplotlib"],
    # flight-log importers (import-log): pyulog (BSD-3) reads PX4 ULog; pymavlink (LGPL-3.0,
    # optional and imported only when a DataFlash log is read) reads ArduPilot .bin logs
    extras_require={
        "px4": ["pyulog"],
        "ardupilot": ["pymavlink"],
        "test": ["pytest", "pytest-xdist", "hypothesis", "mcap", "pyulog", "pymavlink"],
    },
    python_requires=">=3.10",
    zip_safe=True,
    maintainer="bldc_propulsion developers",
    maintainer_email="dev@bldc-propulsion.local",
    description="Rotor speed and thrust estimation for a BLDC motor and propeller",
    license="Apache-2.0",
    tests_require=["pytest"],
    entry_points={
        "console_scripts": [
            "bldc-propulsion = bldc_propulsion.cli:main",
            *[f"{name} = bldc_propulsion.cli:main_{name.replace('-', '_')}" for name in SUBCOMMANDS],
            *[f"{name} = {target}" for name, target in NODES.items()],
        ],
    },
)
