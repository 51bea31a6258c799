"""Replay speed in multiples of real time (goal >= 100x, issue 10): the nodes' cores over a recording.

Run: PYTHONPATH=. python benchmarks/bench_replay.py [--duration 120] [--model M.npz] [--reference]

Prints wall time (what the goal is about) and the process's CPU time (steadier on a machine
shared with other work). ``--reference`` times the per-message reference path as well, which
writes the same messages (test/test_replay_fast.py).
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

GOAL_X = 100.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--duration", type=float, default=120.0, help="recording length (s)")
    ap.add_argument("--model", help="model .npz (default: the first-principles fallback)")
    ap.add_argument("--reference", action="store_true", help="time the per-message reference path too")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        write_sim_bag(simulate("chirp", args.duration, 1), os.path.join(d, "in"))
        for reference in ([False, True] if args.reference else [False]):
            out = os.path.join(d, "ref" if reference else "out")
            t0, c0 = time.perf_counter(), time.process_time()
            info = replay_bag(os.path.join(d, "in"), out, model_path=args.model, reference=reference)
            elapsed, cpu = time.perf_counter() - t0, time.process_time() - c0
            speed = args.duration / elapsed
            print(
                f"replay{' (reference path)' if reference else ''}: {args.duration:.0f} s of recording in "
                f"{elapsed:.2f} s = {speed:.0f}x real time (CPU {cpu:.2f} s = {args.duration / cpu:.0f}x; "
                f"{info['messages_in']} messages in, {info['messages_out']} out; goal >= {GOAL_X:.0f}x: "
                f"{'met' if speed >= GOAL_X else 'not met'})"
            )


if __name__ == "__main__":
    main()
