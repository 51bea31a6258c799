"""Replay a corpus of recordings with two versions of the code and compare every output message.

Run: PYTHONPATH=. python benchmarks/compare_replay.py --base /path/to/other/checkout [--duration 8]

The corpus (test/_replay_corpus.py) covers profiles, MCAP and SQLite3, a vehicle recording
with --namespace, battery/voltage inputs, and faults (dropped batches, NaN samples, gaps,
rejected samples, a truncated file). Exit 1 if any replay differs in any message or summary.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "test"))
from _replay_corpus import CASES, build_corpus, differences  # noqa: E402

_RUN = """
import json, sys
from bldc_propulsion.replay import replay_bag
cases = json.loads(sys.argv[1])
out = {}
for name, src, dst, kw in cases:
    out[name] = replay_bag(src, dst, **kw)
print(json.dumps(out))
"""


def replay_with(code: Path, jobs: list) -> dict:
    env = {**os.environ, "PYTHONPATH": str(code)}
    proc = subprocess.run([sys.executable, "-c", _RUN, json.dumps(jobs)], env=env, cwd=code,
                          capture_output=True, text=True, check=True)
    return json.loads(proc.stdout.splitlines()[-1])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--base", required=True, help="checkout of the code to compare with")
    ap.add_argument("--duration", type=float, default=8.0)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        bags = build_corpus(d / "in", args.duration)
        jobs = {who: [(name, str(bags[name]), str(d / who / name), kw) for name, kw in CASES]
                for who in ("base", "new")}
        (d / "base").mkdir()
        (d / "new").mkdir()
        infos = {"base": replay_with(Path(args.base), jobs["base"]), "new": replay_with(ROOT, jobs["new"])}
        bad = 0
        for name, _ in CASES:
            diffs = differences(d / "base" / name, d / "new" / name, infos["base"][name], infos["new"][name])
            print(f"{name:20s} {'same' if not diffs else 'DIFFERENT: ' + '; '.join(diffs)[:400]}")
            bad += bool(diffs)
    print("all identical" if not bad else f"{bad} replays differ")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
