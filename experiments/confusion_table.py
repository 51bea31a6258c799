"""Confusion table of the discrepancy workflow: every hidden effect and the no-effect control.

For each effect of the contract (and "control": no hidden effect) and each seed: simulate
reference recordings with the effect OFF (staircase, triangle, random steps) and a validation
recording, train a baseline network on them, simulate measured and holdout recordings with the
effect ON (other seeds, profiles that excite it), run the workflow, and record which effect it
names first and how much the holdout RMSE fell. Prints the table (true effect x first named
effect) and the median RMSE reduction per effect.

    PYTHONPATH=. python experiments/confusion_table.py --seeds 5 --jobs 2
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from bldc_propulsion import contract as c

SCENARIOS = {
    "battery_voltage": (("pwm", "pwm_filtered"), [("random_steps", 0.95), ("random_steps", 0.4)],
                        [("random_steps", 0.7)]),
    "rotor_lag": (c.DEFAULT_INPUTS, [("random_steps", 1.0)] * 2, [("random_steps", 1.0)]),
    "input_delay": (c.DEFAULT_INPUTS, [("random_steps", 1.0)] * 2, [("random_steps", 1.0)]),
    "esc_deadband": (c.DEFAULT_INPUTS, [("triangle", 1.0), ("random_steps", 1.0)], [("triangle", 1.0)]),
    "spin_down_asymmetry": (c.DEFAULT_INPUTS, [("random_steps", 1.0)] * 2, [("random_steps", 1.0)]),
    "motor_heating": (c.DEFAULT_INPUTS, [("high_load", 1.0)] * 2, [("high_load", 1.0)]),
    "control": (c.DEFAULT_INPUTS, [("random_steps", 1.0), ("staircase", 1.0)], [("random_steps", 1.0)]),
}


def one_run(effect: str, seed: int, duration: float, hidden: int, epochs: int) -> dict:
    from bldc_propulsion.discrepancy.workflow import Options, run_workflow
    from bldc_propulsion.sim import simulate
    from bldc_propulsion.sim.record import write_sim_bag
    from bldc_propulsion.training.dataset import load_signals
    from bldc_propulsion.training.train import train_model

    inputs, meas_spec, hold_spec = SCENARIOS[effect]
    off = {} if effect == "control" else {effect: 0.0}
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as d:
        def bag(name, profile, s, effects, soc=1.0, dur=duration):
            p = os.path.join(d, name)
            write_sim_bag(simulate(profile, dur, s, effects=effects, soc=soc), p)
            return load_signals(p)

        base = 1000 * seed
        ref = [bag("r1", "staircase", base + 1, off), bag("r2", "triangle", base + 2, off),
               bag("r3", "random_steps", base + 3, off)]
        val = [bag("v", "random_steps", base + 4, off, dur=duration / 2)]
        meas = [bag(f"m{k}", p, base + 10 + k, {}, soc) for k, (p, soc) in enumerate(meas_spec)]
        hold = [bag(f"h{k}", p, base + 20 + k, {}, soc) for k, (p, soc) in enumerate(hold_spec)]
        model = train_model(ref, val, inputs=inputs, hidden=hidden, seed=seed, thrust_coefficient=2.8e-5,
                            max_epochs=epochs).model
        data = run_workflow(model, meas, ref, hold, Options(max_effects=2, max_epochs=epochs, seed=seed),
                            lambda m: None).data
    return {
        "effect": effect, "seed": seed, "named": data["named"],
        "first": data["named"][0] if data["named"] else "(nothing)",
        "before": data["holdout_rmse_before"], "after": data["holdout_rmse_after"],
        "seconds": time.perf_counter() - t0,
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--duration", type=float, default=30.0, help="seconds per recording")
    ap.add_argument("--hidden", type=int, default=8)
    ap.add_argument("--epochs", type=int, default=60)
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--effects", default=",".join(SCENARIOS))
    args = ap.parse_args(argv)
    effects = [e for e in args.effects.split(",") if e]
    jobs = [(e, s, args.duration, args.hidden, args.epochs) for e in effects for s in range(args.seeds)]
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
