"""The physics fit starts from the user's motor and refuses what the data cannot support.

- ``physics.sizing.physics_start``: the nominal bench resized to a stated Kv, propeller and pack, checked
  against numbers computed by hand from its stated relations (CT ~ sqrt(P/D), momentum theory for
  CP, winding resistance ~ V^2/P, ...), and the nominal bench stated as itself is the nominal bench.
- ``physics.config.start_model``: a CONFIG wins over a stated prior where both give a constant, and says so.
- ``train --kind physics`` on a simulated bench of another motor class (``draw_far_bench``): with
  its true Kv and propeller stated, the fitted Kv is the bench's (within 30 %, not at a bound);
  without them the fit starts from the 12 in bench and a warning says so.
- A stated Kv the recordings contradict (the nominal 710 kv bench trained as a 2000 kv motor): the
  fit ends at a bound of the stated range, so no model is written (exit 2, one line naming the
  constant, its value, the range and the stated value).
- The F80 thrust-stand log (../shared/real/esc_test) with its motor's rating: Kv within 30 %.
"""

from __future__ import annotations

import csv
import io
import json
import math
import re
import sys
from pathlib import Path

import numpy as np
import pytest

from bldc_propulsion import contract as c
from bldc_propulsion.discrepancy.identify import Heating
from bldc_propulsion.physics import config as pc
from bldc_propulsion.physics import fit as pf
from bldc_propulsion.physics.params import BenchParams
from bldc_propulsion.physics.sizing import (
    CP_RANGE_FACTOR,
    KV_RANGE_FACTOR,
    figure_of_merit,
    physics_start,
    propeller_cp_from_ct,
    propeller_ct_from_geometry,
)
from bldc_propulsion.priors import INCH_M, MotorPriors
from bldc_propulsion.sim import simulate
from bldc_propulsion.sim.random_bench import draw_far_bench
from bldc_propulsion.sim.record import write_sim_bag

sys.path.insert(0, str(Path(__file__).parent))
from test_discrepancy import cli  # noqa: E402

REAL = Path(__file__).resolve().parents[2] / "shared" / "real"
F80 = REAL / "esc_test" / "Log_2019-11-09_181347.csv"
#: every effect on, the ESC braking actively (BLHeli's default)
EFFECTS = {**{n: 1.0 for n in c.EFFECTS}, "spin_down_asymmetry": 0.0}
#: draw_far_bench(22): a 3S bench with a 1086 kv motor (1.53x the nominal's) on a 9.9 in propeller
FAR_SEED = 22


# --- the start point, by hand --------------------------------------------------------------------------
def test_propeller_coefficients_from_diameter_and_pitch_by_hand():
    nom = BenchParams()
    # CT ~ sqrt(pitch / diameter), anchored at the 12x4.5's 0.105: a 7x5.6 has P/D 0.8 vs 0.375
    ct = propeller_ct_from_geometry(7 * INCH_M, 5.6 * INCH_M, nom.propeller_ct, nom.propeller_diameter_m)
    assert ct == pytest.approx(0.105 * math.sqrt(0.8 / 0.375), rel=1e-12)
    # momentum theory: CP = CT^1.5 / (FM sqrt(pi/2)); the 12x4.5's CT 0.105 and CP 0.042 give FM 0.6464
    fm = figure_of_merit(0.105, 0.042)
    assert fm == pytest.approx(0.105**1.5 / (0.042 * math.sqrt(math.pi / 2)), rel=1e-12)
    assert fm == pytest.approx(0.6464, abs=1e-4)
    assert propeller_cp_from_ct(0.105, fm) == pytest.approx(0.042, rel=1e-12)
    assert propeller_cp_from_ct(ct, fm) == pytest.approx(0.15336**1.5 / (0.6464 * 1.253314), rel=1e-3)  # 0.0741


