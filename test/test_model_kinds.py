"""One model file for every kind (network, physics, hybrid): round trips, version 1 files, bad input."""

from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path

import numpy as np
import pytest

from bldc_propulsion import contract as c
from bldc_propulsion.contract import HYBRID, MODEL_KINDS, NETWORK, PHYSICS
from bldc_propulsion.errors import ModelError
from bldc_propulsion.model import PHYSICS_SPEED, HybridModel, NetworkModel, load_model, save_model
from bldc_propulsion.physics.params import PLANT_FIELDS, BenchParams, PlantParams
from bldc_propulsion.physics.plant_model import PlantModel

sys.path.insert(0, str(Path(__file__).parent))
from _models import good_model  # noqa: E402

EFFECTS = {name: 1.0 for name in c.EFFECTS}


def plant_model() -> PlantModel:
    p = dataclasses.replace(BenchParams(), motor_kv_rpm_per_v=650.0, propeller_cp=0.05, sim_step_s=0.005)
    return PlantModel(p, {**EFFECTS, "rotor_lag": 1.3, "spin_down_asymmetry": 0.0}, 11.8,
                      metadata={"discrepancy": {"added": ["rotor_lag"]}})


def hybrid_model() -> HybridModel:
    rng = np.random.default_rng(3)
    net = NetworkModel((PHYSICS_SPEED, c.INPUT_PWM), [0.0, 0.0], [700.0, 1.0], -50.0, 50.0,
                       rng.normal(size=(4, 2)), rng.normal(size=4), rng.normal(size=4) / 4, 0.0,
                       thrust_coefficient=2.9e-5, metadata={"kind_note": "residual"})
    return HybridModel(plant_model(), net)


def arrays_in(path: Path) -> dict[str, np.ndarray]:
    with np.load(path) as z:
        return {k: z[k] for k in z.files}


def write(path: Path, arrays: dict[str, np.ndarray]) -> Path:
    with open(path, "wb") as fh:
        np.savez(fh, **arrays)
    return path


def test_version_1_file_loads_as_the_network_it_was(tmp_path):
    """A file as the format-1 writer (main before issue 13) wrote it: no ``kind``, version 1."""
    m = good_model()
    a = {k: v for k, v in m._arrays().items() if k != "kind"}
    a["format_version"] = np.array(1, dtype=np.int64)
    p = write(tmp_path / "v1.npz", a)
    back = load_model(p)
    assert isinstance(back, NetworkModel) and back.kind == "network"
    X = np.random.default_rng(0).uniform([9, 0.05, 0.05], [13, 0.1, 0.1], (50, 3))
    np.testing.assert_array_equal(back.forward(X), m.forward(X))
    assert load_model(p, kinds=MODEL_KINDS).input_names == m.input_names


def test_network_file_says_its_kind_and_version(tmp_path):
    p = tmp_path / "n.npz"
    save_model(good_model(), p)
    a = arrays_in(p)
    assert int(a["format_version"]) == 2 and str(a["kind"]) == "network"
    assert "physics_names" not in a


def test_physics_model_round_trip(tmp_path):
    m = plant_model()
    p = tmp_path / "phys.npz"
    save_model(m, p)
    a = arrays_in(p)
    assert str(a["kind"]) == PHYSICS and "W1" not in a
    assert tuple(a["physics_names"]) == PLANT_FIELDS and a["physics_values"].dtype == np.float64
    back = load_model(p, kinds=MODEL_KINDS)
    assert isinstance(back, PlantModel)
    assert back.params == m.params and type(back.params) is PlantParams
    assert back.params.motor_kv_rpm_per_v == 650.0 and back.params.sim_step_s == 0.005
    assert back.effects == m.effects and back.supply_v == 11.8
    assert back.thrust_coefficient == pytest.approx(BenchParams().thrust_coefficient)  # from CT
    assert back.metadata == m.metadata


def test_hybrid_model_round_trip(tmp_path):
    m = hybrid_model()
    p = tmp_path / "hyb.npz"
    save_model(m, p)
    back = load_model(p, kinds=MODEL_KINDS)
    assert isinstance(back, HybridModel) and back.kind == HYBRID
    assert back.plant.params == m.plant.params and back.plant.effects == m.plant.effects
    np.testing.assert_array_equal(back.network.W1, m.network.W1)
    assert back.network.input_names == (PHYSICS_SPEED, c.INPUT_PWM)
    assert back.thrust_coefficient == 2.9e-5 and back.metadata == {"kind_note": "residual"}


def test_a_use_that_runs_networks_refuses_other_kinds(tmp_path):
    p = tmp_path / "phys.npz"
    save_model(plant_model(), p)
    with pytest.raises(ModelError, match=rf"^{p}: kind physics: a network model is needed here$"):
        load_model(p, kinds=(NETWORK,))


