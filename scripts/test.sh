#!/usr/bin/env bash
# Run the test suite in .venv (created on first use). Extra arguments go to pytest.
# Two parts: most tests on every core (pytest-xdist, a file per worker), then the tests that
# start node processes and judge wall time, alone (conftest.SERIAL_FILES: a second worker's
# load would falsify their timing).
export WITH_ROS=1
source "$(dirname "${BASH_SOURCE[0]}")/venv.sh"
# (before the thread limits below: nproc reports OMP_NUM_THREADS when it is set)
cores=$(nproc 2>/dev/null || echo 2)
workers=$(( cores < 4 ? cores : 4 ))  # conftest.MAX_WORKERS: each worker its own ROS domain
# One BLAS thread per process: OpenBLAS starts a thread per core in every worker and its threads
# spin while they wait, so two workers on two cores ran 1.4x slower (the parallel part 815 s ->
# 599 s with this, results identical)
export OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
set +e
.venv/bin/python -m pytest -q --durations=10 -n "$workers" --dist loadfile -m "not serial" "$@" test
parallel=$?
.venv/bin/python -m pytest -q --durations=5 -m serial "$@" test
serial=$?
# 5 = nothing collected (e.g. -k matched tests of one part only): fine if the other part ran
if [ "$parallel" -eq 5 ] && [ "$serial" -ne 5 ]; then parallel=0; fi
if [ "$serial" -eq 5 ] && [ "$parallel" -ne 5 ]; then serial=0; fi
echo "test parts: parallel exit $parallel, serial exit $serial" >&2
[ "$parallel" -eq 0 ] && [ "$serial" -eq 0 ]
