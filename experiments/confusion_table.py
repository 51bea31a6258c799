"""Confusion table of the discrepancy workflow: every hidden effect and the no-effect control.

For each effect of the contract (and "control": no hidden effect) and each seed: the scenario of
test/test_discrepancy.py (reference recordings with the effect OFF and a validation recording, a
baseline network trained on them, measured and holdout recordings with the effect ON under
commands that excite it), all recordings and the baseline's initial weights drawn from the seed;
run the workflow, and record which effect it names first and how much the holdout RMSE fell.
Prints the table (true effect x first named effect) and the median RMSE reduction per effect.

By default every run is on a bench drawn from its seed (``sim.random_bench``: other constants,
sometimes a bent throttle map or a two-RC pack) with the hidden effect at a drawn strength
(0.5-2x); ``--nominal-bench`` uses the nominal bench at strength 1, ``--far-bench`` benches of
another motor class (``random_bench.draw_far_bench``: 3S/4S, other speed and power). Seeds 0-4
are the reported ones; tune on ``--first-seed 100``.

    PYTHONPATH=. python experiments/confusion_table.py --seeds 5 --jobs 2
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
sys.path.insert(0, str(ROOT / "benchmarks"))
from results import check_record_path, write_record  # noqa: E402


def one_run(effect: str, seed: int, bench_kind: str, hidden: int, epochs: int) -> dict:
    """One scenario of test/test_discrepancy.py (same commands, states of charge and sizes) at
    another seed: every recording and the baseline's initial weights change with the seed."""
    sys.path.insert(0, str(ROOT / "test"))
    import test_discrepancy as T
    from bldc_propulsion.discrepancy.workflow import Options, run_workflow
    from bldc_propulsion.sim import random_bench as rb

    T.HIDDEN, T.EPOCHS = hidden, epochs  # recording lengths are the test's (SCENARIOS)
    bench = rb.DRAWS[bench_kind](seed) if bench_kind != "nominal" else None
    strength = rb.draw_strength(effect, seed) if bench_kind != "nominal" and effect != "control" else 1.0
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as d:
        s = T.scenario(effect, Path(d), seed, bench=bench, strength=strength)
        data = run_workflow(s.model, s.measured, s.reference, s.holdout,
                            Options(max_effects=2, max_epochs=epochs, seed=seed), lambda m: None).data
    return {
        "effect": effect, "seed": seed, "named": data["named"], "strength": strength,
        "first": data["named"][0] if data["named"] else "(nothing)",
        "before": data["holdout_rmse_before"], "after": data["holdout_rmse_after"],
        "seconds": time.perf_counter() - t0,
    }


def print_table(results: list[dict], effects: list[str]) -> None:
    """The confusion table, the holdout RMSE reduction (median [min, max]) and the control's false names."""
    cols = [*c.EFFECTS, "(nothing)"]
    print(f"\n{len(results)} runs, seeds {', '.join(map(str, sorted({r['seed'] for r in results})))}")
    print("true \\ first named".ljust(22) + "".join(x[:14].rjust(15) for x in cols) + "   correct")
    for e in effects:
        rows = [r for r in results if r["effect"] == e]
        counts = [sum(r["first"] == col for r in rows) for col in cols]
        want = "(nothing)" if e == "control" else e
        ok = sum(r["first"] == want for r in rows)
        print(e.ljust(22) + "".join(str(n).rjust(15) for n in counts) + f"   {ok}/{len(rows)}")
    print("holdout RMSE reduction over seeds: median [min, max]; control: effects named at all")
    for e in effects:
        rows = [r for r in results if r["effect"] == e]
        red = [100 * (1.0 - r["after"] / r["before"]) for r in rows if r["before"] > 0]
        print(f"  {e:20s} {float(np.median(red)):6.1f} % [{min(red):.1f}, {max(red):.1f}]   "
              f"(median before {np.median([r['before'] for r in rows]):.1f}, after "
              f"{np.median([r['after'] for r in rows]):.1f} rad/s)"
              + (f"   false names: {sum(len(r['named']) for r in rows)}" if e == "control" else ""))
    right = sum(r["first"] == ("(nothing)" if r["effect"] == "control" else r["effect"]) for r in results)
    print(f"named right first: {right}/{len(results)}", flush=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--first-seed", type=int, default=0, help="seeds first-seed .. first-seed+seeds-1")
    which = ap.add_mutually_exclusive_group()
    which.add_argument("--nominal-bench", action="store_true", help="the nominal bench, hidden effects at 1")
    which.add_argument("--far-bench", action="store_true",
                    help="benches of another motor class (random_bench.draw_far_bench: 3S/4S, other speed and power)")
    ap.add_argument("--hidden", type=int, default=8)
    ap.add_argument("--epochs", type=int, default=300)
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--effects", default=",".join([*c.EFFECTS, "control"]))
    ap.add_argument("--json", metavar="PATH", help="also write every run to PATH (benchmarks/results.py renders them)")
    args = ap.parse_args(argv)
    check_record_path(args.json)
    t_all = time.perf_counter()
    effects = [e for e in args.effects.split(",") if e]
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    kind = "nominal" if args.nominal_bench else "far" if args.far_bench else "random"
    jobs = [(e, s, kind, args.hidden, args.epochs) for s in seeds for e in effects]
    print(f"{kind} benches, seeds {seeds.start}-{seeds.stop - 1}")
    results = []
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        for r in pool.map(one_run, *zip(*jobs, strict=True)):
            results.append(r)
            print(f"{r['effect']:20s} seed {r['seed']} (strength {r['strength']:.2f}): named "
                  f"{r['named'] or 'nothing'}; holdout RMSE "
                  f"{r['before']:.1f} -> {r['after']:.1f} rad/s ({r['seconds']:.0f} s)", file=sys.stderr, flush=True)
            if len(results) % len(effects) == 0:  # a seed complete: the table so far (a run cut short keeps it)
                print_table(results, effects)
    if args.json:
        write_record(args.json, {"bench": kind, "runs": results}, seconds=time.perf_counter() - t_all)
    return 0


if __name__ == "__main__":
    sys.exit(main())
