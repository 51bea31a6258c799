"""Confusion table of `discrepancy --physics`: every hidden effect and the no-effect control.

For each effect of the contract and each seed: the bench physics with every effect on except
that one as the model (CONFIG), measured and holdout recordings of test/test_discrepancy.py's
scenario for the effect (same commands and states of charge, recordings drawn from the seed)
with all effects on. Control: the same, but the recordings lack the effect too (the model is
then right), one effect per seed in turn; for battery_voltage all control recordings are on one
pack charge (with the effect off the simulator's supply is stiff at the pack's starting voltage,
so packs at different charges still differ in voltage: that IS the effect, and it is named). Prints the table (true effect x first named effect),
the median holdout RMSE reduction and the median fitted strength (truth: 1).

    PYTHONPATH=. python experiments/physics_confusion.py --seeds 5
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bldc_propulsion import contract as c

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "test"))


def one_run(d: Path, effect: str, seed: int, control: bool) -> dict:
    import test_discrepancy as T
    from bldc_propulsion.discrepancy import physics as ph
    from bldc_propulsion.discrepancy.physics_workflow import run_physics_workflow
    from bldc_propulsion.discrepancy.workflow import Options
    from bldc_propulsion.training.dataset import load_signals

    _, _, meas_spec, hold_spec = T.SCENARIOS[effect]
    if control and effect == "battery_voltage":
        meas_spec = [(kd, 1.0, dur) for kd, _, dur in meas_spec]
        hold_spec = [(kd, 1.0, dur) for kd, _, dur in hold_spec]
    rec_effects = {effect: 0.0} if control else {}
    sub = d / f"{effect}_{seed}_{'control' if control else 'on'}"
    sub.mkdir()
    meas = [T._bag(sub, f"m{k}_{kd}", kd, 5000 + 100 * seed + k, rec_effects, soc, dur)
            for k, (kd, soc, dur) in enumerate(meas_spec)]
    hold = [T._bag(sub, f"h{k}_{kd}", kd, 6000 + 100 * seed + k, rec_effects, soc, dur)
            for k, (kd, soc, dur) in enumerate(hold_spec)]
    model = ph.PhysicsModel(ph.load_config(None).params, {**{e: 1.0 for e in c.EFFECTS}, effect: 0.0})
    t0 = time.perf_counter()
    data = run_physics_workflow(model, [load_signals(p) for p in meas], [], [load_signals(p) for p in hold],
                                Options(max_effects=2), lambda m: None).data
    fitted = data["evidence"].get(effect, {}).get("fitted_parameters", {})
    return {"effect": "control" if control else effect, "seed": seed,
            "first": data["named"][0] if data["named"] else "(nothing)",
            "before": data["holdout_rmse_before"], "after": data["holdout_rmse_after"],
            "strength": fitted.get("strength", float("nan")), "seconds": time.perf_counter() - t0}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    args = ap.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(args.seeds):
            for effect in c.EFFECTS:
                rows.append(one_run(Path(tmp), effect, seed, control=False))
                print(rows[-1], file=sys.stderr, flush=True)
            rows.append(one_run(Path(tmp), c.EFFECTS[seed % len(c.EFFECTS)], seed, control=True))
            print(rows[-1], file=sys.stderr, flush=True)
    cols = [*c.EFFECTS, "(nothing)"]
    short = {"battery_voltage": "battery", "spin_down_asymmetry": "spin_down", "motor_heating": "heating",
             "esc_deadband": "deadband"}
    print("true \\ first named   " + " ".join(f"{short.get(x, x):>11s}" for x in cols) + "  correct")
    for true in [*c.EFFECTS, "control"]:
        mine = [r for r in rows if r["effect"] == true]
        want = "(nothing)" if true == "control" else true
        counts = [sum(r["first"] == x for r in mine) for x in cols]
        ok = sum(r["first"] == want for r in mine)
        print(f"{true:20s} " + " ".join(f"{n:11d}" for n in counts) + f"  {ok}/{len(mine)}")
    print("median holdout RMSE reduction / fitted strength (truth 1):")
    for true in [*c.EFFECTS, "control"]:
        mine = [r for r in rows if r["effect"] == true]
        red = np.median([100 * (1 - r["after"] / r["before"]) for r in mine])
        st = np.nanmedian([r["strength"] for r in mine]) if true != "control" else float("nan")
        print(f"  {true:20s} {red:5.1f} %" + (f"   strength {st:.2f}" if np.isfinite(st) else ""))
    print(f"{len(rows)} runs, workflow {sum(r['seconds'] for r in rows):.0f} s in total")
    return 0


if __name__ == "__main__":
    sys.exit(main())
