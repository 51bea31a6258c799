"""The README's walkthrough ("Recording your own bench") runs as written and is right.

The bash block between ``<!-- walkthrough:begin -->`` and ``<!-- walkthrough:end -->`` is run as
it stands (only its ``ros2 ...`` lines are skipped: they need a ROS install), from a folder that
looks like the clone's root (``bags`` linked), with the venv's ``bin`` on PATH. Then: the effect
``discrepancy`` names is the simulator's truth (the flights differ from the bundled bench bags
only in the ESC's braking: ``spin_down_asymmetry``), and the model the walkthrough trains is as
good on ``bags/chirp`` as the demo's (scripts/demo.sh step 1), within 1.5x its RMSE.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: The simulator's truth: the flights' ESC coasts, the bench bags' brakes (sim/bench.py, bags/README).
TRUTH = "spin_down_asymmetry"
#: The walkthrough's model may be at most this many times the demo's test RMSE on bags/chirp.
TEST_RMSE_RATIO = 1.5
#: scripts/demo.sh step 1's training recordings and validation (checked against the script).
DEMO_TRAIN = ["staircase", "triangle", "staircase_half", "triangle_half"]
DEMO_VALIDATION = "validation"


def walkthrough_block(readme: str) -> str:
    """The bash block between the walkthrough markers, its ``ros2`` lines dropped."""
    m = re.search(r"<!-- walkthrough:begin -->(.*?)<!-- walkthrough:end -->", readme, re.S)
    assert m, "README.md has no walkthrough markers"
    blocks = re.findall(r"```bash\n(.*?)```", m.group(1), re.S)
    assert len(blocks) == 1, f"expected one bash block in the walkthrough, found {len(blocks)}"
    return "\n".join(line for line in blocks[0].splitlines() if not line.lstrip().startswith("ros2 "))


def env_with_cli() -> dict[str, str]:
    """PATH with the venv's bin (where `bldc-propulsion` is) first, the tree under test importable."""
    bins = [str(ROOT / ".venv" / "bin"), str(Path(sys.executable).parent)]
    return {**os.environ, "PATH": os.pathsep.join([*bins, os.environ.get("PATH", "")]),
            "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep)}


def cli(env: dict[str, str], cwd: Path, *args: str) -> dict:
    proc = subprocess.run([sys.executable, "-m", "bldc_propulsion.cli", *args, "--json"], capture_output=True,
                          text=True, env=env, cwd=cwd, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return json.loads(proc.stdout)


def test_block_extraction_keeps_every_command_but_ros2():
    block = walkthrough_block((ROOT / "README.md").read_text(encoding="utf-8"))
    assert "ros2 launch" not in block and "bldc-propulsion discrepancy" in block
    assert "#   ros2 bag record" in block  # a comment mentioning ros2 is not a ros2 line


def test_demo_step_1_trains_on_what_this_test_compares_with():
    demo = (ROOT / "scripts" / "demo.sh").read_text(encoding="utf-8")
    m = re.search(r"\$BP train ((?:bags/\w+ ?)+)\\\n\s*--validation bags/(\w+)", demo)
    assert m, "scripts/demo.sh step 1's train command not found"
    assert m.group(1).split() == [f"bags/{b}" for b in DEMO_TRAIN] and m.group(2) == DEMO_VALIDATION


@pytest.mark.skipif(sys.platform == "win32", reason="the walkthrough is a bash block")
def test_readme_walkthrough_runs_as_written_and_names_the_truth(tmp_path):
    env = env_with_cli()
    (tmp_path / "bags").symlink_to(ROOT / "bags", target_is_directory=True)
    block = walkthrough_block((ROOT / "README.md").read_text(encoding="utf-8"))
    proc = subprocess.run(["bash", "-e", "-o", "pipefail", "-c", block], capture_output=True, text=True,
                          env=env, cwd=tmp_path, timeout=1200)
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = proc.stdout
    # the summary names the truth as new, and nothing else as new
    new = re.findall(r"^new effect\(s\) found in the measured data, added: (.*)$", out, re.M)
    assert new == [TRUTH], out[-3000:]
    work = tmp_path / "walkthrough"
    from bldc_propulsion.model import load_model

    added = load_model(str(work / "models" / "bench_plus.npz")).metadata["discrepancy"]["added"]
    assert added[0]["effect"] == TRUTH, added
    assert (work / "reports" / "discrepancy" / "index.html").exists()

    # the walkthrough's model against the demo's on the test recording: the demo's figure as
    # docs/results/demo.json records it (test_results_doc retrains the demo's model and checks
    # that figure to 1e-9, so training it again here would only cost time)
    demo = json.loads((ROOT / "docs" / "results" / "demo.json").read_text(encoding="utf-8"))
    demo_rmse = demo["figures"]["models"]["network"]["scores"]["chirp"]["rmse_rad_s"]
    chirp = str(ROOT / "bags" / "chirp")
    evaluated = cli(env, ROOT, "evaluate", "--model", str(work / "models" / "bench.npz"), chirp)
    ours = evaluated["rmse_rad_s"]
    assert ours <= TEST_RMSE_RATIO * demo_rmse, (ours, demo_rmse)

    # the figures the README quotes under the block are this run's
    prose = (ROOT / "README.md").read_text(encoding="utf-8").split("<!-- walkthrough:end -->")[0].rsplit("```", 1)[1]
    quoted = re.search(r"holdout RMSE (\d+\.\d) → (\d+\.\d) rad/s", prose)
    printed = re.search(r"RMSE (\d+\.\d+) -> (\d+\.\d+) rad/s", out)
    assert quoted and printed, (prose, out[-2000:])
    assert [float(x) for x in quoted.groups()] == [round(float(x), 1) for x in printed.groups()], (quoted, printed)
    quoted_pct = re.search(r"tests at (\d+\.\d) % of the speed range", prose)
    ours_pct = evaluated["recordings"][0]["rmse_percent_of_range"]
    assert quoted_pct and float(quoted_pct.group(1)) == round(ours_pct, 1), (quoted_pct, ours_pct)
