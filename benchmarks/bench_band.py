"""Issue 34 item 2's goal: the one-sigma speed band calibrated on held-out recordings, every kind.

Usage::

    taskset -c 1 python benchmarks/bench_band.py [--seeds 3-6] [--kinds network,physics,hybrid]
                                                 [--restarts 2] [--keep DIR] [--json PATH]

Per bench seed, the bench, training and validation recordings and the three kinds are those of
``bench_accuracy.py`` (small size: staircases and triangles at seven charges, random steps at two
for validation); each model's band is fitted on the validation recordings only, as ``train``
fits it. Held out (never seen by the training or the band): the chirp and the low-charge random
steps of the accuracy benchmark, and random steps, a staircase and a multirotor's motor in flight
(the ``flight`` profile: never stopped, moved every frame) of other seeds at charges between the
training ones. Printed per kind: the share of measured speeds inside +-1 sigma
(``evaluate``'s ``band_coverage``) pooled over every held-out recording of every bench, with
the median [min, max] over benches and over recordings; per profile; and the mean sigma. The
goal: 60-76 % pooled, every kind.

Why pooled: the residual of a model is mostly a bias that depends on the operating points and
the history a recording visits (which levels, how deep the pack sags), so one 40 s recording
holds only a dozen or so independent samples of it: on the nominal bench, the coverage of single
40 s recordings spread over 50-85 % even for a band fitted on those very recordings.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bldc_propulsion.recordings import Signals, load_signals
from bldc_propulsion.sim import simulate
from bldc_propulsion.sim.record import write_sim_bag
from bldc_propulsion.training.evaluate import BandCoverage, evaluate

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_accuracy as acc  # noqa: E402
from results import check_record_path, write_record  # noqa: E402

#: The goal (issue 34): pooled coverage at one sigma on held-out recordings, %.
GOAL_PERCENT = (60.0, 76.0)
#: Held-out recordings beyond bench_accuracy's two tests: (name, profile, seconds, charge).
MORE_TESTS = (("steps", "random_steps", 40.0, 0.7), ("staircase", "staircase", 40.0, 0.6),
              ("flight", "flight", 40.0, 0.65))


def held_out(d: Path, seed: int | None, size: acc.Size) -> dict[str, Signals]:
    """Every held-out recording of one bench: bench_accuracy's tests and ``MORE_TESTS``."""
    _, _, tests = acc.recordings(d, seed, size)
    params, effects, _ = acc.bench_of(seed)
    base = 1000 * (seed + 1 if seed is not None else 0)
    for k, (name, profile, seconds, soc) in enumerate(MORE_TESTS):
        path = d / f"bench{seed}_{profile}_{50 + k}_{soc}"
        if not path.exists():
            write_sim_bag(simulate(profile, seconds, base + 50 + k, effects=effects, soc=soc, params=params), path)
        tests[name] = load_signals(path)
    return tests


def total(parts: list[BandCoverage]) -> BandCoverage:
    return sum(parts[1:], parts[0])


