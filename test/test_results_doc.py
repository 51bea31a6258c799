"""The figures the README and docs/results.md quote cannot go stale (issue 31, item 1).

1. Rendering the committed ``docs/results/*.json`` reproduces docs/results.md and the README's
   results regions byte for byte (so nobody edits a figure by hand).
2. The demo's figures are recomputed by the code that wrote them (``benchmarks/results.py
   --update demo``: the demo's commands on the bundled bags) and compared with the JSON: what is
   named, every verdict and count exactly, floats within ``REL_TOL``. The runs are deterministic on
   one machine, but CPUs differ in the last bits of their BLAS and numpy SIMD kernels (AVX-512
   against AVX2), and the fits carry that to 2e-4 relative at most (the demo's dead time, 35.371
   against 35.377 ms; most figures 1e-8 to 1e-6): floats compare to the three or four significant
   digits a figure is rendered with.
3. Every number with a unit in the README's prose comes from a rendered region, or is listed in
   ``ALLOWED`` with the reason it cannot go stale.

The expensive groups (confusion tables over many seeds, the accuracy benches, the real logs'
splits) are produced by their scripts with ``--json``; only their rendering is checked here.
"""

from __future__ import annotations

import math
import re
import sys
from pathlib import Path
from typing import Any

import pytest

from _scripts import load_script
from bldc_propulsion.physics.fit import FitFlag

ROOT = Path(__file__).resolve().parents[1]


results = load_script("benchmarks/results.py", "bench_results")


# --- 1. the documents are the JSON's rendering ------------------------------------------------------
def test_docs_results_md_is_what_the_json_renders_to():
    assert (ROOT / "docs" / "results.md").read_text(encoding="utf-8") == results.render_results_md(), \
        "docs/results.md differs from its rendering: run python benchmarks/results.py"


def test_readme_regions_are_what_the_json_renders_to():
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    assert results.render_readme(text) == text, "README.md's results region is stale: run python benchmarks/results.py"


def test_the_demo_group_is_measured_and_its_command_is_the_update():
    rec = results.read_record("demo")
    assert rec is not None, "docs/results/demo.json is missing: run python benchmarks/results.py --update demo"
    assert rec["command"] == "python benchmarks/results.py --update demo"
    assert re.fullmatch(r"\d{4}-\d{2}-\d{2}", rec["date"]) and rec["commit"]


def test_a_record_names_the_numerical_libraries_its_floats_came_from(tmp_path):
    from importlib.metadata import version
    path = tmp_path / "r.json"
    results.write_record(path, {"x": 1.0}, command="python benchmarks/x.py")
    rec = results.read_record("r", tmp_path)
    assert rec is not None
    assert rec["libraries"]["numpy"] == version("numpy") and rec["libraries"]["scipy"] == version("scipy")
    assert f"numpy {version('numpy')}, scipy {version('scipy')}" in results.provenance(rec)
    assert rec["simd"] in ("AVX-512", "AVX2", "SSE4.2", "ASIMD", None)  # x86-64 CI machines: AVX2 at least
    assert results.provenance({**rec, "simd": "AVX-512"}).startswith(f"measured {rec['date']} at {rec['commit']}") \
        and "(1 CPUs, AVX-512, numpy" in results.provenance({**rec, "simd": "AVX-512", "cpus": 1})
    del rec["libraries"], rec["simd"]  # records written before the libraries were kept still render
    assert "numpy" not in results.provenance(rec) and results.provenance(rec).startswith(f"measured {rec['date']}")


def test_a_group_not_measured_says_which_command_to_run(tmp_path):
    (tmp_path / "demo.json").write_text((ROOT / "docs" / "results" / "demo.json").read_text(encoding="utf-8"))
    text = results.render_results_md(tmp_path)
    for name, group in results.GROUPS.items():
        if name != "demo":
            assert f"Not measured yet: run `{group.command}`" in text


