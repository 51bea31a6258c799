# Sourced by the other scripts: create .venv (once) and install the package with test extras.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  if ! "$PY" -m venv .venv 2>/dev/null; then
    rm -rf .venv
    echo "error: '$PY -m venv' failed; on Debian install it with: apt-get install python3-venv" >&2
    exit 2
  fi
fi
# ROS 2 Jazzy's rclpy, message packages and Fast DDS as binary wheels from PyPI (CPython 3.11;
# about 270 MB): the node tests run them for real. Where the wheels do not exist (another
# Python) the node tests are skipped on a developer machine; in CI (CI set) that is an error.
ROS_WHEELS="ros-jazzy-rclpy ros-jazzy-common-interfaces ros-jazzy-rmw-fastrtps-cpp"
if [ ! -f .venv/.installed ] || [ setup.py -nt .venv/.installed ]; then
  echo "installing bldc_propulsion and its dependencies into .venv (log: .venv/install.log)" >&2
  if ! { .venv/bin/python -m pip install --upgrade pip && .venv/bin/python -m pip install -e '.[test]'; } \
      > .venv/install.log 2>&1; then
    tail -n 20 .venv/install.log >&2
    echo "error: installing into .venv failed (full log: .venv/install.log)" >&2
    exit 2
  fi
  touch .venv/.installed
fi
# Only the test command asks for ROS (WITH_ROS=1); the demo does not need it.
if [ -n "${WITH_ROS:-}" ] && [ ! -f .venv/.installed-ros ]; then
  echo "installing ROS 2 Jazzy rclpy wheels into .venv (log: .venv/install-ros.log)" >&2
  if .venv/bin/python -m pip install $ROS_WHEELS > .venv/install-ros.log 2>&1; then
    touch .venv/.installed-ros
  else
    tail -n 5 .venv/install-ros.log >&2
    if [ -n "${CI:-}" ]; then
      echo "error: CI needs rclpy for the node tests; installing $ROS_WHEELS failed" >&2
      exit 2
    fi
    echo "warning: rclpy not installed: the node tests will be skipped" >&2
  fi
fi