def test_the_nominal_bench_stated_as_itself_is_the_nominal_bench():
    nom = BenchParams()
    start = physics_start(MotorPriors(motor_kv_rpm_per_v=710.0, cells=3, propeller_diameter_m=12 * INCH_M,
                                      propeller_pitch_m=4.5 * INCH_M))
    assert start.params == nom  # every constant, bit for bit (so a CONFIG written from it lists none)
    assert start.stated == {"motor_kv_rpm_per_v": "--motor-kv 710",
                            "propeller_cp": "--prop-diameter-in 12 --prop-pitch-in 4.5"}
    assert start.ranges["motor_kv_rpm_per_v"] == pytest.approx((710 / KV_RANGE_FACTOR, 710 * KV_RANGE_FACTOR))
    assert start.ranges["propeller_cp"] == pytest.approx((0.042 / CP_RANGE_FACTOR, 0.042 * CP_RANGE_FACTOR))


def test_a_motor_of_twice_the_kv_is_sized_for_eight_times_the_power():
    """Same pack, same propeller, Kv x2: full-drive speed x2 (the same share of the no-load speed),
    shaft power ~ w^3 x8, torque x4. Winding and ESC resistance ~ V^2/P: /8; no-load current ~ P/V:
    x8; the pack's series resistance ~ V/P: /8; the motor's bell inertia and thermal capacity ~
    torque: x4, its thermal resistance /4 (the thermal time constant kept)."""
    nom = BenchParams()
    p = physics_start(MotorPriors(motor_kv_rpm_per_v=1420.0, cells=3)).params
    assert p.winding_resistance_ohm == pytest.approx(0.20 / 8, rel=1e-9)
    assert p.esc_resistance_ohm == pytest.approx(0.06 / 8, rel=1e-9)
    assert p.motor_no_load_current_a == pytest.approx(0.4 * 8, rel=1e-9)
    assert p.battery_series_resistance_ohm == pytest.approx(0.035 / 8, rel=1e-9)
    assert p.motor_rotor_inertia_kg_m2 == pytest.approx(4e-6 * 4, rel=1e-9)
    assert p.motor_thermal_capacity_j_per_k == pytest.approx(70.0 * 4, rel=1e-9)
    assert p.motor_thermal_resistance_k_per_w == pytest.approx(1.8 / 4, rel=1e-9)
    assert (p.propeller_diameter_m, p.propeller_cp, p.propeller_mass_kg) == \
        (nom.propeller_diameter_m, nom.propeller_cp, nom.propeller_mass_kg)


def test_a_smaller_propeller_and_what_is_not_stated():
    nom = BenchParams()
    # a 6 in propeller (half the diameter) of the nominal pitch ratio on the nominal motor: mass ~ D^3,
    # CP the nominal's, shaft power ~ D^5 = 1/32 at the same speed, so the winding is 32x the nominal's
    start = physics_start(MotorPriors(propeller_diameter_m=6 * INCH_M), voltage_v=3 * 3.95)
    p = start.params
    assert p.propeller_mass_kg == pytest.approx(0.020 / 8, rel=1e-9)
    assert p.propeller_cp == pytest.approx(nom.propeller_cp, rel=1e-12)
    assert p.winding_resistance_ohm == pytest.approx(0.20 * 32, rel=1e-9)
    # neither Kv nor a pitch stated: nothing to hold a fit against, no narrower range
    assert start.stated == {} and start.ranges == {}
    # a pole count alone sizes nothing
    assert physics_start(MotorPriors(pole_count=14)) is None
    # a pack's voltage outside its cells' range is said
    warned = physics_start(MotorPriors(cells=4), voltage_v=11.1).warnings
    assert len(warned) == 1 and warned[0].startswith("--cells 4: the recordings' median battery voltage 11.10 V")