def test_the_confusion_rendering_counts_right_on_a_hand_made_run_list():
    runs = [  # two seeds of rotor_lag (one named right, one nothing) and a control with a false name
        {"effect": "rotor_lag", "seed": 0, "named": ["rotor_lag"], "first": "rotor_lag", "before": 10.0, "after": 5.0},
        {"effect": "rotor_lag", "seed": 1, "named": [], "first": "(nothing)", "before": 8.0, "after": 8.0},
        {"effect": "control", "seed": 0, "named": ["input_delay"], "first": "input_delay", "before": 4.0,
         "after": 3.0},
    ]
    text = "\n".join(results.render_confusion({"runs": runs}))
    assert "| rotor_lag | 0 | 1 | 0 | 0 | 0 | 0 | 1 | 1/2 |" in text
    assert "| control | 0 | 0 | 1 | 0 | 0 | 0 | 0 | 0/1 |" in text
    assert "Named right first: **1/3**; false names on the controls: 1" in text
    assert "- rotor_lag: 25.0 % [0.0, 50.0]" in text  # median of 50 % and 0 %


def test_a_real_logs_rendering_states_its_rating_its_context_and_the_alarms_counted():
    """Each stand log's section names its own motor's rating and what changed on its stand (the
    record's), and counts the monitor's runs that raised an alarm; minor changes are no alarm."""
    row = {"split": 0, "kind": "physics", "percent": 1.5, "kv": 1700.0, "b": 1.0, "b_direct": 1.0,
           "b_direct_training": 1.0}
    health = [{"split": 0, "kind": "physics", "events": ["unnamed change from 30.4 s"], "minor": [],
               "monitored_s": 87.0, "duration_s": 112.0},
              {"split": 1, "kind": "physics", "events": [], "minor": ["pack_resistance (1.03 factor) from 54 s"],
               "monitored_s": 87.0, "duration_s": 112.0}]
    text = "\n".join(results.render_real({"log": "x.csv", "log_range_rad_s": 1671.0, "rated_kv": 1600.0,
                                          "splits": [row], "health": health,
                                          "health_context": "Nobody changed the stand."}))
    assert "Kv, rpm/V (rated 1600)" in text and "| 0 | physics | 1.50 % | 1700 |" in text
    assert "each split's model. Nobody changed the stand." in text
    assert "Runs with an alarm: 1 of 2." in text


def test_a_real_logs_rendering_says_whether_the_contradicted_speed_was_left_out():
    """The spans import-csv names, and what the models were given there: as read, or nothing."""
    row = {"split": 0, "kind": "physics", "percent": 1.5, "kv": 1700.0, "b": 1.0, "b_direct": 1.0,
           "b_direct_training": 1.0}
    base = {"log": "x.csv", "log_range_rad_s": 1671.0, "rated_kv": 1600.0, "splits": [row],
            "speed_contradicted_s": [[10.72, 11.32], [106.03, 111.58]]}
    read = "\n".join(results.render_real(base))
    dropped = "\n".join(results.render_real({**base, "speed_dropped": True}))
    for text in (read, dropped):
        assert "contradicted by its thrust at 10.7-11.3 s, 106.0-111.6 s (the log's time" in text
    assert "scored and trained on those rows as read" in read and "--drop-contradicted" not in read
    assert "left out there (`--drop-contradicted`" in dropped and "as read" not in dropped


def test_the_flight_benchmark_pools_every_scored_piece_against_its_goal():
    """bench_flight.summarize: median, min, max and the pieces within issue 29's goal, hand-made
    rows (two benches, two scored pieces each); rendered per bench in the test pieces' order."""
    flight = load_script("benchmarks/bench_flight.py", "bench_flight")
    rows = [{"seed": 1, "network": {"percent": [1.5, 2.5]}, "hybrid": {"percent": [0.5, 0.9]}},
            {"seed": 2, "network": {"percent": [3.5, 1.0]}, "hybrid": {"percent": [1.2, 0.3]}}]
    s = flight.summarize(rows, ["network", "hybrid"])
    assert s["network"] == {"median": 2.0, "min": 1.0, "max": 3.5, "goal": 2.0, "within": 2, "scored": 4}
    assert s["hybrid"]["median"] == pytest.approx(0.7) and s["hybrid"]["within"] == 3
    text = "\n".join(results.render_flight({"benches": rows, "summary": s, "flight_s": 60.0,
                                            "flights": [{"role": "train", "soc": 0.95},
                                                        {"role": "test", "soc": 0.8}, {"role": "test", "soc": 0.6}]}))
    assert "| bench | network | hybrid |" in text and "the pieces at 80, 60 % charge" in text
    assert "| 2 | 3.50 / 1.00 % | 1.20 / 0.30 % |" in text
    assert "- network: median 2.00 % [1.00, 3.50]; goal at most 2 %: 2 of 4 pieces (**not met**)" in text


