"""Wall time of one `discrepancy` run on the README case, for each model kind.

Network path: a model without battery voltage trained on bags/staircase + bags/triangle (as
scripts/demo.sh step 4; the training is not timed), then `discrepancy --model M --measured
bags/discharge_a --holdout bags/discharge_b` with the default --max-effects. Physics path:
`discrepancy --physics --measured bags/staircase bags/validation --holdout bags/discharge_b
--max-effects 4` (demo step 5). Prints the wall time, what was named and the holdout RMSE.

Run from the repository root: PYTHONPATH=. .venv/bin/python benchmarks/bench_discrepancy.py
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BAGS = ROOT / "bags"


def cli(*args: str) -> tuple[subprocess.CompletedProcess, float]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "bldc_propulsion.cli", *args], capture_output=True, text=True,
                          env=env, cwd=ROOT)
    elapsed = time.perf_counter() - t0
    if proc.returncode != 0:
        sys.exit(f"bench_discrepancy: {' '.join(args[:2])} failed: {proc.stderr.strip().splitlines()[-1]}")
    return proc, elapsed


def report(what: str, proc: subprocess.CompletedProcess, elapsed: float) -> None:
    d = json.loads(proc.stdout)
    print(f"{what}: {elapsed:.1f} s wall; named {d['named'] or 'nothing'}; holdout RMSE "
          f"{d['holdout_rmse_before']:.2f} -> {d['holdout_rmse_after']:.2f} rad/s; considered, not added: "
          f"{[x['effect'] for x in d['considered_not_added']]}")


def main() -> int:
    with tempfile.TemporaryDirectory() as tmp:
        model = Path(tmp) / "model_no_voltage.npz"
        cli("train", str(BAGS / "staircase"), str(BAGS / "triangle"), "--validation", str(BAGS / "validation_full"),
            "-o", str(model), "--inputs", "pwm,pwm_filtered")
        proc, t = cli("discrepancy", "--model", str(model), "--measured", str(BAGS / "discharge_a"),
                      "--holdout", str(BAGS / "discharge_b"), "--json")
        report("network path (--model, default --max-effects)", proc, t)
        proc, t = cli("discrepancy", "--physics", "--measured", str(BAGS / "staircase"), str(BAGS / "validation"),
                      "--holdout", str(BAGS / "discharge_b"), "--max-effects", "4", "--json")
        report("physics path (--physics, --max-effects 4)", proc, t)
    return 0


if __name__ == "__main__":
    sys.exit(main())
