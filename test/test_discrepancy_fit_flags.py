"""Physics fits that are no basis for a verdict, and one number per fitted quantity.

- A fitted constant or strength at a bound of its range, or implausibly far from the CONFIG
  (physics.fit.PLAUSIBLE_FACTOR), is flagged: a "warning:" line naming the constant, the fitted value,
  the CONFIG's value and the range; ``fit_flags`` in --json; a table in the report. A trial fit so
  flagged is not added, however much it helps (known truth: recordings of a motor with 0.4x the
  CONFIG's Kv; rotor_lag, which the model really lacks, is fitted with that Kv).
- A named effect's fitted value in physical units is the same number in the summary, the --json
  evidence, the saved CONFIG and the report (it was three: the step-3 grid strength, the step-4 fit
  and the final model's refit after a later effect).
"""

from __future__ import annotations

import dataclasses
import html
import json
import sys
from pathlib import Path

import numpy as np
import pytest

from bldc_propulsion import contract as c
from bldc_propulsion.cli import build_parser
from bldc_propulsion.commands import discrepancy as cmd
from bldc_propulsion.discrepancy import physics as ph
from bldc_propulsion.discrepancy.results import kept_text
from bldc_propulsion.discrepancy.workflow import MAX_TRIALS
from bldc_propulsion.physics import config as pc
from bldc_propulsion.physics import fit as pf
from bldc_propulsion.physics.params import BenchParams, params_with_overrides

sys.path.insert(0, str(Path(__file__).parent))
from test_discrepancy import _bag, cli  # noqa: E402

DURATION_S = 20.0
ALL_BUT_LAG = {**{name: 1.0 for name in c.EFFECTS}, "rotor_lag": 0.0}


def _fit(model: pc.PhysicsConfig, free: tuple[str, ...] = ()) -> pf.Fit:
    consts = np.array(list(pc.load_config(None).constants().values()))
    return pf.Fit(model, np.zeros(1), np.zeros((1, len(pc.CALIBRATED) + len(free))), 0.0, consts,
                  pf.LOG_RANGE_BASE.copy(), free)


def test_fit_flags_name_the_constant_its_value_the_config_and_the_range():
    nominal = pc.load_config(None)
    cfg = dataclasses.replace(nominal, source="bench.json")  # a CONFIG the user gave
    kv, cp, bend, rs = cfg.constants().values()
    top = pf.STRENGTH_MAX["rotor_lag"]
    far = cfg.with_constants([3.0 * kv, 1.9 * cp, 2.0 * bend, rs]).with_effect("rotor_lag", top)
    flags = {f.quantity: f for f in pf.fit_flags(_fit(far, ("rotor_lag",)), cfg, "test fit")}
    # Kv 3x the CONFIG's: implausible; CP 1.9x: inside the factor 2; rotor_lag and the throttle
    # map's exponent (range a factor 2 either way) at their upper bounds
    assert set(flags) == {"motor_kv_rpm_per_v", "rotor_lag strength", "esc_throttle_exponent"}
    assert flags["esc_throttle_exponent"].at_bound and "0.5-2" in flags["esc_throttle_exponent"].text()
    kv_flag = flags["motor_kv_rpm_per_v"]
    assert not kv_flag.at_bound and kv_flag.value == pytest.approx(3 * kv) and kv_flag.config == kv
    assert f"motor_kv_rpm_per_v fitted {3 * kv:.4g} vs CONFIG {kv:.4g}" in kv_flag.text()
    assert "implausible" in kv_flag.text() and f"{kv * 1e-3:.4g}-{kv * 1e3:.4g}" in kv_flag.text()
    assert flags["rotor_lag strength"].at_bound and f"0-{top:g}" in flags["rotor_lag strength"].text()
    assert kv_flag.blocks and flags["rotor_lag strength"].blocks
    # the factor is one constant, either way
    assert pf.implausible(kv / (pf.PLAUSIBLE_FACTOR * 1.01), kv) and not pf.implausible(kv / pf.PLAUSIBLE_FACTOR, kv)
    assert pf.fit_flags(_fit(cfg), cfg, "test fit") == []
    # without a CONFIG (the nominal bench stands for an unknown motor) the same Kv is flagged, and
    # only a bound is held against the verdict
    loose = {f.quantity: f for f in pf.fit_flags(_fit(far, ("rotor_lag",)), nominal, "test fit")}
    assert "no CONFIG given" in loose["motor_kv_rpm_per_v"].text() and not loose["motor_kv_rpm_per_v"].blocks
    assert loose["rotor_lag strength"].blocks


@pytest.fixture(scope="module")
def kv_bags(tmp_path_factory) -> dict[str, list[str]]:
    """A bench whose motor has 0.4x the CONFIG's Kv (every effect on, rotor_lag included)."""
    d = tmp_path_factory.mktemp("fit_flags")
    bench = params_with_overrides(BenchParams(), {"motor_kv_rpm_per_v": 0.4 * BenchParams().motor_kv_rpm_per_v})
    return {"measured": [_bag(d, f"m{k}", "steps", 1510 + k, {}, 1.0, DURATION_S, bench) for k in range(2)],
            "holdout": [_bag(d, "h", "steps", 1610, {}, 1.0, DURATION_S, bench)]}