def test_a_real_logs_rendering_lists_the_constants_its_training_left_at_a_bound():
    """train's own warning text (FitFlag.text) of a constant at a bound is listed once per split
    with the end it sits at, exponents and all; a hybrid that holds no correction is said to be
    the physics alone; a split without such warnings is not listed."""
    def at_bound(quantity: str, value: float, low: float, high: float) -> str:
        return FitFlag("training fit", quantity, value, 1.0, low, high, at_bound=True, stated=False,
                       basis="start (not stated)").text()

    thermal = at_bound("motor_thermal_resistance_k_per_w", 1.644, 0.1027, 1.644)
    small = at_bound("rotor_lag strength", 2e-05, 1e-05, 0.5)
    rows = [{"split": 0, "kind": "physics", "warnings": [thermal, small]},
            {"split": 0, "kind": "hybrid", "warnings": [thermal, "the network did not improve on the physics on the "
                                                        "validation recordings: the hybrid's correction is 0 (the "
                                                        "physics model alone)"]},
            {"split": 1, "kind": "physics", "warnings": []}]
    text = "\n".join(results._fit_flag_lines(rows))
    assert "- split 0: motor_thermal_resistance_k_per_w at the high end of 0.1027-1.644; " \
           "rotor_lag strength at the low end of 1e-05-0.5" in text
    assert "split 1" not in text and text.count("motor_thermal") == 1
    assert "The hybrid of split 0 is the physics alone" in text


def test_foreign_heating_is_judged_on_the_speed_lost_and_its_per_kelvin_shown_aside():
    heating = {"path": "physics", "case": "motor_heating", "seed": 7, "named": ["motor_heating"],
               "first": "motor_heating", "before": 7.0, "after": 1.0, "fitted": 6.0, "truth": 5.0,
               "unit": "% of the full-drive speed lost warm", "per_k": 0.95, "truth_per_k": 0.393,
               "tau_s": 120.0, "truth_tau_s": 89.0}
    other = {**heating, "path": "network", "fitted": 100.0}  # the other path's run: not in this table
    text = "\n".join(results.render_foreign({"runs": [heating, other]}, "physics"))
    assert "fitted value / truth 1.20, 1/1 within 30 %" in text  # 6 / 5, not 0.95 / 0.393
    assert "seed 7 0.95 vs 0.393 %/K, time constant 120 vs 89 s" in text


def test_a_foreign_miss_shows_what_its_effect_does_to_the_measured_speed():
    hit = {"path": "physics", "case": "esc_deadband", "seed": 3, "named": ["esc_deadband"], "first": "esc_deadband",
           "before": 9.0, "after": 3.0, "effect_rad_s": 11.6}
    miss = {**hit, "seed": 4, "named": [], "first": "(nothing)", "after": 9.0, "effect_rad_s": 0.73}
    text = "\n".join(results.render_foreign({"runs": [hit, miss]}, "physics"))
    assert "Named right first: **1/2**; no control runs" in text  # no controls: no claim about them
    assert "esc_deadband seed 4 0.73 vs 9.0 rad/s." in text and "seed 3 11.6" not in text


