"""The identification rules alone (identify/) on the confusion table's recordings.

For each hidden effect of the dynamic family (and heating and the control) and each seed: the
recordings of experiments/confusion_table.py's scenario (reference without the effect, measured
with it at the drawn strength, on the bench drawn from the seed), no network trained: the
dynamics are identified on the measured and on the reference recordings and ``which_dynamic``
says which one changed, and ``then`` which one the next round would add once that one is in the
model (none, where only one effect is hidden). Seconds a run, so the rules can be checked on many tuning seeds
(``--first-seed 100``) before the network table (about an hour) is run.

    PYTHONPATH=. python experiments/dynamic_identification.py --first-seed 100 --seeds 10
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EFFECTS = ("rotor_lag", "input_delay", "esc_deadband", "spin_down_asymmetry", "motor_heating", "control")


def recordings(effect: str, seed: int, d: Path) -> tuple[list, list, float]:
    """(measured, reference, strength): the confusion table's scenario at ``seed``, its bags in ``d``."""
    sys.path.insert(0, str(ROOT / "test"))
    import test_discrepancy as T
    from bldc_propulsion.recordings import load_signals
    from bldc_propulsion.sim import random_bench as rb

    bench = rb.draw_bench(seed)
    strength = rb.draw_strength(effect, seed) if effect != "control" else 1.0
    _, ref_extra, meas_spec, _ = T.SCENARIOS[effect]
    off = {} if effect == "control" else {effect: 0.0}
    on = {} if effect == "control" else {effect: strength}
    ref = [T._bag(d, f"ref{k}_{kd}", kd, 100 + 100 * k + seed, off, soc, dur, bench)
           for k, (kd, soc, dur) in enumerate([*T.REF, *ref_extra])]
    meas = [T._bag(d, f"measured{k}_{kd}", kd, 500 + 10 * seed + k, on, soc, dur, bench)
            for k, (kd, soc, dur) in enumerate(meas_spec)]
    return [load_signals(p) for p in meas], [load_signals(p) for p in ref], strength


def one(effect: str, seed: int) -> dict:
    from bldc_propulsion.discrepancy import identify as idf

    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as d:
        meas, ref, strength = recordings(effect, seed, Path(d))
        m, r = idf.identify_dynamics(meas), idf.identify_dynamics(ref)
        m.start_level = idf.identify_start_level(meas, m)
        r.start_level = idf.identify_start_level(ref, r)
        heat = idf.identify_heating(meas, ref)
        steps = idf.step_dynamics(meas, ref, start_level=m.start_level)
    # as refine applies them: heating first (its response to the thermal state), then the dynamics
    choice, why = ("motor_heating", heat.describe()) if heat.changed else idf.which_dynamic(m, r, steps=steps)
    # the next round, as the loop asks it once the first is in the model: what else changed
    then = (idf.which_dynamic(m, r, exclude=[choice], steps=steps)[0]
            if choice in (*idf.DYNAMIC_EFFECTS, "esc_deadband") else None)
    return {"effect": effect, "seed": seed, "strength": strength, "choice": choice or "(nothing)", "why": why,
            "then": then or "(nothing)",
            "measured": m, "reference": r, "steps": steps, "heating": heat,
            "seconds": time.perf_counter() - t0}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--first-seed", type=int, default=100)
    ap.add_argument("--effects", default=",".join(EFFECTS))
    ap.add_argument("--verbose", action="store_true", help="the step-response comparisons too")
    args = ap.parse_args(argv)
    effects = [e for e in args.effects.split(",") if e]
    right = second = 0
    rows = []
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        for e in effects:
            r = one(e, seed)
            rows.append(r)
            want = e if e in (*idf_family(), "motor_heating") else "(nothing)"
            ok = r["choice"] == want
            right += ok
            second += r["then"] != "(nothing)"
            m, f = r["measured"], r["reference"]
            print(f"{e:20s} seed {seed} s={r['strength']:.2f} -> {r['choice']:20s} {'ok ' if ok else 'BAD'} "
                  f"d {1000 * f.delay_s:.0f}->{1000 * m.delay_s:.0f} ms  up {f.tau_up_s:.2f}->{m.tau_up_s:.2f}  "
                  f"down {f.tau_down_s:.2f}->{m.tau_down_s:.2f}  start {f.start_level:.3f}->{m.start_level:.3f}  "
                  f"heat {r['heating'].changed} drop {r['heating'].drop_rad_s:.1f} rad/s z {r['heating'].z:.1f} "
                  f"hottest {r['heating'].hottest:.2f}  then {r['then']}  ({r['seconds']:.0f} s)", flush=True)
            if args.verbose:
                st = r["steps"]
                for k, x in (("dead", st.dead_time), ("up", st.spin_up), ("down", st.spin_down)):
                    if x is not None:
                        print(f"    {k:5s} {x.measured:.3f} vs {x.reference:.3f} -> {x.change:.2f} p={x.p_value:.2g} "
                              f"n={x.n_measured}/{x.n_reference}{' CHANGED' if x.changed else ''}")
                print(f"    start {st.start_level}")
                sh = st.start_level_shift
                if sh is not None:
                    print(f"    shift {sh.reference:.4f}->{sh.measured:.4f} F={sh.f_stat:.1f} p={sh.p_value:.2g} "
                          f"n={sh.n_measured}/{sh.n_reference}{' CHANGED' if sh.changed else ''}")
    print(f"right: {right}/{len(rows)}; a second dynamic effect named after the first: {second}")
    return 0


def idf_family() -> tuple[str, ...]:
    from bldc_propulsion.discrepancy.identify import DYNAMIC_EFFECTS
    return (*DYNAMIC_EFFECTS, "esc_deadband")


if __name__ == "__main__":
    sys.exit(main())
