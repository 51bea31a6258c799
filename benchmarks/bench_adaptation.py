"""Online adaptation on randomized benches (issue 34 item 1): recovery after a change, and no harm
on healthy flights.

Per bench seed (``sim.random_bench.draw_bench``): a physics model fitted on a HEALTHY recording of
that bench (``bench_health.fit_model``), then flights on the same bench (``--profile``: a
multirotor's motor by default, ``random_steps`` a bench's experiment), with a fault injected
at a random onset and without; each flight's streams (the tachometer decoded, the
battery ADC through the battery filter: ``bench_health.streams``) go through the estimator with
and without adaptation, predicting on a 100 Hz grid, against the simulator's true speed.

Printed per fault (spread over the runs: median and worst), against two references for "the
pre-change level":

* the TWIN: the same flight simulated without the fault (same seed, state of charge and
  command; the fault only changes the bench from its onset on), run through the same estimator.
  The level the estimator would have had at the same seconds had nothing changed: the RMSE after
  the change (onset + 10 s .. + 30 s) over the twin's in the same window, and the recovery time
  (the earliest time after the onset from which a 10 s window's RMSE is within 1.2x of the
  twin's in the same window);
* the seconds BEFORE the onset (onset - 20 s .. onset) of the same flight: post/pre and its
  recovery time as above. This compares different seconds of a flight of random steps, which
  differ in difficulty: the healthy twin's own post/pre (printed) spreads as wide as a fault's.

And the adapted parameters at the end. Healthy flights: adapted RMSE / offline RMSE over the
whole flight. The issue's goals: back within 1.2x within 10 s; healthy ratio <= 1.05.
The adapter's settings (core.adaptation.AdaptationConfig) were tuned on bench seeds 1-3 only;
the reported benches are seeds from --first-seed (default 300), disjoint from them.

    .venv/bin/python benchmarks/bench_adaptation.py --seeds 4 --flights 1 [--profile random_steps] [--json PATH]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_health import fit_model, streams  # noqa: E402
from results import check_record_path, pack_change, write_record  # noqa: E402

from bldc_propulsion.core.adaptation import (  # noqa: E402
    ADAPTED,
    AdaptationConfig,
    adapted_params,
    adapter_for,
)
from bldc_propulsion.core.estimator import ThrustEstimator  # noqa: E402
from bldc_propulsion.core.health import HealthStream, require_physics  # noqa: E402
from bldc_propulsion.physics.params import BenchParams  # noqa: E402
from bldc_propulsion.sim import PROFILES, simulate  # noqa: E402
from bldc_propulsion.sim.faults import Fault, apply_fault  # noqa: E402
from bldc_propulsion.sim.random_bench import draw_bench  # noqa: E402

#: The faults judged, at sizes a vehicle meets (the health monitor's goals plus friction).
FAULTS = {"propeller_damage": 0.1, "bearing_friction": 3.0, "motor_heating": 30.0, "pack_resistance": 2.0}
TUNING_BENCHES = [1, 2, 3]
FLIGHT_S = 100.0
ONSET_RANGE_S = (40.0, 60.0)
PRE_S = 20.0  #: the pre-change RMSE's window, before the onset
POST_S = (10.0, 30.0)  #: the post-change RMSE's window, after the onset
RECOVERY_WINDOW_S = 10.0
GOAL_RATIO = 1.2
GOAL_HEALTHY = 1.05
GRID_HZ = 100.0
#: The offline model's values in ADAPTED order (no loss, the friction's factor 1, its resistance unknown here)
OFFLINE = [0.0, 1.0, math.nan]


def run_flight(model: Any, res: Any, config: AdaptationConfig | None = None, adapt: bool = True, *,
               speed: Callable[[float, float], float | None] | None = None, states: bool = False,
               keep: bool = False, health: bool = False) -> dict[str, Any]:
    """A simulated flight's streams through the estimator (adapting or not), merged in time
    order as a node receives them, predicting on a GRID_HZ grid: the grid times, the predicted
    and true speeds and thrusts there (NaN: no thrust), and the adapted parameters' values after
    each prediction (with ``states``, the adaptation's state too; with ``keep``, the estimator).
    ``speed``: what the tachometer says, given the time and the decoded speed (None: no sample).
    ``health``: the health monitor watches the same inputs (``core.health.HealthStream``), and a
    change it names is passed to the adapter; its events are returned too."""
    pwm, volt, measured = streams(res)
    if speed is not None:
        pairs = [(t, speed(t, w)) for t, w in zip(measured[0].tolist(), measured[1].tolist(), strict=True)]
        kept = [(t, w) for t, w in pairs if w is not None]
        measured = (np.array([t for t, _ in kept]), np.array([w for _, w in kept]))
    est = ThrustEstimator(model, adapter=adapter_for(model, config) if adapt else None)
    grid = np.arange(math.ceil(float(pwm[0][0]) * GRID_HZ), math.floor(float(res.truth_t[-1]) * GRID_HZ)) / GRID_HZ
    t_all = np.concatenate([pwm[0], volt[0], measured[0], grid])
    x_all = np.concatenate([pwm[1], volt[1], measured[1], np.zeros(len(grid))])
    k_all = np.concatenate([np.zeros(len(pwm[0])), np.ones(len(volt[0])), np.full(len(measured[0]), 2.0),
                            np.full(len(grid), 3.0)])
    order = np.lexsort((k_all, t_all))
    out_t, out_w, out_f, theta, state = [], [], [], [], []
    feed = (est.update_pwm, est.update_voltage, est.update_speed)
    monitor = HealthStream(est) if health else None
    watch = (None, None, None) if monitor is None else (monitor.update_pwm, monitor.update_voltage,
                                                         monitor.update_speed)
    for t, kind, x in zip(t_all[order].tolist(), k_all[order].tolist(), x_all[order].tolist(), strict=True):
        if kind < 3.0:
            then = watch[int(kind)]
            if feed[int(kind)](t, x) and then is not None:
                then(t, x)
            continue
        p = est.predict(t)
        if p.ready:
            out_t.append(t)
            out_w.append(p.speed_rad_s)
            out_f.append(math.nan if p.thrust_n is None else p.thrust_n)
            theta.append([v for v, _ in est.adapter.values().values()] if est.adapter is not None else OFFLINE)
            if states:
                state.append(est.adaptation_state())
    tt = np.asarray(out_t)
    out: dict[str, Any] = {"t": tt, "predicted": np.asarray(out_w), "theta": np.asarray(theta),
                           "truth": np.interp(tt, res.truth_t, res.truth_speed), "thrust": np.asarray(out_f),
                           "truth_thrust": np.interp(tt, res.truth_t, res.truth_thrust)}
    if states:
        out["states"] = state
    if monitor is not None:
        monitor.finish()
        out["events"] = [e.as_dict() for e in monitor.events]
    if keep:
        out["estimator"] = est
    return out


def rmse(run: dict[str, Any], t0: float, t1: float) -> float:
    """RMSE (rad/s) of the prediction against the truth over [t0, t1)."""
    sel = (run["t"] >= t0) & (run["t"] < t1)
    return float(np.sqrt(np.mean((run["predicted"][sel] - run["truth"][sel]) ** 2))) if sel.any() else math.nan


def thrust_rmse(run: dict[str, Any], t0: float, t1: float) -> float:
    """RMSE (N) of the predicted thrust against the simulator's over [t0, t1); NaN without a thrust."""
    sel = (run["t"] >= t0) & (run["t"] < t1)
    return float(np.sqrt(np.mean((run["thrust"][sel] - run["truth_thrust"][sel]) ** 2))) if sel.any() else math.nan


def recovery_s(run: dict[str, Any], onset: float, level: Callable[[float, float], float]) -> float | None:
    """The earliest time after the onset (0.5 s steps) from which a RECOVERY_WINDOW_S window's
    RMSE is within GOAL_RATIO of ``level`` over the same window (a constant: the pre-change RMSE;
    the twin's RMSE there); None if never before the flight ends."""
    end = float(run["t"][-1]) - RECOVERY_WINDOW_S
    for tau in np.arange(0.0, end - onset, 0.5):
        t0, t1 = onset + tau, onset + tau + RECOVERY_WINDOW_S
        if rmse(run, t0, t1) <= GOAL_RATIO * level(t0, t1):
            return float(tau)
    return None


#: The faults ``told`` can give the model: not a bearing's friction, whose constant (the no-load
#: current) the fit holds at its default where the data do not tell it (0.4 A on benches 4-7, whose
#: own are 0.21-0.58 A) with the other constants standing in for the rest, so adding the bench's
#: change to it is no reference (told, the flights of benches 4-7 came within 1.2x 2/8; adapted 5/8).
TOLD = ("propeller_damage", "motor_heating", "pack_resistance")


def told(model: Any, bench: BenchParams, fault: Fault) -> Any:
    """The model told the fault's truth (one of ``TOLD``): its constants moved as the simulator
    moved the bench's (``sim.faults.apply_fault``), along the adapter's own parameters. A
    propeller's loss and a hot winding as they are; the pack's series resistance by what the fault
    adds to the BENCH's (the model's own was fitted, or held at a default, beside its other
    constants, so a factor on it would not be the change)."""
    plant = require_physics(model, "bench_adaptation", "")
    theta, pack, heat = [0.0, 0.0], None, 0.0
    if fault.name == "propeller_damage":
        theta[0] = fault.size
    elif fault.name == "pack_resistance":
        pack = (plant.params.battery_series_resistance_ohm + apply_fault(bench, fault).battery_series_resistance_ohm
                - bench.battery_series_resistance_ohm)
    else:
        assert fault.name == "motor_heating", fault.name
        heat = fault.size
    return dataclasses.replace(plant, params=adapted_params(plant.params, theta, 1.0, pack, heat))


def judge(model: Any, res: Any, fault: Fault, twin: Any, config: AdaptationConfig | None = None,
          health: bool = False, bench: BenchParams | None = None) -> dict[str, Any]:
    """One faulted flight: RMSE after the change over the twin's (``twin``: the same flight
    without the fault) and over the seconds before the onset, adapted and offline, with their
    recovery times; the thrust's RMSE after the change; the adapted parameters at the end. With
    the ``bench``: the RMSE after the change of the model told it (``told``, not adapting) over the
    offline twin's: whether the model can hold the change at all, so that a miss of the adapter is
    the estimator's (told within the goal) or the model's structure's (told not)."""
    out: dict[str, Any] = {}
    o = fault.onset_s
    if bench is not None and fault.name in TOLD:
        post = rmse(run_flight(told(model, bench, fault), res, adapt=False), o + POST_S[0], o + POST_S[1])
        out["told"] = {"post_rad_s": post}
    for label, adapt in (("adapted", True), ("offline", False)):
        run = run_flight(model, res, config, adapt, health=health and adapt)
        pre = rmse(run, o - PRE_S, o)
        post = rmse(run, o + POST_S[0], o + POST_S[1])
        out[label] = {"pre_rad_s": pre, "post_rad_s": post, "ratio": post / pre,
                      "recovery_s": recovery_s(run, o, lambda t0, t1, pre=pre: pre),
                      "thrust_post_n": thrust_rmse(run, o + POST_S[0], o + POST_S[1])}
        tw = run_flight(model, twin, config, adapt, health=health and adapt)
        twin_post = rmse(tw, o + POST_S[0], o + POST_S[1])
        out[label] |= {"twin_post_rad_s": twin_post, "vs_twin": post / twin_post,
                       "twin_ratio": twin_post / rmse(tw, o - PRE_S, o),
                       "recovery_vs_twin_s": recovery_s(run, o, lambda t0, t1, tw=tw: rmse(tw, t0, t1))}
        if not adapt and "told" in out:  # against the offline twin: the model, not the estimator
            out["told"]["vs_twin"] = out["told"]["post_rad_s"] / twin_post
        if adapt:
            out["final"] = {n: float(v) for n, v in zip(ADAPTED, run["theta"][-1], strict=True)}
            out["final_twin"] = {n: float(v) for n, v in zip(ADAPTED, tw["theta"][-1], strict=True)}
            if health:
                out["events"], out["events_twin"] = run["events"], tw["events"]
    return out


def healthy_ratio(model: Any, res: Any, config: AdaptationConfig | None = None,
                  health: bool = False) -> dict[str, Any]:
    """A healthy flight: adapted and offline RMSE over the flight (after the first 5 s) and their ratio."""
    a, o = (run_flight(model, res, config, adapt, health=health and adapt) for adapt in (True, False))
    t0, t1 = float(a["t"][0]) + 5.0, float(a["t"][-1]) + 1.0
    ra, ro = rmse(a, t0, t1), rmse(o, t0, t1)
    return {"adapted_rad_s": ra, "offline_rad_s": ro, "ratio": ra / ro,
            **{n: float(v) for n, v in zip(ADAPTED, a["theta"][-1], strict=True)},
            **({"events": a["events"]} if health else {})}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=4, help="benches (default 4)")
    ap.add_argument("--first-seed", type=int, default=300, help="first bench seed (default 300; tuning used 1-3)")
    ap.add_argument("--flights", type=int, default=1, help="flights per fault and bench, and healthy ones (default 1)")
    ap.add_argument("--profile", choices=sorted(PROFILES), default="flight",
                    help="the flights' command profile (default flight: a multirotor's motor, never stopped; "
                         "random_steps: a bench's experiment over the whole range)")
    ap.add_argument("--health", action="store_true",
                    help="the health monitor watches too and a change it names is passed to the adapter "
                         "(replay --adapt --health, the node with both on)")
    ap.add_argument("--json", metavar="PATH", help="also write the figures to PATH")
    args = ap.parse_args()
    check_record_path(args.json)
    t_start = time.perf_counter()
    rng = np.random.default_rng(4321)
    runs: dict[str, list[dict[str, Any]]] = {name: [] for name in FAULTS}
    healthy: list[dict[str, Any]] = []
    benches = list(range(args.first_seed, args.first_seed + args.seeds))
    with tempfile.TemporaryDirectory() as d:
        for bench_seed in benches:
            model, fit_s = fit_model(bench_seed, Path(d))
            bench = draw_bench(bench_seed)
            print(f"bench {bench_seed}: model fitted in {fit_s:.0f} s", file=sys.stderr)
            for k in range(args.flights):
                for j, (name, size) in enumerate(FAULTS.items()):
                    fault = Fault(name, size, float(rng.uniform(*ONSET_RANGE_S)))
                    seed = 10_000 * bench_seed + 100 * k + j
                    soc = float(rng.uniform(0.5, 1.0))
                    res = simulate(args.profile, FLIGHT_S, seed, params=bench, soc=soc, faults=[fault])
                    twin = simulate(args.profile, FLIGHT_S, seed, params=bench, soc=soc)
                    r = {"bench": bench_seed, "seed": seed, "onset_s": fault.onset_s,
                         **judge(model, res, fault, twin, health=args.health, bench=bench)}
                    runs[name].append(r)
                    print(f"  {fault.spec}: {json.dumps(r, default=float)}", file=sys.stderr)
                seed = 10_000 * bench_seed + 5000 + k
                res = simulate(args.profile, FLIGHT_S, seed, params=bench, soc=float(rng.uniform(0.5, 1.0)))
                healthy.append({"bench": bench_seed, "seed": seed, **healthy_ratio(model, res, health=args.health)})
                print(f"  healthy: {healthy[-1]}", file=sys.stderr)
    summary = {"benches": benches, "tuning_benches": TUNING_BENCHES, "profile": args.profile, "faults": FAULTS,
               "health": args.health, "flight_s": FLIGHT_S,
               "runs": runs, "healthy": healthy, "seconds": time.perf_counter() - t_start}
    print_table(summary)
    if args.json:
        write_record(args.json, json.loads(json.dumps(summary, default=float)), seconds=summary["seconds"])