def test_a_config_wins_where_it_and_a_prior_both_give_a_constant(tmp_path):
    cfg = tmp_path / "bench.json"
    cfg.write_text(json.dumps({"params": {"motor_kv_rpm_per_v": 800.0}}))
    priors = MotorPriors(motor_kv_rpm_per_v=1900.0, propeller_diameter_m=7 * INCH_M, propeller_pitch_m=5.6 * INCH_M)
    model, notes, warnings = pc.start_model(str(cfg), priors, 15.5)
    assert model.params.motor_kv_rpm_per_v == 800.0 and model.source == str(cfg)
    assert model.params.propeller_diameter_m == pytest.approx(7 * INCH_M)  # not in the CONFIG: the prior's
    assert warnings == [f"--motor-kv 1900: --physics {cfg} sets motor_kv_rpm_per_v 800, which wins over the "
                        "stated 1900"]
    assert set(model.stated) == {"propeller_cp"} and set(model.ranges) == {"propeller_cp"}
    assert model.basis("propeller_cp") == ("stated (--prop-diameter-in 7 --prop-pitch-in 5.6)", True)
    assert model.basis("motor_kv_rpm_per_v") == ("CONFIG", True)
    # neither: the nominal bench, and the one line that says so
    nominal, _, warned = pc.start_model(None, MotorPriors(), 12.0)
    assert nominal.params.motor_kv_rpm_per_v == 710.0 and warned == [pc.NOMINAL_START_WARNING]
    assert warned[0].startswith("no --motor-kv/--prop-diameter-in: starting from the simulator's 12 in bench")


def test_a_kv_far_from_the_stated_one_is_flagged_against_it():
    priors = MotorPriors(motor_kv_rpm_per_v=1900.0)
    start, _, _ = pc.start_model(None, priors, 15.5)
    consts = np.array(list(start.constants().values()))
    anchor, span = pf.base_window(start)
    assert anchor[0] == pytest.approx(1900.0) and span[0] == pytest.approx(math.log(KV_RANGE_FACTOR))
    fit = pf.Fit(start.with_constants([1900.0 * KV_RANGE_FACTOR, *consts[1:]]), np.zeros(1),
                 np.zeros((1, len(pc.CALIBRATED))), 0.0, anchor, span)
    (flag,) = [f for f in pf.fit_flags(fit, start, "test fit") if f.quantity == "motor_kv_rpm_per_v"]
    assert flag.at_bound and flag.stated and flag.blocks
    assert flag.text() == (f"test fit: motor_kv_rpm_per_v fitted {1900 * KV_RANGE_FACTOR:.4g} vs stated "
                           f"(--motor-kv 1900) 1900 (at a bound of its range {1900 / KV_RANGE_FACTOR:.4g}-"
                           f"{1900 * KV_RANGE_FACTOR:.4g})")
    # Kv 1e6 on the nominal bench (no priors): at the bound of its range, never silent
    nominal = pc.load_config(None)
    a, s = pf.base_window(nominal)
    far = pf.Fit(nominal.with_constants([710e3, *list(nominal.constants().values())[1:]]), np.zeros(1),
                 np.zeros((1, len(pc.CALIBRATED))), 0.0, a, s)
    (kv,) = [f for f in pf.fit_flags(far, nominal, "test fit") if f.quantity == "motor_kv_rpm_per_v"]
    assert kv.at_bound and kv.blocks and "nominal (no CONFIG given)" in kv.text()


def test_no_voltage_says_the_full_drive_speed_in_words():
    text = Heating(0.0, 0.0, 0.0).describe()
    assert "inf" not in text and "full-drive speed, not computed here: no battery voltage" in text
    assert Heating(0.0, 0.0, 0.0).as_dict()["full_drive_speed_rad_s"] is None


# --- train --kind physics on simulated benches ------------------------------------------------------------
@pytest.fixture(scope="module")
def far_bags(tmp_path_factory) -> dict[str, list[str]]:
    """A staircase (training) and random steps (validation) on a bench of another motor class."""
    d = tmp_path_factory.mktemp("far_bench")
    bench = draw_far_bench(FAR_SEED)
    out = {}
    for what, profile, seed, soc, dur in (("train", "staircase", 1, 1.0, 16.0),
                                          ("validation", "random_steps", 2, 0.8, 10.0)):
        path = d / what
        write_sim_bag(simulate(profile, dur, seed, effects=EFFECTS, soc=soc, params=bench), path)
        out[what] = [str(path)]
    return out


