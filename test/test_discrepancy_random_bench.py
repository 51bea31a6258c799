"""The discrepancy workflow on a bench it was not tuned on (sim.random_bench), physics path.

A small case of experiments/physics_confusion.py: a bench drawn from a tuning seed (other Kv,
resistance, inertia, CT/CP, dead time, start level, pack, noise, thermal constants, friction;
the experiment's tables report seeds 0-9), the nominal bench physics with every effect on but
the hidden one as the model, reference recordings without the effect, measured and holdout with
it at a drawn strength.
The hidden effect must be named first, with its strength within 30 % of the truth in the model's
units; on recordings without it (the control), nothing may be named.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from bldc_propulsion import contract as c
from bldc_propulsion.discrepancy import physics as ph
from bldc_propulsion.discrepancy.physics_kind import PhysicsKind
from bldc_propulsion.discrepancy.workflow import Options, run_physics_workflow
from bldc_propulsion.physics import config as pc
from bldc_propulsion.recordings import load_signals
from bldc_propulsion.sim import random_bench as rb

sys.path.insert(0, str(Path(__file__).parent))
from test_discrepancy import _bag  # noqa: E402

SEED = 101  #: a tuning seed (>= 100), not one of the reported 0-4


def _run(d: Path, effect: str, hidden_in_measured: bool) -> tuple[dict, float]:
    bench = rb.draw_bench(SEED)
    strength = rb.draw_strength(effect, SEED)
    on = {effect: strength if hidden_in_measured else 0.0}
    off = {effect: 0.0}
    ref = [load_signals(_bag(d, f"r{k}_{kd}", kd, 4000 + k, off, 1.0, 30.0, bench))
           for k, kd in enumerate(["steps", "sweep"])]
    meas = [load_signals(_bag(d, f"m{k}_{hidden_in_measured}", "steps", 5000 + k, on, 1.0, 30.0, bench))
            for k in range(2)]
    hold = [load_signals(_bag(d, f"h_{hidden_in_measured}", "steps", 6000, on, 1.0, 30.0, bench))]
    return workflow(effect, meas, ref, hold), rb.model_strength(effect, strength, bench)


def workflow(effect: str, meas: list, ref: list, hold: list) -> dict:
    """The physics path with the nominal bench, every effect on but ``effect``, as the model."""
    model = pc.PhysicsConfig(pc.load_config(None).params, {**{e: 1.0 for e in c.EFFECTS}, effect: 0.0})
    return run_physics_workflow(model, meas, ref, hold, Options(max_effects=2), lambda m: None).data


_RUNS: dict[tuple[str, bool], tuple[dict, float]] = {}


def run(d: Path, effect: str, hidden_in_measured: bool) -> tuple[dict, float]:
    """``_run`` once per session."""
    key = (effect, hidden_in_measured)
    if key not in _RUNS:
        _RUNS[key] = _run(d, effect, hidden_in_measured)
    return _RUNS[key]


@pytest.fixture(scope="module")
def bags(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("random_bench")


def test_hidden_effect_on_a_drawn_bench(bags):
    data, _ = run(bags, "rotor_lag", True)
    assert data["named"][:1] == ["rotor_lag"], data["considered_not_added"]
    assert data["holdout_rmse_after"] <= 0.7 * data["holdout_rmse_before"]
    # 30 s reference recordings barely warm the winding: a heating strength fitted there may end
    # at its bound, and that must be said (not silently used)
    for hit in data["reference_fit"]["at_bound"]:
        assert any(hit in w for w in data["warnings"]), (hit, data["warnings"])


def test_hidden_effect_strength_within_30_percent_of_truth(bags):
    """The issue's goal on one drawn bench. Seed 101's bench missed it (rotor_lag 0.44 vs 0.68
    true, -35 %; a strict xfail) before the benches drew the motor's thermal and friction
    constants too; the bench it draws now (every other constant the same) meets it. One bench
    either way: the spread is the confusion table's (experiments/physics_confusion.py)."""
    data, truth = run(bags, "rotor_lag", True)
    fitted = data["evidence"]["rotor_lag"]["fitted_parameters"]["strength"]
    assert fitted == pytest.approx(truth, rel=0.3)


def test_control_on_a_drawn_bench_names_nothing(bags):
    data, _ = run(bags, "rotor_lag", False)
    assert data["named"] == [], data["iterations"]


def test_a_slow_drift_in_hot_recordings_is_not_named_heating(bags):
    """Seed 101's heating control of experiments/physics_confusion.py (the same recordings): no
    heating anywhere, the model without it, long loads measured. Before the throttle map was
    calibrated (its bench bends it, x^1.15) and the dead time fitted, a thermal state fitted the
    misfit as a slow drift and improved the holdout (3.3 -> 3.0 rad/s, accepted on its own), and
    only the identification kept heating out. The held-out score now rejects it outright (the
    workflow's verdict on these controls is the experiment's, one seed in six: a whole workflow
    on 11 minutes of recordings is experiment-size); the identification, the safeguard for a
    drift the model lacks (a second pack RC branch, a drifting sensor), must still say the
    speed's response to the thermal state is the reference's, from the data alone."""
    from test_discrepancy import REF, SCENARIOS

    bench = rb.draw_bench(SEED)
    _, ref_extra, meas_spec, _ = SCENARIOS["motor_heating"]

    def recordings(spec: list, tag: str, seed0: int, heating: float = 0.0) -> list:
        return [load_signals(_bag(bags, f"{tag}{k}_{kd}", kd, seed0 + 100 * SEED + k, {"motor_heating": heating},
                                  soc, dur, bench))
                for k, (kd, soc, dur) in enumerate(spec)]

    kind = PhysicsKind(pc.load_config(None))
    kind.ref_data = ph.blocked(recordings([*REF, *ref_extra], "hr", 4000), "reference")
    kind.meas_data = ph.blocked(recordings(meas_spec, "hm", 5000), "measured")
    assert "the reference's" in (kind.contradicted("motor_heating") or "")
    # the same loads with the winding heating (the experiment's drawn strength): not the reference's
    kind.meas_data = ph.blocked(recordings(meas_spec, "hx", 5000, rb.draw_strength("motor_heating", SEED)),
                                "measured")
    assert kind.contradicted("motor_heating") is None