def _spread(xs: list[float | None]) -> str:
    """median / worst of a list (None: never recovered, counted as worst)."""
    if not xs:
        return "-"
    vals = [math.inf if x is None else x for x in xs]
    return f"{float(np.median(vals)):.2f} / {max(vals):.2f}"


def _range(xs: list[float]) -> str:
    """lowest - highest of a list."""
    return f"{min(xs):.2f} - {max(xs):.2f}" if xs else "-"


def print_table(s: dict[str, Any]) -> None:
    print(f"benches {s['benches']} (tuned on {s['tuning_benches']}), {s.get('profile', 'random_steps')} flights, "
          f"{s['seconds']:.0f} s")
    print("| fault (size) | runs | after / twin, adapted: median / worst | offline | recovery to 1.2x twin (s) | "
          "within 1.2x from 10 s on | post/pre adapted | offline | recovery to 1.2x pre (s) | "
          "within 1.2x from 10 s on | twin's own post/pre | thrust RMSE after, adapted / offline (N, median) | "
          "adapted values at the end (median) |")
    print("|---" * 13 + "|")
    for name, rows in s["runs"].items():
        ok_twin = sum(r["adapted"]["vs_twin"] <= GOAL_RATIO for r in rows)
        ok = sum(r["adapted"]["ratio"] <= GOAL_RATIO for r in rows)
        finals = {k: float(np.median([r["final"][k] for r in rows])) for k in ("propeller_damage", "bearing_friction")}
        print(f"| {name} ({s['faults'][name]:g}) | {len(rows)} | {_spread([r['adapted']['vs_twin'] for r in rows])} | "
              f"{_spread([r['offline']['vs_twin'] for r in rows])} | "
              f"{_spread([r['adapted']['recovery_vs_twin_s'] for r in rows])} | {ok_twin}/{len(rows)} | "
              f"{_spread([r['adapted']['ratio'] for r in rows])} | {_spread([r['offline']['ratio'] for r in rows])} | "
              f"{_spread([r['adapted']['recovery_s'] for r in rows])} | {ok}/{len(rows)} | "
              f"{_range([r['adapted']['twin_ratio'] for r in rows])} | "
              f"{np.median([r['adapted']['thrust_post_n'] for r in rows]):.3f} / "
              f"{np.median([r['offline']['thrust_post_n'] for r in rows]):.3f} | "
              f"propeller {finals['propeller_damage']:.3f}, friction x{finals['bearing_friction']:.2f}"
              f"{pack_change(rows)} |")
    for name, rows in s["runs"].items():
        told = [r["told"]["vs_twin"] for r in rows if "told" in r]
        if told:
            print(f"{name} told the change: after / twin {_spread(told)} "
                  f"(within {GOAL_RATIO}x: {sum(x <= GOAL_RATIO for x in told)}/{len(told)})")
    h = s["healthy"]
    ok = sum(r["ratio"] <= GOAL_HEALTHY for r in h)
    print(f"healthy: {len(h)} flights, adapted/offline RMSE median / worst {_spread([r['ratio'] for r in h])} "
          f"(goal <= {GOAL_HEALTHY}: {ok}/{len(h)})")


if __name__ == "__main__":
    main()