def _train(bags: dict[str, list[str]], out: Path, *options: str):
    return cli("train", *bags["train"], "--validation", *bags["validation"], "--kind", "physics", "-o", str(out),
               "--json", *options)


def test_another_motor_class_with_its_priors_gives_its_kv(far_bags, tmp_path):
    bench = draw_far_bench(FAR_SEED)
    kv, diameter = bench.motor_kv_rpm_per_v, bench.propeller_diameter_m / INCH_M
    assert kv / BenchParams().motor_kv_rpm_per_v > 1.5 and diameter < 10.0  # another class than 710 kv, 12 in
    proc = _train(far_bags, tmp_path / "with.npz", "--motor-kv", f"{kv:.0f}", "--prop-diameter-in", f"{diameter:.1f}",
                  "--cells", str(bench.battery_cells))
    assert proc.returncode == 0, proc.stderr
    data = json.loads(proc.stdout)
    fitted = data["constants"]["motor_kv_rpm_per_v"]
    assert abs(fitted / kv - 1.0) < 0.3, fitted
    assert not any("motor_kv_rpm_per_v" in w for w in data["warnings"]), data["warnings"]  # not at a bound
    assert not any(w.startswith("no --motor-kv") for w in data["warnings"])
    # without them: the 12 in bench is the start, and one warning line says so
    proc = _train(far_bags, tmp_path / "without.npz")
    assert proc.returncode == 0, proc.stderr
    data = json.loads(proc.stdout)
    assert data["warnings"][0] == pc.NOMINAL_START_WARNING
    assert f"warning: {pc.NOMINAL_START_WARNING}" in proc.stderr.splitlines()


@pytest.fixture(scope="module")
def nominal_bags(tmp_path_factory) -> dict[str, list[str]]:
    d = tmp_path_factory.mktemp("nominal_bench")
    out = {}
    for what, profile, seed, dur in (("train", "staircase", 5, 12.0), ("validation", "random_steps", 6, 8.0)):
        path = d / what
        write_sim_bag(simulate(profile, dur, seed, effects=EFFECTS, soc=0.9), path)
        out[what] = [str(path)]
    return out


def test_a_stated_kv_the_recordings_contradict_is_refused(nominal_bags, tmp_path):
    """The nominal 710 kv bench trained as a 2000 kv motor: every fit either ends on the stated
    range's lower bound (1538 rpm/V) or reaches its edge with an implausible CP (which then absorbs
    the wrong Kv), so the model is not written."""
    out = tmp_path / "m.npz"
    proc = _train(nominal_bags, out, "--motor-kv", "2000")
    assert proc.returncode == 2 and not out.exists()
    assert proc.stderr.count("\n") == 1 + proc.stderr.count("start:") + proc.stderr.count("fitting") \
        + proc.stderr.count("  RMSE") + proc.stderr.count("recordings\n")  # progress, then one error line
    line = proc.stderr.splitlines()[-1]
    assert "--motor-kv 2000" in line and "all 4 fits contradict it" in line, line
    # the fitted value is printed rounded: 1538 or 1539 at the bound 2000 / KV_RANGE_FACTOR = 1538.46
    kv_at_bound = re.search(r"motor_kv_rpm_per_v fitted 153[89] ", line) is not None \
        and f"at a bound of its range {2000 / KV_RANGE_FACTOR:.4g}-{2000 * KV_RANGE_FACTOR:.4g}" in line \
        and "stated" in line
    assert kv_at_bound or ("propeller_cp fitted" in line and "implausible" in line), line


