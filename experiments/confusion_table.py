"""Confusion table of the discrepancy workflow: every hidden effect and the no-effect control.

For each effect of the contract (and "control": no hidden effect) and each seed: the scenario of
test/test_discrepancy.py (reference recordings with the effect OFF and a validation recording, a
baseline network trained on them, measured and holdout recordings with the effect ON under
commands that excite it), all recordings and the baseline's initial weights drawn from the seed;
run the workflow, and record which effect it names first and how much the holdout RMSE fell.
Prints the table (true effect x first named effect) and the median RMSE reduction per effect.

    PYTHONPATH=. python experiments/confusion_table.py --seeds 5 --jobs 1
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from bldc_propulsion import contract as c

ROOT = Path(__file__).resolve().parents[1]


def one_run(effect: str, seed: int, duration: float, hidden: int, epochs: int) -> dict:
    """One scenario of test/test_discrepancy.py (same commands, states of charge and sizes) at
    another seed: every recording and the baseline's initial weights change with the seed."""
    sys.path.insert(0, str(ROOT / "test"))
    import test_discrepancy as T
    from bldc_propulsion.discrepancy.workflow import Options, run_workflow

    T.HIDDEN, T.EPOCHS = hidden, epochs  # recording lengths are the test's (SCENARIOS)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as d:
        s = T.scenario(effect, Path(d), seed)
        data = run_workflow(s.model, s.measured, s.reference, s.holdout,
                            Options(max_effects=2, max_epochs=epochs, seed=seed), lambda m: None).data
    return {
        "effect": effect, "seed": seed, "named": data["named"],
        "first": data["named"][0] if data["named"] else "(nothing)",
        "before": data["holdout_rmse_before"], "after": data["holdout_rmse_after"],
        "seconds": time.perf_counter() - t0,
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--hidden", type=int, default=8)
    ap.add_argument("--epochs", type=int, default=300)
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--effects", default=",".join([*c.EFFECTS, "control"]))
    args = ap.parse_args(argv)
    effects = [e for e in args.effects.split(",") if e]
    jobs = [(e, s, 0.0, args.hidden, args.epochs) for e in effects for s in range(args.seeds)]
    results = []
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        for r in pool.map(one_run, *zip(*jobs)):
            results.append(r)
            print(f"{r['effect']:20s} seed {r['seed']}: named {r['named'] or 'nothing'}; holdout RMSE "
                  f"{r['before']:.1f} -> {r['after']:.1f} rad/s ({r['seconds']:.0f} s)", file=sys.stderr, flush=True)
    cols = [*c.EFFECTS, "(nothing)"]
    width = max(len(x) for x in cols) + 1
    print("true \\ first named".ljust(22) + "".join(x[:14].rjust(15) for x in cols) + "   correct")
    for e in effects:
        rows = [r for r in results if r["effect"] == e]
        counts = [sum(r["first"] == col for r in rows) for col in cols]
        want = "(nothing)" if e == "control" else e
        ok = sum(r["first"] == want for r in rows)
        print(e.ljust(22) + "".join(str(n).rjust(15) for n in counts) + f"   {ok}/{len(rows)}")
    print()
    print("median holdout RMSE reduction (before -> after, over seeds):")
    for e in effects:
        rows = [r for r in results if r["effect"] == e]
        red = [1.0 - r["after"] / r["before"] for r in rows if r["before"] > 0]
        print(f"  {e:20s} {100 * float(np.median(red)):6.1f} %   "
              f"(median before {np.median([r['before'] for r in rows]):.1f}, after "
              f"{np.median([r['after'] for r in rows]):.1f} rad/s)")
    del width
    return 0


if __name__ == "__main__":
    sys.exit(main())