def test_a_foreign_effect_that_does_not_move_the_speed_is_judged_as_a_control():
    hit = {"path": "physics", "case": "esc_deadband", "seed": 3, "named": ["esc_deadband"], "first": "esc_deadband",
           "before": 9.0, "after": 3.0, "effect_rad_s": 11.6}
    quiet = {**hit, "seed": 8, "named": [], "first": "(nothing)", "after": 9.0, "effect_rad_s": 0.0}
    wrong = {**quiet, "seed": 9, "named": ["input_delay"], "first": "input_delay"}  # a name there is a false one
    small = {**quiet, "seed": 4, "effect_rad_s": 0.73}  # small but there: still a miss
    text = "\n".join(results.render_foreign({"runs": [hit, quiet, wrong, small]}, "physics"))
    assert "| esc_deadband | 0 | 0 | 0 | 1 | 0 | 0 | 1 | 1/2 |" in text
    assert "| control | 0 | 0 | 1 | 0 | 0 | 0 | 1 | 1/2 |" in text
    assert "Named right first: **2/4**; false names on the controls: 1" in text
    assert "esc_deadband seed 8 (0 rad/s, named nothing); esc_deadband seed 9 (0 rad/s, named input_delay)" in text
    assert "esc_deadband seed 4 0.73 vs 9.0 rad/s." in text and "seed 8 0.00 vs" not in text
    assert results.judged_case({"case": "esc_deadband"}) == "esc_deadband"  # no figure: judged as recorded


def test_a_benchmarks_json_path_is_checked_before_any_work(tmp_path):
    import subprocess

    for bad, why in ((tmp_path / "no" / "x.json", "does not exist"), (ROOT / "README.md", "must end in .json")):
        proc = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "bench_real.py"), "--thrust-law-only",
                               "--json", str(bad)], capture_output=True, text=True, cwd=ROOT, timeout=120)
        assert proc.returncode == 2 and why in proc.stderr and len(proc.stderr.splitlines()) == 1, proc.stderr
        assert proc.stdout == ""  # nothing computed


# --- 2. the demo's figures, recomputed ---------------------------------------------------------------
REL_TOL = 1e-3  #: floats: 5x the CPU-to-CPU spread seen, a rendered figure's fourth digit


def _same(got: Any, want: Any, where: str = "") -> list[str]:
    """Where ``got`` differs from ``want`` (floats within ``REL_TOL``), as readable lines."""
    if isinstance(want, dict) and isinstance(got, dict):
        out = [f"{where}.{k}: missing" for k in want if k not in got]
        return out + [d for k in want if k in got for d in _same(got[k], want[k], f"{where}.{k}")]
    if isinstance(want, list) and isinstance(got, list) and len(want) == len(got):
        return [d for i, (g, w) in enumerate(zip(got, want, strict=True)) for d in _same(g, w, f"{where}[{i}]")]
    if isinstance(want, float) and isinstance(got, (int, float)) and not isinstance(got, bool):
        return [] if math.isclose(got, want, rel_tol=REL_TOL, abs_tol=1e-9) else [f"{where}: {got!r} != {want!r}"]
    return [] if got == want else [f"{where}: {got!r} != {want!r}"]


def test_the_comparison_takes_cpu_rounding_but_not_a_changed_figure():
    want = {"named": ["input_delay"], "share": 0.9173423157712909, "epochs": 40}
    assert _same({**want, "share": 0.9173423249612108}, want) == []  # AVX-512 against AVX2
    assert _same({**want, "share": 0.919}, want) == [".share: 0.919 != 0.9173423157712909"]
    assert _same({**want, "epochs": 41}, want) and _same({**want, "named": []}, want)


@pytest.fixture(scope="module")
def demo() -> dict[str, Any]:
    rec = results.read_record("demo")
    if rec is None:
        pytest.fail("docs/results/demo.json is missing: run python benchmarks/results.py --update demo")
    return rec["figures"]


def test_the_demo_group_runs_what_scripts_demo_sh_runs():
    """The figures are the demo's only while its commands are the demo's."""
    demo_sh = " ".join((ROOT / "scripts" / "demo.sh").read_text(encoding="utf-8").replace("\\\n", " ").split())
    assert " ".join(results.DEMO_TRAINING) + " --validation bags/validation" in demo_sh
    assert " ".join(results.DEMO_TESTS) in demo_sh
    for fragment in ("train bags/staircase bags/triangle --validation bags/validation_full",
                     "--inputs pwm,pwm_filtered",
                     "--measured bags/discharge_a --holdout bags/discharge_b --max-effects 1",
                     "--physics --measured bags/staircase bags/validation --holdout bags/discharge_b --max-effects 4"):
        assert fragment in demo_sh, fragment


