#!/usr/bin/env bash
# Run the test suite in .venv (created on first use). Extra arguments go to pytest.
export WITH_ROS=1
source "$(dirname "${BASH_SOURCE[0]}")/venv.sh"
exec .venv/bin/python -m pytest -q --durations=15 "$@" test
