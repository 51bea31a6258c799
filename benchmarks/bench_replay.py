"""Replay speed in multiples of real time (goal >= 50x): the nodes' cores over a recording.

Run: PYTHONPATH=. python benchmarks/bench_replay.py [--duration 120] [--model M.npz]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), os.pardir))
from bldc_propulsion.replay import replay_bag  # noqa: E402
from bldc_propulsion.sim import simulate  # noqa: E402
from bldc_propulsion.sim.record import write_sim_bag  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--duration", type=float, default=120.0, help="recording length (s)")
    ap.add_argument("--model", help="model .npz (default: the first-principles fallback)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        write_sim_bag(simulate("chirp", args.duration, 1), os.path.join(d, "in"))
        t0 = time.perf_counter()
        info = replay_bag(os.path.join(d, "in"), os.path.join(d, "out"), model_path=args.model)
        elapsed = time.perf_counter() - t0
    print(
        f"replay: {args.duration:.0f} s of recording in {elapsed:.2f} s = {args.duration / elapsed:.0f}x real time "
        f"({info['messages_in']} messages in, {info['messages_out']} out; goal >= 50x)"
    )


if __name__ == "__main__":
    main()