def test_the_held_pack_resistance_is_said_unless_a_config_states_it(nominal_bags, tmp_path):
    """Training holds the pack's series resistance (it is not fitted): unless a CONFIG states it, the
    model carries the simulator's bench's 0.035 ohm, and one warning line says so; a CONFIG that
    states it sets it, and the line goes."""
    proc = _train(nominal_bags, tmp_path / "a.npz")
    assert proc.returncode == 0, proc.stderr
    data = json.loads(proc.stdout)
    assert data["constants"]["battery_series_resistance_ohm"] == BenchParams().battery_series_resistance_ohm == 0.035
    held = [w for w in data["warnings"] if w.startswith("battery_series_resistance_ohm held at 0.035 (the simulator's "
                                                         "12 in bench's), not fitted")]
    assert len(held) == 1 and f"warning: {held[0]}" in proc.stderr.splitlines(), data["warnings"]
    cfg = tmp_path / "c.json"
    cfg.write_text(json.dumps({"params": {"battery_series_resistance_ohm": 0.021}}))
    proc = _train(nominal_bags, tmp_path / "b.npz", "--physics-config", str(cfg))
    assert proc.returncode == 0, proc.stderr
    data = json.loads(proc.stdout)
    assert data["constants"]["battery_series_resistance_ohm"] == 0.021
    assert not any("battery_series_resistance_ohm held" in w for w in data["warnings"]), data["warnings"]


def test_physics_config_goes_with_the_physics(nominal_bags, tmp_path):
    cfg = tmp_path / "c.json"
    cfg.write_text(json.dumps({"params": {"motor_kv_rpm_per_v": 700.0}}))
    proc = cli("train", *nominal_bags["train"], "--validation", *nominal_bags["validation"], "--physics-config",
               str(cfg), "-o", str(tmp_path / "n.npz"))
    assert proc.returncode == 2 and "--physics-config" in proc.stderr and "--kind physics or hybrid" in proc.stderr


# --- the F80 thrust-stand log ---------------------------------------------------------------------------
def _piece(src: Path, dst: Path, t0: float, t1: float) -> Path:
    """The log's rows with t0 <= time < t1, as a CSV of the same format."""
    rows = list(csv.reader(io.StringIO(src.read_text(encoding="utf-8-sig"), newline="")))
    col = rows[0].index("Time (s)")
    keep = [r for r in rows[1:] if len(r) > col and r[col].strip() and t0 <= float(r[col]) < t1]
    with open(dst, "w", encoding="utf-8", newline="") as fh:
        csv.writer(fh).writerows([rows[0], *keep])
    return dst


@pytest.mark.skipif(not F80.is_file(), reason="esc_test logs not available")
def test_the_f80_log_with_its_rating_gives_a_kv_near_it(tmp_path):
    """T-Motor F80 Pro 1900 kv, 7x5.6 in three-blade propeller on a 16 V supply: the steps
    1150-1450 us for training, 1450-1550 us for validation (a piece of the log). The fitted Kv is
    ~2350 rpm/V: the plant's throttle map starts at its start threshold, this ESC's at ~1000 us,
    so Kv rises to make up the slope (its torque per ampere says ~2100)."""
    bags = {}
    for what, (t0, t1) in (("train", (14.0, 48.0)), ("validation", (48.0, 58.0))):
        imp = cli("import-csv", str(_piece(F80, tmp_path / f"{what}.csv", t0, t1)), "-o", str(tmp_path / what))
        assert imp.returncode == 0, imp.stderr
        bags[what] = [str(tmp_path / what)]
    proc = _train(bags, tmp_path / "f80.npz", "--motor-kv", "1900", "--prop-diameter-in", "7",
                  "--prop-pitch-in", "5.6", "--pole-count", "14")
    assert proc.returncode == 0, proc.stderr
    data = json.loads(proc.stdout)
    assert abs(data["constants"]["motor_kv_rpm_per_v"] / 1900.0 - 1.0) < 0.3, data["constants"]
