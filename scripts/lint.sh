#!/usr/bin/env bash
# Lint (ruff) and type-check (mypy) in .venv with the versions pinned here, as pyproject.toml
# configures them; exits non-zero on any finding. CI (.ci/run) runs it before the test suite.
RUFF_VERSION=0.17.6
MYPY_VERSION=2.4.1
# with the ROS wheels installed (as for the tests), mypy checks the nodes against rclpy's types
export WITH_ROS=1
source "$(dirname "${BASH_SOURCE[0]}")/venv.sh"
if ! .venv/bin/ruff --version 2>/dev/null | grep -qx "ruff $RUFF_VERSION" \
    || ! .venv/bin/mypy --version 2>/dev/null | grep -q "^mypy $MYPY_VERSION "; then
  echo "installing ruff $RUFF_VERSION and mypy $MYPY_VERSION into .venv" >&2
  .venv/bin/python -m pip install --quiet "ruff==$RUFF_VERSION" "mypy==$MYPY_VERSION" >&2
fi
status=0
.venv/bin/ruff check . || status=1
.venv/bin/mypy || status=1
exit $status
