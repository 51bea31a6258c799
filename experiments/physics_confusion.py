"""Confusion table of `discrepancy --physics`: every hidden effect and the no-effect control.

For each effect of the contract and each seed: a bench drawn from the seed (``sim.random_bench``:
other constants, sometimes a bent throttle map or a two-RC pack; ``--nominal-bench``: the
nominal one), the hidden effect at a drawn strength (0.5-2x; 1 on the nominal bench). The model
(CONFIG) is the NOMINAL bench physics with every effect on except the hidden one. Reference
recordings (test/test_discrepancy.py's REF and the scenario's extras) lack the effect; measured and
holdout recordings (the scenario's commands and states of charge) have it. Control: reference,
measured and holdout all lack the effect the model lacks (one effect per seed in turn); for
battery_voltage all control recordings are on one pack charge (with the effect off the
simulator's supply is stiff at each pack's own starting voltage, so packs at different charges
would still differ in voltage: that IS the effect). Prints the table (true effect x first named),
the holdout RMSE reduction and the fitted strength vs the truth in the nominal model's units
(``random_bench.model_strength``), median [min, max] over seeds; for rotor_lag and motor_heating
also what the recordings identify on any split of winding resistance and propeller drag (the
spin-up time constant, the full-drive speed lost once warm: ``physics.fitted_value``) vs the
drawn bench's own value. ``--far-bench``: benches of another motor class
(``random_bench.draw_far_bench``), where the CONFIG-unit strengths of those two are off by the
split and the identified values are the check.

    PYTHONPATH=. python experiments/physics_confusion.py --seeds 5 --jobs 2

``--oracle`` gives the model the drawn bench's constants instead of the nominal ones: what the
workflow reaches with a perfect CONFIG (a ceiling for the reductions).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from bldc_propulsion import contract as c

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "test"))
sys.path.insert(0, str(ROOT / "benchmarks"))
from results import check_record_path, write_record  # noqa: E402


def one_run(effect: str, seed: int, control: bool, bench_kind: str, tmp: str, oracle: bool = False) -> dict:
    import test_discrepancy as T
    from bldc_propulsion.discrepancy import physics as ph
    from bldc_propulsion.discrepancy.workflow import Options, run_physics_workflow
    from bldc_propulsion.physics import config as pc
    from bldc_propulsion.physics.params import BenchParams
    from bldc_propulsion.recordings import load_signals
    from bldc_propulsion.sim import random_bench as rb

    bench = rb.DRAWS[bench_kind](seed) if bench_kind != "nominal" else None
    strength = rb.draw_strength(effect, seed) if bench_kind != "nominal" else 1.0
    _, ref_extra, meas_spec, hold_spec = T.SCENARIOS[effect]
    ref_spec = [*T.REF, *ref_extra]
    if control and effect == "battery_voltage":
        meas_spec = [(kd, 1.0, dur) for kd, _, dur in meas_spec]
        hold_spec = [(kd, 1.0, dur) for kd, _, dur in hold_spec]
    off = {effect: 0.0}
    on = off if control else {effect: strength}
    sub = Path(tmp) / f"{effect}_{seed}_{'control' if control else 'on'}"
    sub.mkdir()

    def bags(spec: list, tag: str, seed0: int, eff: dict) -> list:
        return [load_signals(T._bag(sub, f"{tag}{k}_{kd}", kd, seed0 + 100 * seed + k, eff, soc, dur, bench))
                for k, (kd, soc, dur) in enumerate(spec)]

    ref = bags(ref_spec, "r", 4000, off)
    meas = bags(meas_spec, "m", 5000, on)
    hold = bags(hold_spec, "h", 6000, on)
    params = pc.load_config(None).params
    if oracle and bench is not None:  # the drawn bench's every constant as the CONFIG: a ceiling
        params = dataclasses.replace(bench, sim_step_s=params.sim_step_s)
    model = pc.PhysicsConfig(params, {**{e: 1.0 for e in c.EFFECTS}, effect: 0.0})
    t0 = time.perf_counter()
    data = run_physics_workflow(model, meas, ref, hold, Options(max_effects=2), lambda m: None).data
    fitted = data["evidence"].get(effect, {}).get("fitted_parameters", {}) if not control else {}
    truth = rb.model_strength(effect, strength, bench or pc.load_config(None).params)
    value = data["evidence"].get(effect, {}).get("fitted_value") or {} if effect in data["named"] else {}
    shown = true_shown = float("nan")  # what the recordings identify (plant.spin_up_time_constant_s)
    if "time_constant_ms" in value or "warm_speed_loss_percent" in value:
        from bldc_propulsion.physics import plant

        b = bench or BenchParams()
        if effect == "rotor_lag":  # at the model's speed (the time constant depends on it)
            shown, true_shown = value["time_constant_ms"], 1000.0 * plant.spin_up_time_constant_s(
                b, {"rotor_lag": strength}, value["at_speed_rad_s"])
        else:  # the same quantity on the bench itself
            shown, true_shown = value["warm_speed_loss_percent"], ph.fitted_value(
                effect, strength, b, value["supply_v"])["warm_speed_loss_percent"]
    return {"effect": "control" if control else effect, "hidden": effect, "seed": seed, "named": data["named"],
            "first": data["named"][0] if data["named"] else "(nothing)",
            "before": data["holdout_rmse_before"], "after": data["holdout_rmse_after"],
            "strength": fitted.get("strength", float("nan")) if effect in data["named"] else float("nan"),
            "truth": truth, "shown": shown, "true_shown": true_shown, "seconds": time.perf_counter() - t0}


def print_table(rows: list[dict], effects: list[str]) -> None:
    """The confusion table, holdout RMSE reduction and fitted strength / truth (median [min, max])."""
    print(f"\n{len(rows)} runs, seeds {', '.join(map(str, sorted({r['seed'] for r in rows})))}")
    cols = [*c.EFFECTS, "(nothing)"]
    short = {"battery_voltage": "battery", "spin_down_asymmetry": "spin_down", "motor_heating": "heating",
             "esc_deadband": "deadband"}
    print("true \\ first named   " + " ".join(f"{short.get(x, x):>11s}" for x in cols) + "  correct")
    for true in [*effects, "control"]:
        mine = [r for r in rows if r["effect"] == true]
        want = "(nothing)" if true == "control" else true
        counts = [sum(r["first"] == x for r in mine) for x in cols]
        ok = sum(r["first"] == want for r in mine)
        print(f"{true:20s} " + " ".join(f"{n:11d}" for n in counts) + f"  {ok}/{len(mine)}")
    print("holdout RMSE reduction, median [min, max] over seeds; fitted strength / truth (nominal model's "
          "units), median [min, max], where the effect was named")
    for true in [*effects, "control"]:
        mine = [r for r in rows if r["effect"] == true]
        red = [100 * (1 - r["after"] / r["before"]) for r in mine]
        ratio = [r["strength"] / r["truth"] for r in mine if np.isfinite(r["strength"])]
        line = f"  {true:20s} {np.median(red):5.1f} % [{min(red):.1f}, {max(red):.1f}]"
        if ratio:
            within = sum(abs(x - 1.0) <= 0.3 for x in ratio)
            line += (f"   strength/truth {np.median(ratio):.2f} [{min(ratio):.2f}, {max(ratio):.2f}], "
                     f"{within}/{len(ratio)} within 30 %")
        shown = [r["shown"] / r["true_shown"] for r in mine if np.isfinite(r.get("shown", math.nan))]
        if shown:
            what = "time constant" if true == "rotor_lag" else "warm speed loss"
            line += (f"; {what} / truth {np.median(shown):.2f} [{min(shown):.2f}, {max(shown):.2f}], "
                     f"{sum(abs(x - 1.0) <= 0.3 for x in shown)}/{len(shown)} within 30 %")
        if true == "control":
            line += f"   false names: {sum(len(r['named']) for r in mine)}"
        print(line)
    right = sum(r["first"] == ("(nothing)" if r["effect"] == "control" else r["effect"]) for r in rows)
    print(f"named right first: {right}/{len(rows)}; {len(rows)} runs, workflow "
          f"{sum(r['seconds'] for r in rows):.0f} s in total", flush=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--first-seed", type=int, default=0, help="seeds first-seed .. first-seed+seeds-1")
    which = ap.add_mutually_exclusive_group()
    which.add_argument("--nominal-bench", action="store_true", help="the nominal bench, hidden effects at 1")
    which.add_argument("--far-bench", action="store_true",
                    help="benches of another motor class (random_bench.draw_far_bench: 3S/4S, other speed and power)")
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--effects", default=",".join(c.EFFECTS))
    ap.add_argument("--oracle", action="store_true",
                    help="the drawn bench's constants as the CONFIG instead of the nominal ones "
                         "(what a perfect CONFIG would give)")
    ap.add_argument("--json", metavar="PATH", help="also write every run to PATH (benchmarks/results.py renders them)")
    args = ap.parse_args(argv)
    check_record_path(args.json)
    t_all = time.perf_counter()
    effects = [e for e in args.effects.split(",") if e]
    unknown = [e for e in effects if e not in c.EFFECTS]
    if unknown:  # the control runs on every seed anyway
        ap.error(f"--effects: unknown {', '.join(unknown)} (known: {', '.join(c.EFFECTS)}; the control always runs)")
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    kind = "nominal" if args.nominal_bench else "far" if args.far_bench else "random"
    print(f"{kind} benches, seeds {seeds.start}-{seeds.stop - 1}")
    jobs = [(e, s, ctl) for s in seeds
            for e, ctl in [*((e, False) for e in effects), (c.EFFECTS[s % len(c.EFFECTS)], True)]]
    rows = []
    with tempfile.TemporaryDirectory() as tmp, ProcessPoolExecutor(max_workers=args.jobs) as pool:
        futs = [pool.submit(one_run, e, s, ctl, kind, tmp, args.oracle) for e, s, ctl in jobs]
        for f in futs:
            r = f.result()
            rows.append(r)
            print(f"{r['effect']:20s} seed {r['seed']}: named {r['named'] or 'nothing'}; holdout "
                  f"{r['before']:.1f} -> {r['after']:.1f} rad/s; strength {r['strength']:.2f} (truth "
                  f"{r['truth']:.2f}) ({r['seconds']:.0f} s)", file=sys.stderr, flush=True)
            if len(rows) % (len(effects) + 1) == 0:  # a seed complete: the table so far
                print_table(rows, effects)
    if args.json:
        write_record(args.json, {"bench": kind, "oracle": args.oracle, "runs": rows},
                     seconds=time.perf_counter() - t_all)
    return 0


if __name__ == "__main__":
    sys.exit(main())