@pytest.mark.parametrize("kind", ["network", "physics", "hybrid"])
def test_the_demos_models_and_their_scores_are_recomputed(demo, kind, tmp_path):
    """Steps 1, 1b and 3b: each kind trained as the demo trains it, scored on chirp and discharge_a."""
    assert _same(results.demo_model(kind, tmp_path), demo["models"][kind], kind) == []


def test_the_demos_bench_truth_is_the_simulators():
    assert _same(results.demo_bench(), results.read_record("demo")["figures"]["models"]["bench"]) == []


@pytest.mark.parametrize("part", ["discrepancy", "physics_discrepancy"])
def test_the_demos_discrepancy_steps_are_recomputed(demo, part, tmp_path):
    """Steps 4 and 5: what is named, every candidate's verdict and shares, the holdout before/after."""
    assert _same(results.DEMO_PARTS[part](tmp_path), demo[part], part) == []


# --- 3. no figure in the README's prose but rendered ones --------------------------------------------
UNITS = (r"%|rad/s|rpm/V|rpm|ms|µs|s|min|minutes?|hours?|MB|GB|kHz|Hz|mV|V|N|A|W|Ω|kg m²|N s²/rad²|"
         r"in|cores?|CPUs?")
NUMBER_WITH_UNIT = re.compile(r"(?<![\w.^/-])\d[\d,]*(?:\.\d+)?"  # a number, maybe a range "3-5" or "1.5 .. 2"
                              rf"(?:\s?(?:-|–|\.\.)\s?\d+(?:\.\d+)?)?\s?(?:{UNITS})(?![\w/²])")

#: numbers with a unit that are not measured figures: each with why it cannot go stale
ALLOWED = {
    "270 MB": "the size of the ROS 2 Jazzy wheels scripts/venv.sh installs (its comment says so)",
    "16 minutes": "how long scripts/test.sh takes on 2 cores: an order of magnitude for the reader",
    "2 cores": "the machine the order of magnitude above is for",
    "1 Hz": "the diagnostics period, nodes/params.DIAGNOSTICS_PERIOD_S (checked below)",
}


def readme_prose(text: str) -> str:
    """The README without code blocks, inline code, the rendered regions and the walkthrough (whose
    commands and figures its own test checks, test_cli_simulate.py)."""
    text = re.sub(r"```.*?```", "", text, flags=re.S)
    text = re.sub(r"<!-- (results:\w+|walkthrough):begin -->.*?<!-- \1:end -->", "", text, flags=re.S)
    return re.sub(r"`[^`\n]*`", "", text)


def test_every_number_with_a_unit_in_the_readme_is_rendered_or_allowed():
    found = NUMBER_WITH_UNIT.findall(readme_prose((ROOT / "README.md").read_text(encoding="utf-8")))
    assert [f for f in found if " ".join(f.split()) not in ALLOWED] == []
    assert set(ALLOWED) <= {" ".join(f.split()) for f in found}, "an allowed figure is no longer quoted: drop it"


def test_the_readme_is_a_manual_not_a_notebook():
    """Issue 31: at most 250 lines, none over 120 characters, no session numbers or commit hashes."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    lines = text.splitlines()
    assert len(lines) <= 250
    assert [ln for ln in lines if len(ln) > 120] == []
    assert not re.search(r"\bsession \d+|\b[0-9a-f]{7}\b(?![\w.-])", readme_prose(text))
    for marker in ("<!-- walkthrough:begin -->", "<!-- walkthrough:end -->"):
        assert text.count(marker) == 1


def test_the_allowed_constants_are_the_codes():
    from bldc_propulsion.nodes.params import DIAGNOSTICS_PERIOD_S

    assert DIAGNOSTICS_PERIOD_S == 1.0  # "1 Hz" in the README
    assert "about 270 MB" in (ROOT / "scripts" / "venv.sh").read_text(encoding="utf-8")


def test_the_figure_check_catches_a_hand_written_figure():
    prose = readme_prose("The chirp RMSE is 1.00 rad/s (0.20 %), in 36 ms.\n```\n9 s\n```\n`7 Hz`\n")
    assert NUMBER_WITH_UNIT.findall(prose) == ["1.00 rad/s", "0.20 %", "36 ms"]
