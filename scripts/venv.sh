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
