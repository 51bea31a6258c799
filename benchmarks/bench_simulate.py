"""Wall-clock cost of simulating ten minutes of bench recording (target: well under 20 s).

Run: PYTHONPATH=. python benchmarks/bench_simulate.py [--duration 600] [--profiles staircase,chirp]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), os.pardir))
from bldc_propulsion.sim import simulate  # noqa: E402
from bldc_propulsion.sim.record import write_sim_bag  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--duration", type=float, default=600.0, help="simulated seconds per profile")
    ap.add_argument("--profiles", default="staircase,chirp", help="comma-separated profile names")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    for name in args.profiles.split(","):
        t0 = time.perf_counter()
        res = simulate(name, args.duration, args.seed)
        elapsed = time.perf_counter() - t0
        print(
            f"{name:>12}: {args.duration:.0f} s simulated in {elapsed:.2f} s "
            f"({args.duration / elapsed:.0f}x real time; {len(res.tach)} tach samples, "
            f"{len(res.truth_t)} steps)"
        )
        with tempfile.TemporaryDirectory() as d:
            t0 = time.perf_counter()
            n = write_sim_bag(res, os.path.join(d, "bag"))
            written = time.perf_counter() - t0
            size = sum(f.stat().st_size for f in Path(d, "bag").iterdir())
        print(
            f"{'':>12}  + writing the MCAP bag: {written:.2f} s ({n} messages, {size / 1e6:.1f} MB); "
            f"simulate command total {elapsed + written:.1f} s for {args.duration:.0f} s of recording"
        )


if __name__ == "__main__":
    main()