def test_a_fit_far_from_the_config_is_flagged_and_no_basis_for_a_verdict(kv_bags, tmp_path):
    cfg = tmp_path / "all_but_lag.json"
    cfg.write_text(json.dumps({"effects": ALL_BUT_LAG}))
    report = tmp_path / "report"
    proc = cli("discrepancy", "--physics", str(cfg), "--measured", *kv_bags["measured"], "--holdout",
               *kv_bags["holdout"], "--effects", "rotor_lag", "--max-effects", "1", "--report", str(report), "--json")
    assert proc.returncode == 0, proc.stderr
    data = json.loads(proc.stdout)
    kv = BenchParams().motor_kv_rpm_per_v
    # with rotor_lag (which the recordings have) the calibration finds the true Kv, 0.4x the CONFIG's
    trial = next(f for f in data["fit_flags"] if f["fit"] == "rotor_lag fit" and f["quantity"] == "motor_kv_rpm_per_v")
    assert trial["value"] == pytest.approx(0.4 * kv, rel=0.1) and trial["config"] == kv and not trial["at_bound"]
    assert f"motor_kv_rpm_per_v fitted {trial['value']:.4g} vs CONFIG {kv:.4g}" in trial["text"]
    # (without it, the calibration on the measured data lands far from the CONFIG too: flagged)
    assert any(f["fit"] == "calibration on the measured data" for f in data["fit_flags"])
    # console: one "warning:" line per flag, naming the constant, fitted value, CONFIG value and range
    warned = [line for line in proc.stderr.splitlines() if line.startswith("warning: ")]
    for f in data["fit_flags"]:
        assert any(f["text"] in line and "not a basis for a verdict" in line for line in warned), (f, warned)
        assert any(f["text"] in w for w in data["warnings"])
    # rotor_lag helps the holdout (the model really lacks it) but its fit has that Kv: not added
    assert data["named"] == []
    tried = {x["effect"]: x for x in data["considered_not_added"]}["rotor_lag"]
    assert tried["acceptance"]["mse_reduction"] > tried["acceptance"]["min_mse_reduction"]
    assert not tried["acceptance"]["accepted"] and "not a basis for a verdict" in tried["why"]
    assert "motor_kv_rpm_per_v" in tried["acceptance"]["at_bound"]
    # the report carries the same flags, the same numbers
    page = html.unescape((report / "index.html").read_text())
    assert "implausibly far from the CONFIG" in page and f"<td>{trial['value']:.4g}</td>" in page
    assert trial["text"] in page


@pytest.fixture(scope="module")
def two_bags(tmp_path_factory) -> dict[str, list[str]]:
    d = tmp_path_factory.mktemp("one_number")
    return {"measured": [_bag(d, f"m{k}", "steps", 1710 + k, {}, 1.0, DURATION_S) for k in range(2)],
            "holdout": [_bag(d, "h", "steps", 1810, {}, 1.0, DURATION_S)]}


def test_a_named_effect_has_one_fitted_value_everywhere(two_bags, tmp_path):
    """rotor_lag and input_delay off in the CONFIG, on (nominal) in the recordings. rotor_lag is
    fitted first (strength ~1.2, standing in for the dead time too) and refitted when input_delay is
    added (~1.0): the run that printed three strengths for it (the grid's 1, the first fit, the
    refit). One run of the command (its printed summary, its --json data, the report, the saved
    CONFIG): each effect's strength and physical value are one number, the final model's."""
    cfg = tmp_path / "no_lag_no_delay.json"
    cfg.write_text(json.dumps({"effects": {**ALL_BUT_LAG, "input_delay": 0.0}}))
    out, report = tmp_path / "found.json", tmp_path / "report"
    args = build_parser().parse_args(["discrepancy", "--physics", str(cfg), "--measured", *two_bags["measured"],
                                      "--holdout", *two_bags["holdout"], "--effects", "rotor_lag,input_delay",
                                      "--max-effects", "2", "-o", str(out), "--report", str(report)])
    res = cmd.run(args)
    data, text = res.data, res.text
    page = html.unescape((report / "index.html").read_text())
    assert data["named"] == ["rotor_lag", "input_delay"], data["considered_not_added"]
    first_fit = data["iterations"][0]["parameters"]["strength"]
    saved = pc.load_config(str(out))
    for name, quantity, unit in (("rotor_lag", "rotor inertia", "kg m^2"), ("input_delay", "dead time", "ms")):
        ev = data["evidence"][name]
        value, strength = ev["fitted_value"], ev["fitted_value"]["strength"]
        assert (value["quantity"], value["unit"]) == (quantity, unit)
        assert (strength == ev["fitted_parameters"]["strength"] == data["physics"]["effects"][name]
                == saved.effects[name])
        assert 0.8 <= strength <= 1.3  # the recordings' nominal 1
        shown = f"{quantity} {value['value']:.4g} {unit}"
        for where in (text, ev["sentence"], ev["feature"], page):
            assert shown in where and f"strength {strength:.3g}" in where, where
            assert ph.value_text(value) in where  # with the spin-up time constant for rotor_lag
        assert ("time_constant_ms" in value) == (name == "rotor_lag")
        assert f"{name} {strength:.3g}" in text  # the final model's line
        # the held-out figure that kept it, with the margin and significance it had to meet
        kept = kept_text(ev["acceptance"])
        # on the holdout, at its replication level (acceptance.HOLDOUT_ALPHA) over the k candidates
        # the round tried (workflow.decide)
        alphas = [f"{0.05 / k:g}" for k in range(1, MAX_TRIALS + 1)]
        assert any(f"needed >= 5 % and p < {a})" in kept for a in alphas), kept
        assert f"{ev['acceptance']['alpha']:g}" in alphas
        assert kept in text and kept in page
    # the refit moved rotor_lag's strength, and only the refitted one is stated
    lag = data["evidence"]["rotor_lag"]["fitted_value"]["strength"]
    assert abs(first_fit - lag) > 0.05, (first_fit, lag)
    assert f"strength {first_fit:.3g}" not in text and f"strength {first_fit:.3g}" not in page
    assert f"<td>{lag:.3g}</td>" in page
