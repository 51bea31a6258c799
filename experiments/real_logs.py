"""`discrepancy --physics` on two real thrust-stand logs (RCbenchmark CSV, ../shared/real/).

Each log is imported (`import-csv`) into a temporary directory (the logs carry no license: they
are never copied into the repository) and checked on its own against the package's nominal
bench physics with every effect off: Kv, CP and the throttle exponent are calibrated on the log, then the effects are
switched on one at a time and named while significant on held-out time blocks. The logs are
of other motors and propellers, and short (14 s and 18 s), so there is no separate holdout
recording: the before/after RMSE is in-sample (the tool warns).

    PYTHONPATH=. .venv/bin/python experiments/real_logs.py [--real-dir ../shared/real] [--max-effects 3] [--alpha 0.01]
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
from bldc_propulsion.physics.config import CALIBRATED  # noqa: E402
from bldc_propulsion.physics.params import BenchParams  # noqa: E402

LOGS = ("rcbenchmark_steps_90percent", "rcbenchmark_step_coastdown_16v_10in")


def cli(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), *sys.path])}
    return subprocess.run([sys.executable, "-m", "bldc_propulsion.cli", *args], capture_output=True,
                          text=True, env=env, cwd=ROOT, timeout=900)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--real-dir", default=str(ROOT.parent / "shared" / "real"))
    ap.add_argument("--max-effects", default="3")
    ap.add_argument("--alpha", default="0.01", help="significance level (the tool's default 0.01)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        for name in LOGS:
            bag = Path(tmp) / name
            imp = cli("import-csv", str(Path(args.real_dir) / f"{name}.csv"), "-o", str(bag), "--json")
            if imp.returncode != 0:
                print(f"{name}: import failed: {imp.stderr.strip()}")
                return 1
            info = json.loads(imp.stdout)
            print(f"== {name}: {info['rows']} rows, {info['duration_s']:.1f} s, ESC {info['esc_us_levels']} us, "
                  f"{info['voltage_min_v']:.1f}-{info['voltage_max_v']:.1f} V, speed from the {info['speed_source']} "
                  f"column, max {info['speed_max_rad_s']:.0f} rad/s")
            proc = cli("discrepancy", "--physics", "--measured", str(bag), "--max-effects", args.max_effects,
                       "--alpha", args.alpha, "--json")
            if proc.returncode != 0:
                print(f"{name}: discrepancy failed (exit {proc.returncode}): {proc.stderr.strip()[-2000:]}")
                return 1
            data = json.loads(proc.stdout)
            const = ", ".join(f"{k} {data['calibrated_base']['params'].get(k, getattr(BenchParams(), k)):.4g}"
                              for k in CALIBRATED)
            print(f"calibrated constants (all effects off): {const}, stiff supply {data['physics']['supply_v']:.2f} V")
            for k, it in enumerate(data["iterations"]):
                print(f" round {k + 1}: each effect switched on alone (strength and constants fitted)")
                for effect, ev in it["evidence"].items():
                    print(f"  {effect:20s} held-out MSE reduction {100 * ev['measured']['mse_reduction']:7.1f} % "
                          f"p = {ev['p_value']:.2g} ({ev['measured']['blocks_improved']}/{ev['measured']['blocks']} "
                          f"blocks better) -> {ev['verdict']}")
                if it.get("named"):
                    fp = it["parameters"]
                    print(f" named: {data['evidence'][it['named']]['feature']}; constants then "
                          f"Kv {fp['motor_kv_rpm_per_v']:.0f} rpm/V, CP {fp['propeller_cp']:.3g}, "
                          f"throttle exponent {fp['esc_throttle_exponent']:.3g}; "
                          f"RMSE {it['holdout_rmse_rad_s']:.1f} rad/s")
            if not data["named"]:
                print("named: nothing")
            for c in data["considered_not_added"]:
                if c["verdict"] == "new":
                    print(f"considered, not added: {c['effect']}: {c['why']}")
            print(f"RMSE (in-sample: no holdout) uncalibrated {data['holdout_rmse_uncalibrated']:.1f}, "
                  f"calibrated {data['holdout_rmse_before']:.1f} -> with the named effects "
                  f"{data['holdout_rmse_after']:.1f} rad/s")
            print(f"final physics config: effects {data['physics']['effects']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