def _physics_arrays(tmp_path: Path) -> dict[str, np.ndarray]:
    save_model(plant_model(), tmp_path / "ok.npz")
    return arrays_in(tmp_path / "ok.npz")


def _with_value(a: dict[str, np.ndarray], key: str, name: str, value: float) -> dict[str, np.ndarray]:
    names = [str(x) for x in a[key.replace("values", "names").replace("strengths", "names")]]
    v = a[key].copy()
    v[names.index(name)] = value
    return {**a, key: v}


@pytest.mark.parametrize("change, message", [
    (lambda a: {**a, "kind": np.array("quantum")}, "kind 'quantum' is not known (known: network, physics, hybrid)"),
    (lambda a: {**a, "kind": np.array(3)}, "kind must be a scalar unicode string"),
    (lambda a: {**a, "format_version": np.array(7)}, "format_version 7 is not supported (this program reads 1, 2)"),
    (lambda a: _with_value(a, "physics_values", "motor_rotor_inertia_kg_m2", -1e-6),
     "physics_values: motor_rotor_inertia_kg_m2 -1e-06 must be >= 0"),
    (lambda a: _with_value(a, "physics_values", "propeller_mass_kg", -0.02),
     "physics_values: propeller_mass_kg -0.02 must be > 0"),
    (lambda a: _with_value(a, "physics_values", "motor_kv_rpm_per_v", 0.0),
     "physics_values: motor_kv_rpm_per_v 0.0 must be > 0"),
    (lambda a: _with_value(a, "physics_values", "propeller_cp", np.nan), "physics_values contains NaN or inf"),
    (lambda a: _with_value(a, "effect_strengths", "rotor_lag", -1.0),
     "effect_strengths: rotor_lag strength must be a finite number >= 0"),
    (lambda a: _with_value(a, "effect_strengths", "spin_down_asymmetry", 2.0),
     "effect_strengths: spin_down_asymmetry must be in [0, 1]"),
    (lambda a: {**a, "physics_names": np.array(["warp_factor", *map(str, a["physics_names"][1:])])},
     "physics_names: 'warp_factor' is not known"),
    (lambda a: {**a, "physics_names": a["physics_names"][1:], "physics_values": a["physics_values"][1:]},
     "physics_names: missing battery_series_resistance_ohm"),
    (lambda a: {**a, "physics_values": a["physics_values"][:-1]}, "physics_values must have shape"),
    (lambda a: {**a, "effect_names": a["effect_names"][:-1], "effect_strengths": a["effect_strengths"][:-1]},
     "effect_names: missing motor_heating"),
    (lambda a: {**a, "supply_v": np.array(0.0)}, "supply_v 0.0 must be a voltage > 0"),
    (lambda a: {**a, "supply_tau_s": np.array(-1.0)}, "supply_tau_s -1.0 must be >= 0"),
    (lambda a: {k: v for k, v in a.items() if k != "supply_v"}, "missing array(s) supply_v"),
])
def test_bad_physics_file_is_one_line_naming_file_and_field(tmp_path, change, message):
    p = write(tmp_path / "bad.npz", change(_physics_arrays(tmp_path)))
    with pytest.raises(ModelError) as info:
        load_model(p, kinds=MODEL_KINDS)
    text = str(info.value)
    assert text.startswith(f"{p}: ") and message in text and "\n" not in text


def test_hybrid_network_inputs_must_match(tmp_path):
    save_model(hybrid_model(), tmp_path / "h.npz")
    a = arrays_in(tmp_path / "h.npz")
    p = write(tmp_path / "bad.npz", {**a, "input_names": np.array([c.INPUT_BATTERY_VOLTAGE, c.INPUT_PWM])})
    with pytest.raises(ModelError, match=rf"^{p}: input_names: a hybrid's network must take physics_speed"):
        load_model(p, kinds=MODEL_KINDS)
    q = write(tmp_path / "net.npz", {k: v for k, v in {**a, "kind": np.array("network")}.items()
                                    if k not in ("physics_names", "physics_values", "effect_names",
                                                 "effect_strengths", "supply_v")})
    with pytest.raises(ModelError, match=rf"^{q}: input_names: physics_speed is the physics part's speed"):
        load_model(q, kinds=MODEL_KINDS)
    r = write(tmp_path / "nophys.npz", {**a, "physics_names": a["physics_names"][:3]})
    with pytest.raises(ModelError, match=rf"^{r}: physics_names"):
        load_model(r, kinds=MODEL_KINDS)
    with pytest.raises(ModelError, match="a hybrid's network must take physics_speed"):
        HybridModel(plant_model(), good_model())