def spread(values: list[float]) -> str:
    v = np.asarray(values, dtype=float)
    return f"{np.median(v):5.1f} [{v.min():5.1f}, {v.max():5.1f}]"


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=acc._seeds, default=acc._seeds("3-6"),
                    help="bench seeds: 3-6 (default), 0,2,7 or nominal")
    ap.add_argument("--kinds", default=",".join(acc.KINDS), help="comma-separated model kinds (default: all three)")
    ap.add_argument("--restarts", type=int, default=2, help="LM restarts of each network (default 2)")
    ap.add_argument("--keep", metavar="DIR", help="keep (and reuse) the simulated bags here")
    ap.add_argument("--json", metavar="PATH", help="also write the figures to PATH")
    args = ap.parse_args(argv)
    check_record_path(args.json)
    kinds = [k for k in args.kinds.split(",") if k]
    if unknown := set(kinds) - set(acc.KINDS):
        ap.error(f"--kinds: unknown {', '.join(sorted(unknown))} (known: {', '.join(acc.KINDS)})")
    size = acc.SIZES["small"]
    tmp = None if args.keep else tempfile.TemporaryDirectory()
    d = Path(args.keep or tmp.name)
    d.mkdir(parents=True, exist_ok=True)
    print(f"{len(args.seeds)} bench(es), kinds {', '.join(kinds)}; band fitted on {len(size.validation_socs)} "
          f"validation recordings per bench; {os.cpu_count()} CPUs", flush=True)
    #: kind -> (bench label, test name) -> coverage
    cover: dict[str, dict[tuple[str, str], BandCoverage]] = {k: {} for k in kinds}
    fitted: dict[str, list[float]] = {k: [] for k in kinds}  #: the band's coverage on its own validation
    t_all = time.perf_counter()
    for seed in args.seeds:
        label = acc.bench_of(seed)[2]
        t0 = time.perf_counter()
        train, val, _ = acc.recordings(d, seed, size)
        tests = held_out(d, seed, size)
        for kind, (model, _) in acc.train_kinds(train, val, kinds, 25, args.restarts).items():
            fitted[kind].append(model.metadata["band"]["validation_coverage_percent"])
            _, scores, _ = evaluate(model, list(tests.values()))
            for name, s in zip(tests, scores, strict=True):
                assert s.band is not None, "every kind trained here has a band"
                cover[kind][(label, name)] = s.band
        line = "; ".join(f"{k} {total([c for (b, _), c in cover[k].items() if b == label]).percent:.1f} %"
                         for k in kinds)
        print(f"{label}: {line} ({time.perf_counter() - t0:.0f} s)", flush=True)
    figures = report(cover, fitted, [acc.bench_of(s)[2] for s in args.seeds])
    print(f"total {time.perf_counter() - t_all:.0f} s")
    if args.json:
        write_record(args.json, figures, seconds=time.perf_counter() - t_all)
    if tmp is not None:
        tmp.cleanup()


def report(cover: dict[str, dict[tuple[str, str], BandCoverage]], fitted: dict[str, list[float]],
           benches: list[str]) -> dict[str, object]:
    """Print the tables; the figures for --json."""
    tests = sorted({name for per in cover.values() for _, name in per})
    print("\ncoverage at one sigma on held-out recordings, % (goal "
          f"{GOAL_PERCENT[0]:.0f}-{GOAL_PERCENT[1]:.0f} pooled)")
    print(f"{'kind':8s} {'pooled':>7s} {'benches: median [min, max]':>28s} {'recordings: median [min, max]':>31s}"
          f" {'mean sigma':>11s} {'on validation':>14s}  goal")
    figures: dict[str, object] = {"goal_percent": list(GOAL_PERCENT), "benches": benches, "kinds": {}}
    for kind, per in cover.items():
        pooled = total(list(per.values()))
        by_bench = [total([c for (b, _), c in per.items() if b == label]).percent for label in benches]
        by_rec = [c.percent for c in per.values()]
        met = GOAL_PERCENT[0] <= pooled.percent <= GOAL_PERCENT[1]
        print(f"{kind:8s} {pooled.percent:7.1f} {spread(by_bench):>28s} {spread(by_rec):>31s} "
              f"{pooled.mean_sigma_rad_s:8.2f} rad/s {np.mean(fitted[kind]):10.1f} %  {'met' if met else 'NOT met'}")
        by_test = {name: total([c for (_, n), c in per.items() if n == name]) for name in tests}
        print("         per profile: " + ", ".join(f"{n} {c.percent:.1f} %" for n, c in by_test.items()))
        figures["kinds"][kind] = {  # type: ignore[index]
            "pooled_percent": pooled.percent, "mean_sigma_rad_s": pooled.mean_sigma_rad_s, "goal_met": met,
            "validation_percent": float(np.mean(fitted[kind])),
            "per_bench_percent": dict(zip(benches, by_bench, strict=True)),
            "per_test_percent": {n: c.percent for n, c in by_test.items()},
            "recordings": [{"bench": b, "test": n, **c.as_dict()} for (b, n), c in per.items()],
        }
    return figures


if __name__ == "__main__":
    main()
