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
  .venv/bin/python -m pip install -q --upgrade pip >&2
  .venv/bin/python -m pip install -q -e '.[test]' >&2
  touch .venv/.installed
fi