def test_constructor_refuses_unphysical_constants():
    with pytest.raises(ModelError, match="^model: physics_values: motor_kv_rpm_per_v -1.0 must be > 0"):
        PlantModel(dataclasses.replace(PlantParams(), motor_kv_rpm_per_v=-1.0), EFFECTS, 12.0)
    with pytest.raises(ModelError, match="^model: effect_names: missing"):
        PlantModel(PlantParams(), {"rotor_lag": 1.0}, 12.0)


def test_cli_discrepancy_model_takes_physics_and_hybrid_models(tmp_path):
    """`discrepancy --model` of a physics model is `--physics MODEL.npz` (same figures); of a
    hybrid, the physics path on its physics part, said in one warning line, -o a physics model;
    network-only options are refused naming the model."""
    from test_discrepancy import cli
    from test_discrepancy_physics import recordings

    paths = recordings(tmp_path, "rotor_lag")  # the bench with every effect, rotor_lag included
    lacking = dataclasses.replace(plant_model(), params=dataclasses.replace(BenchParams(), sim_step_s=0.005),
                                  effects={**EFFECTS, "rotor_lag": 0.0}, metadata={})
    plant = tmp_path / "plant.npz"
    save_model(lacking, plant)
    hyb = tmp_path / "hyb.npz"
    save_model(dataclasses.replace(hybrid_model(), plant=lacking), hyb)
    found = tmp_path / "found.npz"
    common = ["--measured", *paths["measured"], "--holdout", *paths["holdout"], "--max-effects", "1", "--json"]
    runs = {"physics": cli("discrepancy", "--physics", str(plant), *common),
            "model": cli("discrepancy", "--model", str(plant), *common),
            "hybrid": cli("discrepancy", "--model", str(hyb), *common, "-o", str(found))}
    for name, proc in runs.items():
        assert proc.returncode == 0, (name, proc.stderr)
    data = {name: json.loads(proc.stdout) for name, proc in runs.items()}
    for name in ("model", "hybrid"):
        assert data[name]["named"] == data["physics"]["named"] == ["rotor_lag"]
        assert data[name]["holdout_rmse_before"] == pytest.approx(data["physics"]["holdout_rmse_before"], rel=1e-9)
        assert data[name]["holdout_rmse_after"] == pytest.approx(data["physics"]["holdout_rmse_after"], rel=1e-9)
    said = [w for w in data["hybrid"]["warnings"] if "hybrid" in w]
    assert said == [f"--model {hyb}: a hybrid: its physics part is checked, without the network's correction; "
                    f"-o {found} gets a physics model"]
    assert not any("hybrid" in w for w in data["model"]["warnings"])
    m = load_model(found, kinds=(PHYSICS,))
    assert m.effects["rotor_lag"] > 0.3 and m.metadata["discrepancy"]["base"] == str(hyb)
    proc = cli("discrepancy", "--model", str(hyb), "--measured", *paths["measured"], "--hidden", "4")
    assert proc.returncode == 2 and proc.stderr.strip().count("\n") == 0
    assert f"--hidden: retrains a network, so it goes with a network --model, not the hybrid model {hyb}" \
        in proc.stderr


def test_discrepancy_physics_writes_and_reads_a_model_file(tmp_path):
    """-o x.npz writes a physics model; --physics accepts it as its CONFIG; JSON still works."""
    from test_discrepancy import cli
    from test_discrepancy_physics import recordings

    paths = recordings(tmp_path, "rotor_lag")
    cfg = tmp_path / "base.json"
    cfg.write_text(json.dumps({"effects": {**EFFECTS, "rotor_lag": 0.0}}))
    out = tmp_path / "found.npz"
    proc = cli("discrepancy", "--physics", str(cfg), "--measured", *paths["measured"],
               "--holdout", *paths["holdout"], "--max-effects", "1", "-o", str(out), "--json")
    assert proc.returncode == 0, proc.stderr
    data = json.loads(proc.stdout)
    assert data["named"] == ["rotor_lag"] and data["model"] == str(out)
    m = load_model(out, kinds=(PHYSICS,))
    assert m.effects["rotor_lag"] == pytest.approx(data["evidence"]["rotor_lag"]["fitted_parameters"]["strength"])
    assert m.params.motor_kv_rpm_per_v == pytest.approx(data["physics"]["params"]["motor_kv_rpm_per_v"])
    assert m.supply_v == pytest.approx(data["physics"]["supply_v"])
    assert m.metadata["discrepancy"]["base"] == str(cfg)
    # the model file as the CONFIG: every effect on, nothing left to name
    again = cli("discrepancy", "--physics", str(out), "--measured", *paths["measured"], "--json")
    assert again.returncode == 0, again.stderr
    assert json.loads(again.stdout)["named"] == []
    # an existing model file is replaced only with --force
    refused = cli("discrepancy", "--physics", str(cfg), "--measured", *paths["measured"], "-o", str(out))
    assert refused.returncode == 2 and "already exists" in refused.stderr
