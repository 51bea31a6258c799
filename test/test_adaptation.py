"""Online adaptation of a physics model's parameters (core/adaptation.py) against known truth: the
RLS against batch least squares by hand, and simulated flights on a randomized bench (bench seed 2,
not the default bench) whose physics model was fitted on a HEALTHY recording of it, with a
propeller loss injected mid-flight (sim/faults.py) and the simulator's true speed as the truth."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

from bldc_propulsion.core.adaptation import (
    ADAPTED,
    BOUNDS,
    HEATING_BOUNDS_K,
    AdaptationConfig,
    PhysicsAdapter,
    _projected,
    adapter_for,
)
from bldc_propulsion.core.estimator import MEASURED_SPEED_MAX_AGE_S, ThrustEstimator
from bldc_propulsion.errors import BadInputError
from bldc_propulsion.sim import simulate
from bldc_propulsion.sim.faults import Fault
from bldc_propulsion.sim.random_bench import draw_bench

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from bench_adaptation import rmse, run_flight, thrust_rmse  # noqa: E402
from bench_health import fit_model  # noqa: E402

BENCH = 2  #: a randomized bench (one of the adapter's tuning benches; the benchmark reports others)
ONSET_S = 30.0
LOSS = 0.12


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    """The bench's physics model, fitted on its healthy recordings (bench_health's helper)."""
    return fit_model(BENCH, tmp_path_factory.mktemp("adaptation_model"))[0]


@pytest.fixture(scope="module")
def faulted():
    """60 s of random steps on the bench, the propeller losing LOSS of CT and CP at ONSET_S."""
    return simulate("random_steps", 60.0, 2201, params=draw_bench(BENCH), soc=0.8,
                    faults=[Fault("propeller_damage", LOSS, ONSET_S)])


@pytest.fixture(scope="module")
def healthy():
    return simulate("random_steps", 60.0, 2202, params=draw_bench(BENCH), soc=0.7)


# --- the estimator by hand ---------------------------------------------------------------------------
def test_rls_equals_batch_least_squares_with_the_prior():
    """No forgetting, no limit: after n samples theta is the regularised least squares
    (sum phi phi^T / r + P0^-1)^-1 sum phi y / r, and P its inverse (the textbook identity)."""
    cfg = AdaptationConfig(memory_s=1e12, innovation_limit=1e9, prior_sigma=(0.1, 1.0))
    from bldc_propulsion.contract import EFFECTS
    from bldc_propulsion.physics.params import PlantParams
    from bldc_propulsion.physics.plant_model import PlantModel

    ad = PhysicsAdapter(PlantModel(PlantParams(sim_step_s=0.005), dict.fromkeys(EFFECTS, 1.0), 12.0), cfg)
    rng = np.random.default_rng(3)
    phi = np.column_stack([rng.uniform(50.0, 200.0, 300), rng.uniform(-20.0, -2.0, 300)])
    truth = np.array([0.08, 0.6])
    r = 4.0
    y = phi @ truth + rng.normal(0.0, 2.0, 300)
    for k in range(300):
        ad._learn(k * 0.01, float(y[k] - phi[k] @ np.array(ad.theta)), float(phi[k, 0]), float(phi[k, 1]), r)
    A = phi.T @ phi / r + np.diag([1 / 0.1**2, 1 / 1.0**2])
    np.testing.assert_allclose(ad.theta, np.linalg.solve(A, phi.T @ y / r), rtol=1e-9)
    P, Pinv = ad._P, np.linalg.inv(A)  # (the adapter keeps the upper triangle)
    np.testing.assert_allclose([P[0][0], P[0][1], P[1][1]], [Pinv[0, 0], Pinv[0, 1], Pinv[1, 1]], rtol=1e-6)
    assert ad.theta == pytest.approx(truth, abs=0.05)


def test_a_network_has_nothing_to_adapt_and_bad_settings_are_one_line():
    sys.path.insert(0, str(Path(__file__).parent))
    from _models import good_model

    with pytest.raises(BadInputError, match="physics or hybrid"):
        adapter_for(good_model())
    with pytest.raises(BadInputError, match="memory_s"):
        AdaptationConfig(memory_s=-1.0)


def test_rebuilds_after_the_first_lift_the_lanes_without_a_jump():
    """At a rebuild the lanes' states move along their sensitivities to the new constants, so the
    prediction does not jump: right after each rebuild the correction is where the rebuilt lanes
    settle, to the linearisation's second order. A lift that divides by the lane units instead of
    multiplying lands a third of the propeller's step short and overshoots the friction's; the
    first rebuild, from the offline constants, cannot tell: the units are 1 there."""
    from bldc_propulsion.contract import EFFECTS
    from bldc_propulsion.physics.params import PlantParams
    from bldc_propulsion.physics.plant_model import PlantModel

    ad = PhysicsAdapter(PlantModel(PlantParams(sim_step_s=0.005), dict.fromkeys(EFFECTS, 1.0), 12.0))
    ad.update_pwm(0.0, 0.07)
    ad.update_voltage(0.0, 11.5)
    t = 0.0

    def settle() -> float:
        nonlocal t
        for _ in range(400):
            t += 0.01
            row = ad._sample(t)
        assert row is not None
        return row[0]

    ad.theta = [0.2, 0.5]
    ad._rebase()
    before = settle()
    for theta in ([0.4, 0.5], [0.4, 1.5]):  # the propeller's lane, then the friction's
        ad.theta = theta
        ad._rebase()
        lifted = ad._sample(t + 1e-3)
        after = settle()
        assert lifted is not None and abs(after - before) > 5.0  # a step large enough to tell
        assert lifted[0] == pytest.approx(after, abs=0.1 * abs(after - before)), theta
        before = after


# --- simulated flights ---------------------------------------------------------------------------------
PRE, POST = (ONSET_S - 20.0, ONSET_S), (ONSET_S + 10.0, ONSET_S + 30.0)


@pytest.fixture(scope="module")
def followed(model, faulted):
    return run_flight(model, faulted, adapt=True), run_flight(model, faulted, adapt=False)


def test_a_propeller_loss_is_followed_within_10_s(followed):
    """After the loss (onset + 10 .. + 30 s) the adapted prediction's RMSE is within 3.5x of its
    RMSE before (onset - 20 s .. onset: 0.8 rad/s here, 2.4 after: the friction's wide prior,
    AdaptationConfig.prior_sigma, lets it take a share of the loss) and a fifth of the offline
    model's, which the loss took to far above its own; the propeller's adapted loss moved by the
    injected one within 30 % ((1 - after) / (1 - before) = 1 - LOSS)."""
    a, o = followed
    assert rmse(a, *POST) <= 3.5 * rmse(a, *PRE), (rmse(a, *PRE), rmse(a, *POST))
    assert rmse(a, *POST) <= 0.2 * rmse(o, *POST), (rmse(a, *POST), rmse(o, *POST))
    assert rmse(o, *POST) >= 3.0 * rmse(o, *PRE), (rmse(o, *PRE), rmse(o, *POST))
    before = a["theta"][np.searchsorted(a["t"], ONSET_S) - 1, 0]
    after = a["theta"][-1, 0]
    assert 1.0 - (1.0 - after) / (1.0 - before) == pytest.approx(LOSS, rel=0.3), (before, after)


@pytest.fixture(scope="module")
def heated():
    """60 s of random steps on the bench, the winding 30 K hotter from ONSET_S: the propeller's CT
    is unchanged, the rotor slower."""
    return simulate("random_steps", 60.0, 2203, params=draw_bench(BENCH), soc=0.8,
                    faults=[Fault("motor_heating", 30.0, ONSET_S)])


def test_the_thrust_follows_a_propeller_loss_and_not_a_hot_winding(model, followed, heated):
    """b scales with the propeller's adapted loss (CT drops with CP), and only with a loss: a hot
    winding moves the loss negative (more drag stands in for the slower rotor), and scaling b up
    with it would raise the thrust of a propeller that did not change (it doubled the thrust's
    error against the offline model's on randomized benches)."""
    a, o = followed
    assert thrust_rmse(a, *POST) <= 0.3 * thrust_rmse(o, *POST), (thrust_rmse(a, *POST), thrust_rmse(o, *POST))
    h, ho = run_flight(model, heated, adapt=True), run_flight(model, heated, adapt=False)
    assert h["theta"][-1, 0] < -0.02  # the loss went negative: the premise
    assert thrust_rmse(h, *POST) <= 1.1 * thrust_rmse(ho, *POST), (thrust_rmse(h, *POST), thrust_rmse(ho, *POST))
    ad = PhysicsAdapter(model)
    for loss, factor in ((-0.09, 1.0), (0.0, 1.0), (0.12, 0.88)):
        ad.theta = [loss, 0.0]
        assert ad.thrust_factor == pytest.approx(factor)


@pytest.mark.xfail(strict=True, reason="known limitation: the issue's 1.2x of the pre-change RMSE; on this flight "
                   "the adapted RMSE after the loss is ~1.8 rad/s against ~1.0 before (the offline model's ~13)")
def test_the_issue_goal_within_1_2x_of_the_pre_change_rmse(followed):
    a, _ = followed
    assert rmse(a, *POST) <= 1.2 * rmse(a, *PRE)


def test_no_change_adaptation_does_no_harm(model, healthy):
    a, o = (run_flight(model, healthy, adapt=x) for x in (True, False))
    t0, t1 = 5.0, 61.0
    assert rmse(a, t0, t1) <= 1.05 * rmse(o, t0, t1), (rmse(a, t0, t1), rmse(o, t0, t1))


def test_frozen_while_the_speed_stops(model, faulted):
    """No measured speed from 35 s to 40 s (the loss is still being learned): the parameters
    learned from the speed do not move over the gap and the status says frozen; they move again
    after. The pack's resistance, learned from the voltage, goes on."""
    run = run_flight(model, faulted, speed=lambda t, w: None if 35.0 <= t < 40.0 else w, states=True)
    t, theta, states = run["t"], run["theta"][:, :2], run["states"]
    gap = (t >= 35.0 + MEASURED_SPEED_MAX_AGE_S) & (t < 40.0)
    assert np.all(theta[gap] == theta[gap][0])
    assert all(s.startswith("frozen: no measured speed") for s in np.asarray(states)[gap])
    assert np.asarray(states)[t >= 45.0][-1] == "on"
    assert not np.all(theta[t >= 41.0] == theta[gap][0])
    assert not np.all(run["theta"][gap, 2] == run["theta"][gap, 2][0])


def test_the_pack_is_frozen_while_the_voltage_stops(model, faulted, monkeypatch):
    """No battery voltage from 35 s to 40 s: the lanes hold the latest one, and the pack's
    resistance learns nothing from it (a row per voltage sample); it moves again after."""
    import bench_adaptation

    def streams(res):
        pwm, (vt, vv), measured = bench_health_streams(res)
        keep = (vt < 35.0) | (vt >= 40.0)
        return pwm, (vt[keep], vv[keep]), measured

    from bench_health import streams as bench_health_streams

    monkeypatch.setattr(bench_adaptation, "streams", streams)
    run = run_flight(model, faulted)
    t, pack = run["t"], run["theta"][:, 2]
    gap = (t >= 35.1) & (t < 40.0)
    assert np.isfinite(pack[gap][0]) and np.all(pack[gap] == pack[gap][0])
    assert not np.all(pack[t >= 41.0] == pack[gap][0])


def test_bounds_hold_with_absurd_speeds(model, faulted):
    """A tachometer reading 4x the speed, then 0.2x: theta stays within its bounds, the
    prediction finite."""
    for factor in (4.0, 0.2):
        run = run_flight(model, faulted, speed=lambda t, w, f=factor: w * f)
        th = run["theta"]
        assert np.all(np.isfinite(run["predicted"]))
        assert np.all(th[:, 0] >= BOUNDS[0][0]) and np.all(th[:, 0] <= BOUNDS[0][1])
        assert np.all(th[:, 1] >= 1.0 + BOUNDS[1][0]) and np.all(th[:, 1] <= 1.0 + BOUNDS[1][1])
        assert th[-1, 0] in (BOUNDS[0][0], BOUNDS[0][1]) or abs(th[-1, 1] - 1.0) > 0.5  # it did move


def test_a_step_past_a_bound_is_projected_in_the_covariance_s_metric():
    """An update past theta's bounds lands on the box's point nearest in P^-1 (scipy's bounded
    minimiser of the same quadratic as the reference, 200 random covariances and steps), and by
    hand: the friction's factor past its floor (theta[1] -1.5 -> -1), the loss moves by the
    regression P01 / P11 on it (0.02 / 0.25 * 0.5 = +0.04), where clipping each alone left it."""
    from scipy.optimize import minimize

    assert _projected([[0.01, 0.02], [0.02, 0.25]], 0.05, -1.5) == pytest.approx((0.09, -1.0))
    assert _projected([[0.01, 0.0], [0.0, 0.25]], 0.6, 60.0) == (BOUNDS[0][1], BOUNDS[1][1])
    assert _projected([[0.01, 0.02], [0.02, 0.25]], 0.05, 3.0) == (0.05, 3.0)  # inside: as it is
    rng = np.random.default_rng(34)
    lo, hi = np.array([b[0] for b in BOUNDS]), np.array([b[1] for b in BOUNDS])
    for _ in range(200):
        a = rng.normal(size=(2, 2)) * [0.1, 0.5]
        cov = a @ a.T + np.diag([1e-4, 1e-3])
        x = np.array([rng.uniform(-1.0, 1.2), rng.uniform(-3.0, 52.0)])
        inv = np.linalg.inv(cov)
        def dist(z, x=x, inv=inv):
            return float((z - x) @ inv @ (z - x))
        ref = minimize(dist, np.clip(x, lo, hi), bounds=BOUNDS, method="L-BFGS-B",
                       options={"ftol": 1e-15, "gtol": 1e-12})
        got = np.array(_projected([[cov[0, 0], cov[0, 1]], [cov[1, 0], cov[1, 1]]], *x))
        assert np.all(got >= lo) and np.all(got <= hi)
        assert dist(got) <= ref.fun + 1e-9 * (1.0 + ref.fun)


def test_off_by_default_and_reset_returns_to_the_offline_model(model, faulted):
    """Default: no adapter, no adaptation status. An adapter never fed a speed, or reset after
    learning, predicts exactly what the offline model does."""
    plain = ThrustEstimator(model)
    assert plain.adapter is None and "adaptation" not in plain.status()[0].values
    adapted = run_flight(model, faulted, adapt=True, keep=True)
    est = adapted["estimator"]
    assert est.adapter.theta[0] > 0.05  # it learned the loss
    values = est.status()[0].values
    assert {f"adapted_{n}" for n in ADAPTED} <= set(values) and "adapted_propeller_damage_sigma" in values
    in_use = float(values["adapted_pack_resistance_in_use"])  # (statuses are strings)
    assert in_use == pytest.approx(est.adapter.pack_ohm, rel=1e-5)
    assert in_use == pytest.approx(model.params.battery_series_resistance_ohm, rel=1e-5)  # a loss moves no pack
    est.reset()
    assert est.adapter.theta == [0.0, 0.0] and est.adapter.values()["bearing_friction"][0] == 1.0
    fresh = ThrustEstimator(model, adapter=adapter_for(model))
    for e in (est, fresh, plain):
        e.reset()
    # after the flight's last measured speed (a recent one would start the physics: not adaptation's)
    pwm_t, pwm = (faulted.pwm_t[:500] + 100.0).tolist(), faulted.pwm[:500].tolist()
    out = []
    for e in (est, fresh, plain):
        e.update_voltage(100.0, 11.5)
        ws = []
        for t, x in zip(pwm_t, pwm, strict=True):
            e.update_pwm(t, x)
            ws.append(e.predict(t + 0.005))
        out.append(ws)
    for a, b in zip(out[0], out[2], strict=True):
        assert a.speed_rad_s == b.speed_rad_s and a.thrust_n == b.thrust_n
    for a, b in zip(out[1], out[2], strict=True):
        assert a.speed_rad_s == b.speed_rad_s and a.thrust_n == b.thrust_n
    assert math.isfinite(out[2][-1].speed_rad_s) and out[2][-1].speed_rad_s > 0.0


def test_reusing_a_sample_between_steps_changes_nothing(model, monkeypatch):
    """Predictions faster than the lanes' steps (1 kHz here, 5 ms steps) reuse the latest sample
    (``_Twins.still_at``); sampling afresh at every call gives the same predictions and parameters,
    bit for bit, through a loss and the lanes' rebuilds it brings."""
    import bench_adaptation

    from bldc_propulsion.core import adaptation

    res = simulate("random_steps", 12.0, 2203, params=draw_bench(BENCH), soc=0.8,
                   faults=[Fault("propeller_damage", 0.2, 3.0)])
    monkeypatch.setattr(bench_adaptation, "GRID_HZ", 1000.0)
    fast = run_flight(model, res, adapt=True, keep=True)
    assert fast["estimator"].adapter.relinearisations >= 2
    monkeypatch.setattr(adaptation._Twins, "still_at", lambda self, t: False)
    fresh = run_flight(model, res, adapt=True)
    assert len(fast["t"]) > 10000
    assert np.array_equal(fast["predicted"], fresh["predicted"])
    assert np.array_equal(fast["theta"], fresh["theta"], equal_nan=True)


# --- the guard: the adapted parameters are used only while they score no worse ----------------------
def test_the_guard_scores_both_predictions_a_priori_by_hand(model):
    """Squared errors on the measured speeds, forgotten over memory_s; the correction applies while
    the adapted one's sum is no larger. Hand-computed: errors from the offline model 1, 0, 2 rad/s
    at 0, memory_s and 2 memory_s, from the adapted one -2, -1, 1.5 (corrections 3, 1, 0.5)."""
    ad = PhysicsAdapter(model)
    m, k = ad.config.memory_s, math.exp(-1.0)
    ad._judge(10.0, 1.0, -2.0)
    assert (ad._score.offline, ad._score.adapted, ad.in_use) == (1.0, 4.0, False)
    assert ad.correction(10.0) == (0.0, 0.0) and ad.applied_thrust_factor == 1.0
    ad._judge(10.0 + m, 0.0, -1.0)
    assert ad._score.offline == pytest.approx(k) and ad._score.adapted == pytest.approx(4.0 * k + 1.0)
    ad._judge(10.0 + 2.0 * m, 2.0, 1.5)
    assert ad._score.offline == pytest.approx(k * k + 4.0)
    assert ad._score.adapted == pytest.approx((4.0 * k + 1.0) * k + 2.25)
    assert ad.in_use  # 3.16 against 4.14: the adapted one scores better now


def test_where_theta_does_not_learn_the_guard_scores_apart(model, hot_flight):
    """By hand: a speed where theta does not learn (a coast, the dead band) goes to its own tallies,
    and the correction at a prediction follows the guard of its regime, told by the offline speed
    there (none given: the driven one's)."""
    ad = PhysicsAdapter(model)
    ad._judge(10.0, 1.0, 0.5)  # driven: the adapted better
    ad._judge(10.1, 1.0, 3.0, low=True)  # a coast: the adapted worse
    assert (ad._score.offline, ad._score.adapted, ad.in_use) == (1.0, 0.25, True)
    assert (ad._score_low.offline, ad._score_low.adapted, ad.in_use_low) == (1.0, 9.0, False)
    ad = run_flight(model, hot_flight[1], adapt=True, keep=True)["estimator"].adapter
    t = ad._hist_t[-1]
    row = ad._sample(t)
    fast, slow = ad.speed_scale_rad_s, 0.5 * ad.config.min_speed_fraction * ad.speed_scale_rad_s
    assert row is not None and ad._driven(row, fast) and not ad._driven(row, slow)
    ad.in_use, ad.in_use_low = True, False
    moved = ad.correction(t)
    assert moved[0] != 0.0 and ad.correction(t, fast) == moved and ad.correction(t, slow) == (0.0, 0.0)
    ad.in_use, ad.in_use_low = False, True
    assert ad.correction(t) == (0.0, 0.0) == ad.correction(t, fast) and ad.correction(t, slow) == moved


def test_the_guard_keeps_a_wrong_adaptation_out_of_the_prediction(model, monkeypatch):
    """Healthy flights on which the adapter, unguarded, learns a change that is not there (the
    model's own error at some operating points looks like one): its prediction is then more than
    5 % worse than the offline model's against the simulator's truth on most of them; guarded it
    is within the issue's 5 % on every one, no worse than offline in the median, and its worst
    flight is better than the unguarded worst. The guard judges on the decoded speeds over its
    memory, so a flight may end slightly above the offline model (not a per-flight guarantee)."""
    from bldc_propulsion.core import adaptation

    flights = [simulate("random_steps", 30.0, seed, params=draw_bench(BENCH), soc=0.8) for seed in range(2210, 2220)]
    t0, t1 = 10.0, 30.0
    offline = [rmse(run_flight(model, res, adapt=False), t0, t1) for res in flights]
    guarded = [rmse(run_flight(model, res, adapt=True), t0, t1) for res in flights]
    monkeypatch.setattr(adaptation.PhysicsAdapter, "_judge", lambda self, *args: None)
    unguarded = [rmse(run_flight(model, res, adapt=True), t0, t1) for res in flights]
    g, u = np.divide(guarded, offline), np.divide(unguarded, offline)
    assert np.sum(u > 1.05) >= 5, u  # the case the guard is for
    assert g.max() <= 1.05 and np.median(g) <= 1.0 and g.max() < u.max(), (g, u)


# --- the pack's series resistance, from the voltage ------------------------------------------------
def _sag_rows(r_of_t, seconds: float, seed: int, held: bool = False):
    """Rows every 50 ms of v = e(t) - R(t) i - 0.015 lag_30s(i) + noise: i the supply current
    through a 2 s filter (as the model's), stepping between 2 and 30 A every 1-4 s (or held at 15 A),
    e falling 2 mV/s (the pack discharging); the voltage's noise 5 mV."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, seconds, 0.05)
    level = np.empty_like(t)
    k, nxt, cur = 0, 0.0, 15.0
    for k, x in enumerate(t):
        if not held and x >= nxt:
            cur, nxt = float(rng.uniform(2.0, 30.0)), x + float(rng.uniform(1.0, 4.0))
        level[k] = cur
    i = np.empty_like(t)
    lag = np.empty_like(t)
    i[0] = lag[0] = level[0]
    for k in range(1, len(t)):
        i[k] = i[k - 1] + (1.0 - math.exp(-0.05 / 2.0)) * (level[k] - i[k - 1])
        lag[k] = lag[k - 1] + (1.0 - math.exp(-0.05 / 30.0)) * (i[k] - lag[k - 1])
    v = 16.0 - 0.002 * t - np.array([r_of_t(x) for x in t]) * i - 0.015 * lag + rng.normal(0.0, 0.005, len(t))
    return t, v, i


def test_the_sag_estimator_finds_the_pack_resistance_and_follows_it_doubling():
    """Against the known truth of a hand-built pack: R 0.025 ohm, doubled at 60 s; the estimator
    starts at 0.035 (a model's default) with a sigma of as much. Within 5 % of R before the change,
    and within 10 % of 2 R from 20 s after it on (its memory 5 s; the offset takes the step's
    first share); the current held still, R's sigma stays near its prior (nothing to tell R by),
    so the adapter would publish no resistance."""
    from bldc_propulsion.core.adaptation import _Sag

    sag = _Sag(0.035, 0.035, 0.05, 5.0, 4.0)
    t, v, i = _sag_rows(lambda x: 0.025 if x < 60.0 else 0.05, 120.0, 5)
    at = {}
    for x, vv, ii in zip(t.tolist(), v.tolist(), i.tolist(), strict=True):
        sag.add(x, vv, ii)
        at[round(x, 2)] = sag.x[1]
    assert at[59.95] == pytest.approx(0.025, rel=0.05)
    after = [at[x] for x in at if x >= 80.0]
    assert 0.045 <= min(after) and max(after) <= 0.055, (min(after), max(after))
    held = _Sag(0.035, 0.035, 0.05, 5.0, 4.0)
    for x, vv, ii in zip(*_sag_rows(lambda x: 0.025, 60.0, 6, held=True), strict=True):
        held.add(x, vv, ii)
    assert held.sigma_r > 0.5 * 0.035


@pytest.fixture(scope="module")
def pack_flights():
    """60 s of random steps on the bench, the pack's series resistance doubled at ONSET_S, and its twin."""
    bench = draw_bench(BENCH)
    return (simulate("random_steps", 60.0, 2231, params=bench, soc=0.8,
                     faults=[Fault("pack_resistance", 2.0, ONSET_S)]),
            simulate("random_steps", 60.0, 2231, params=bench, soc=0.8))


def test_a_pack_whose_resistance_doubles_is_seen_in_the_voltage(model, pack_flights):
    """The adapter's measured resistance against the simulator's: its baseline within 30 % of the
    bench's series resistance (the model holds 0.035 ohm, not the bench's), the doubling seen at
    the end (x1.6-2.5 of the baseline; the twin stays within 25 % of it); the model's resistance
    moves by the change, and the prediction after it is no worse than the offline model's."""
    faulted, twin = pack_flights
    truth = draw_bench(BENCH).battery_series_resistance_ohm
    runs = [run_flight(model, res, adapt=True, keep=True) for res in pack_flights]
    ad, ad_twin = (r["estimator"].adapter for r in runs)
    assert ad.pack_baseline_ohm == pytest.approx(truth, rel=0.3), (ad.pack_baseline_ohm, truth)
    assert 1.6 <= ad.pack_measured_ohm / ad.pack_baseline_ohm <= 2.5
    assert 0.75 <= ad_twin.pack_measured_ohm / ad_twin.pack_baseline_ohm <= 1.25
    assert ad.pack_ohm - model.params.battery_series_resistance_ohm == pytest.approx(
        ad.pack_measured_ohm - ad.pack_baseline_ohm)
    assert ad.adapted_plant().params.battery_series_resistance_ohm == ad.pack_ohm
    value, sigma = ad.values()["pack_resistance"]
    assert value == ad.pack_measured_ohm and 0.0 < sigma < 0.2 * value
    offline = run_flight(model, faulted, adapt=False)
    assert rmse(runs[0], *POST) <= 1.05 * rmse(offline, *POST), (rmse(runs[0], *POST), rmse(offline, *POST))


def test_a_change_of_the_pack_counts_past_a_third_and_until_it_falls_under_a_sixth(model):
    """By hand, baseline 0.04 ohm (pack_significant 0.35): the measured resistance's change moves the
    model's only once it exceeds 35 % of the baseline, and keeps moving it until it falls back
    under 17.5 % (a healthy flight's estimate swings +-20 %); the model's resistance is its own
    plus the change while it counts."""
    ad = PhysicsAdapter(model)
    rs = model.params.battery_series_resistance_ohm
    ad.pack_baseline_ohm = 0.04
    for measured, counts in ((0.048, False), (0.0535, False), (0.055, True), (0.047, True), (0.0475, True),
                             (0.0469, False), (0.05, False), (0.025, True), (0.0329, True), (0.0335, False)):
        ad._sag.x[1] = measured
        ad._count_pack_change()
        assert ad.pack_changed is counts, measured
        assert ad.pack_ohm == pytest.approx(rs + measured - 0.04 if counts else rs), measured


def test_a_named_pack_moves_the_model_by_its_factor_of_the_resistance_measured_before(model):
    """By hand: the measured resistance 0.04 ohm until 50 s, then climbing 2 mohm/s (the voltage's
    estimate following a change); the monitor names a pack 1.9x with its onset at 52 s: the
    model's series resistance moves by 0.9 x 0.04 (the value 5 s before the onset) and stays there
    whatever the estimate does; the size refined (2.1x) moves only it; a second named change (1.5x
    at 80 s) adds half of the resistance measured before its own onset; the names are in the saved
    model's metadata. Given the sag per ampere the monitor sized a factor against
    (``HealthEvent.reference``), the factor's share of that is added instead."""
    ad = PhysicsAdapter(model)
    rs = model.params.battery_series_resistance_ohm
    sag = ad._sag
    sag.add = lambda t, v, i: None  # the estimate as the rows set it

    def row(t: float, r: float) -> None:
        sag.x[1] = r
        ad._lanes.supply = lambda: (t, 15.0, 5.0)  # type: ignore[method-assign]
        ad._pack_row()

    for k in range(560):  # 0.1 s rows, kept as the adapter keeps them
        row(0.1 * k, 0.04 if k < 500 else 0.04 + 0.0002 * (k - 500))
    assert ad.pack_ohm == rs
    assert ad.take_named("pack_resistance", 1.9, 52.0)
    assert ad.pack_ohm == pytest.approx(rs + 0.9 * 0.04)
    ad.take_named("pack_resistance", 2.1, 52.0)
    assert ad.pack_ohm == pytest.approx(rs + 1.1 * 0.04)
    for k in range(560, 800):
        row(0.1 * k, 0.04 + 0.0002 * (k - 500))
    assert ad.pack_ohm == pytest.approx(rs + 1.1 * 0.04)  # the estimate's climb does not move it
    ad.take_named("pack_resistance", 1.5, 80.0)
    assert ad.pack_named_ohm == pytest.approx(1.1 * 0.04 + 0.5 * (0.04 + 0.0002 * 250), abs=2e-4)
    assert [c["size"] for c in ad.named_changes()] == [2.1, 1.5]
    assert ad.adapted_plant().params.battery_series_resistance_ohm == pytest.approx(ad.pack_ohm)
    assert not ad.take_named("pack_resistance", math.nan, 90.0)
    # with the sag the monitor sized the factor against, the ohms it found are added
    before = ad.pack_named_ohm
    assert ad.take_named("pack_resistance", 1.5, 95.0, reference=0.03)
    assert ad.pack_named_ohm == pytest.approx(before + 0.5 * 0.03)
    ad.take_named("pack_resistance", 1.6, 95.0, reference=0.035)  # refined, against its own window
    assert ad.pack_named_ohm == pytest.approx(before + 0.6 * 0.035)


# --- a change the health monitor names, taken into the model -------------------------------------------
@pytest.fixture(scope="module")
def hot_flight():
    """100 s of a multirotor's motor on the bench, the winding 30 K hotter from 50 s (the health
    monitor needs its healthy reference first), and the same flight without it."""
    kw = {"params": draw_bench(BENCH), "soc": 0.8}
    return (simulate("flight", 100.0, 2204, faults=[Fault("motor_heating", 30.0, 50.0)], **kw),
            simulate("flight", 100.0, 2204, **kw))


def test_a_heating_the_monitor_names_is_taken_and_the_speed_comes_back(model, hot_flight):
    """Alone, the adapter has no parameter for a hot winding and stands the propeller's and the
    friction's in for it (the loss goes negative): 10-50 s after the rise its RMSE stays 1.2x and
    more of the same flight without the rise (1.24 against 0.74 rad/s). With the health monitor
    watching, the monitor names the heating with its size and the adapter takes it: the winding's
    rise in the model within 30 % of the truth, the propeller's loss back near its value before,
    the RMSE within 1.2x of the healthy flight's, and the winding's resistance in the adapted model."""
    faulted, twin = hot_flight
    post = (60.0, 100.0)
    alone = run_flight(model, faulted, adapt=True)
    watched = run_flight(model, faulted, adapt=True, health=True, keep=True)
    healthy = run_flight(model, twin, adapt=True, health=True)
    assert rmse(alone, *post) > 1.2 * rmse(healthy, *post), (rmse(alone, *post), rmse(healthy, *post))
    assert alone["theta"][-1, 0] < -0.03  # the premise: the propeller stands in for the heating
    assert [e["name"] for e in watched["events"]] == ["motor_heating"] and healthy["events"] == []
    ad = watched["estimator"].adapter
    assert ad.heating_k == pytest.approx(30.0, rel=0.3) and ad.taken[0][0] == "motor_heating"
    assert abs(ad.theta[0]) < 0.03, ad.theta
    assert rmse(watched, *post) <= 1.2 * rmse(healthy, *post), (rmse(watched, *post), rmse(healthy, *post))
    from bldc_propulsion.core.health import heated

    assert ad.adapted_plant().params.winding_resistance_ohm == pytest.approx(
        heated(model.params, ad.heating_k).winding_resistance_ohm)
    assert ad.adapted_plant().metadata["named_changes_taken"][0]["name"] == "motor_heating"


def test_a_named_heating_takes_theta_back_to_before_its_onset(model, hot_flight):
    """By hand on an adapter that has flown: a named heating takes theta back to its value 5 s
    before the onset (``_BEFORE_ONSET_S``) and sets the winding's rise; the same change's refined
    size moves the rise (the lanes rebuilt only past 2 K), another heating adds to the rise before
    it; a size that is not a number and a name the adapter has no use for are not taken, and the
    bound holds."""
    ad = run_flight(model, hot_flight[1], adapt=True, keep=True)["estimator"].adapter
    before, now = ad.theta_at(75.0), list(ad.theta)
    assert before != ad.theta_at(95.0)  # theta moved over the flight: the history matters
    for name, size in (("input_delay", 0.01), ("bearing_friction", math.nan), ("motor_heating", math.nan)):
        assert not ad.take_named(name, size, 80.0)
    assert ad.theta == now and ad.heating_k == 0.0 and ad.taken == []
    assert ad.take_named("motor_heating", 20.0, 80.0) and ad.heating_k == 20.0
    assert ad.theta == before and ad.theta_at(200.0) == before  # the history's latest value too
    rebuilt = ad.relinearisations
    assert ad.take_named("motor_heating", 26.0, 80.0) and ad.heating_k == 26.0  # refined
    assert not ad.take_named("motor_heating", 27.0, 80.0) and ad.heating_k == 27.0  # within 2 K of the lanes'
    assert ad.relinearisations == rebuilt + 1
    assert ad.take_named("motor_heating", 10.0, 90.0) and ad.heating_k == 37.0  # another rise
    assert ad.take_named("motor_heating", 500.0, 95.0) and ad.heating_k == HEATING_BOUNDS_K[1]
    assert [n for n, _, _ in ad.taken] == ["motor_heating"] * 3


def test_a_named_pack_takes_theta_back_to_before_its_onset(model, hot_flight):
    """By hand on an adapter that has flown: a named pack takes theta back to its value 5 s before
    the onset, as a heating does (what theta learnt since, at the steps where the pack sagged more
    than the model undid, was the pack in the propeller's and the friction's place), the
    covariance kept; its refined size moves the resistance only, theta as it has learnt since."""
    ad = run_flight(model, hot_flight[1], adapt=True, keep=True)["estimator"].adapter
    before, cov = ad.theta_at(75.0), [list(r) for r in ad._P]
    assert before != list(ad.theta)  # theta moved over the flight: the history matters
    assert ad.take_named("pack_resistance", 1.8, 80.0, reference=0.04)
    assert ad.theta == before and ad._P == cov and ad.pack_named_ohm == pytest.approx(0.8 * 0.04)
    ad._set_theta([0.01, 0.1])  # learnt on since
    assert ad.take_named("pack_resistance", 1.9, 80.0, reference=0.04)
    assert ad.theta == [0.01, 0.1] and ad.pack_named_ohm == pytest.approx(0.9 * 0.04)


def test_a_renamed_change_holds_only_its_latest_name(model, hot_flight):
    """By hand on an adapter that has flown: a change named one fault and renamed another while
    it is sized (the monitor's ``_refine``) holds only the new name's take: a heating renamed a
    pack leaves no winding rise, a pack renamed a heating no ohms (None: nothing named before),
    and an earlier change's take stays; theta is the new take's (back to before the onset)."""
    ad = run_flight(model, hot_flight[1], adapt=True, keep=True)["estimator"].adapter
    before = ad.theta_at(75.0)
    assert ad.take_named("motor_heating", 20.0, 60.0) and ad.heating_k == 20.0  # an earlier change
    assert ad.take_named("motor_heating", 15.0, 80.0) and ad.heating_k == 35.0
    assert ad.take_named("pack_resistance", 1.8, 80.0, reference=0.04)  # renamed
    assert ad.heating_k == 20.0 and ad.pack_named_ohm == pytest.approx(0.8 * 0.04)
    assert ad.theta == before
    assert [n for n, _, _ in ad.taken] == ["motor_heating", "pack_resistance"]
    assert ad.take_named("motor_heating", 12.0, 80.0)  # and back: the pack's ohms go, the rise comes
    assert ad.pack_named_ohm is None and ad.heating_k == 32.0
    assert [(n, v) for n, v, _ in ad.taken] == [("motor_heating", 20.0), ("motor_heating", 12.0)]


@pytest.fixture(scope="module")
def rubbed():
    """A flight whose bearing's friction triples at 50 s, cut 3 s later: theta has begun to learn it."""
    return simulate("flight", 53.0, 2205, params=draw_bench(BENCH), soc=0.8,
                    faults=[Fault("bearing_friction", 3.0, 50.0)])


def test_a_named_propeller_or_friction_restarts_theta_from_before_its_onset_with_its_size(model, rubbed):
    """By hand on an adapter that has flown into a tripled friction: the named friction (a factor)
    takes theta back to its value 5 s before the onset with the factor - 1 added to the friction's
    parameter, and the covariance back to the prior; its refined size moves that parameter by the
    refinement only (what theta learnt since stays); a named propeller loss (a fraction) does the
    same on the loss (``test_a_named_change_theta_explains_far_better_is_refused``)."""
    ad = run_flight(model, rubbed, adapt=True, keep=True)["estimator"].adapter
    prior = [[s * s, 0.0] for s in ad.config.prior_sigma]
    prior[1] = [0.0, prior[1][0]]
    before = ad.theta_at(45.0)
    assert ad._P != prior and ad.theta != before  # learnt over the flight: both must move back
    named = [before[0], before[1] + 2.0]
    assert ad.recent_sq(named) < ad.recent_sq(ad.theta)  # the premise: theta has not learnt it all yet
    rebuilt = ad.relinearisations
    assert ad.take_named("bearing_friction", 3.0, 50.0)
    assert ad.theta == pytest.approx(named) and ad._P == prior
    assert ad.relinearisations == rebuilt + 1 and ad.values()["bearing_friction"][0] == pytest.approx(before[1] + 3.0)
    ad.theta[1] += 0.3  # learnt since the name
    assert ad.take_named("bearing_friction", 2.5, 50.0)  # refined: 0.5 less
    assert ad.theta == pytest.approx([before[0], before[1] + 1.8])
    assert ad.taken == [("bearing_friction", 2.5, 50.0)]


def test_a_named_change_theta_explains_far_better_is_refused(model, hot_flight):
    """On a healthy flight a named tripled friction (or a loss past the bound, projected on it)
    would make the last 3 s's errors many times theta's (a name dated after theta learnt the
    change, or a wrong one): refused, nothing moves. A loss too small to contradict them is
    taken: theta as it was 5 s before its onset, the loss added."""
    ad = run_flight(model, hot_flight[1], adapt=True, keep=True)["estimator"].adapter
    now, before = list(ad.theta), ad.theta_at(75.0)
    assert ad.recent_sq([before[0], before[1] + 2.0]) > 4.0 * ad.recent_sq(now)
    assert not ad.take_named("bearing_friction", 3.0, 80.0)
    assert not ad.take_named("propeller_damage", 0.9, 85.0)
    assert ad.theta == now and ad.taken == []
    at85 = ad.theta_at(85.0)
    small = [at85[0] + 0.002, at85[1]]
    assert ad.recent_sq(small) <= 4.0 * ad.recent_sq(now)  # the premise
    assert ad.take_named("propeller_damage", 0.002, 90.0)
    assert ad.theta == pytest.approx(small) and ad.taken == [("propeller_damage", 0.002, 90.0)]


def test_a_provisional_take_is_undone_when_named_otherwise_or_not_at_all(model, hot_flight):
    """By hand on an adapter that has flown: the leading candidate of a change still being named
    is taken as a name would be if it is a hot winding (the rise set, theta back to 5 s before the
    onset; what the adapter learns itself is not taken), and refined likewise; named otherwise, the
    adapter goes back to exactly what it was before the lead (theta, covariance, rise, the changes
    taken) and the name is judged on its own (a tripled friction on a healthy flight: refused);
    dropped (the change left unnamed, or set aside, or led by another candidate), the same; named
    as led, taken afresh as a name."""
    ad = run_flight(model, hot_flight[1], adapt=True, keep=True)["estimator"].adapter
    now, cov, before = list(ad.theta), [list(r) for r in ad._P], ad.theta_at(75.0)
    assert now != before  # the premise: the lead moves theta
    assert not ad.drop_provisional()
    assert ad.take_named("motor_heating", 20.0, 80.0, provisional=True)
    assert ad.heating_k == 20.0 and ad.theta == before and ad.taken == [("motor_heating", 20.0, 80.0)]
    assert ad.provisional
    assert ad.take_named("motor_heating", 24.0, 80.0, provisional=True) and ad.heating_k == 24.0
    assert not ad.take_named("bearing_friction", 3.0, 80.0)  # named otherwise: undone, then refused
    assert ad.theta == now and ad._P == cov and ad.heating_k == 0.0 and ad.taken == []
    assert ad.take_named("motor_heating", 20.0, 80.0, provisional=True) and ad.drop_provisional()
    assert ad.theta == now and ad._P == cov and ad.heating_k == 0.0 and ad.taken == []
    assert ad.take_named("motor_heating", 20.0, 80.0, provisional=True)
    assert ad.take_named("motor_heating", 27.0, 80.0)  # named as led: taken afresh
    assert ad.theta == before and ad.heating_k == 27.0 and ad.taken == [("motor_heating", 27.0, 80.0)]
    assert not ad.provisional and not ad.drop_provisional()
    kept = list(ad.theta)  # a lead the adapter learns itself (a propeller, a friction, a pack) is not taken
    for name, size in (("propeller_damage", 0.002), ("bearing_friction", 1.1), ("pack_resistance", 1.5)):
        assert not ad.take_named(name, size, 90.0, provisional=True)
    assert ad.theta == kept and ad.taken == [("motor_heating", 27.0, 80.0)]
    assert ad.take_named("motor_heating", 5.0, 90.0, provisional=True) and ad.heating_k == 32.0
    assert not ad.take_named("bearing_friction", 1.1, 90.0, provisional=True)  # the lead moved on: undone
    assert ad.heating_k == 27.0 and ad.taken == [("motor_heating", 27.0, 80.0)] and not ad.drop_provisional()


@pytest.fixture(scope="module")
def slow_name():
    """70 s of a multirotor's motor, the winding 30 K hotter from 50 s: a heating the monitor
    names only 8 s after its onset (a friction explains it about as well until then)."""
    return simulate("flight", 70.0, 2213, params=draw_bench(BENCH), soc=0.8,
                    faults=[Fault("motor_heating", 30.0, 50.0)])


def test_a_heating_that_leads_before_its_name_is_taken_at_once(model, slow_name, monkeypatch):
    """End to end (``HealthStream`` and the adapter): the hot winding leads the change seconds
    before it is named and is taken then; the name takes the same change afresh, and the named
    change is all that is left. Until the name, the speed's RMSE is below what it is with no lead
    taken (``HealthMonitor.leading`` None)."""
    from bldc_propulsion.core.health import HealthMonitor

    calls = []
    take = PhysicsAdapter.take_named

    def spy(self, name, size, onset_s, provisional=False, reference=None):
        moved = take(self, name, size, onset_s, provisional, reference)
        calls.append((self._last_update_t, name, provisional, moved, self.heating_k))
        return moved

    monkeypatch.setattr(PhysicsAdapter, "take_named", spy)
    run = run_flight(model, slow_name, adapt=True, health=True, keep=True)
    (event,) = run["events"]
    led = [c for c in calls if c[2] and c[3]]
    assert event["name"] == "motor_heating" and event["named_s"] > 55.0  # the premise: a late name
    assert led and led[0][1] == "motor_heating" and led[0][0] < 55.0 and led[0][4] > 10.0, led[:1]
    assert [c[1] for c in calls if not c[2]][0] == "motor_heating"
    ad = run["estimator"].adapter
    assert ad.taken == [("motor_heating", event["size"], event["onset_s"])] and ad.heating_k == event["size"]
    status = run["estimator"]._adaptation_values()  # the node's and replay's key-values
    assert status["adapted_motor_heating"] == event["size"] and status["adapted_motor_heating_provisional"] is False
    monkeypatch.setattr(HealthMonitor, "leading", property(lambda self: None))
    unled = run_flight(model, slow_name, adapt=True, health=True)
    window = (led[0][0], event["named_s"])
    assert rmse(run, *window) < 0.5 * rmse(unled, *window), (rmse(run, *window), rmse(unled, *window))


class _Monitor:
    """What ``HealthStream._pass_on`` reads of the monitor, set by hand."""

    def __init__(self) -> None:
        self.pending = None
        self.leading = None

    def finish(self):
        """The end of the data: the change being named reported as it stands."""
        ev, self.pending, self.leading = self.pending, None, None
        return [ev]


class _Adapter:
    """Records what ``HealthStream._pass_on`` passes on."""

    def __init__(self) -> None:
        self.calls: list[tuple] = []
        self.references: list[float | None] = []

    def take_named(self, name, size, onset_s, provisional=False, reference=None):
        self.calls.append((name, size, onset_s, provisional))
        self.references.append(reference)
        return True

    def drop_provisional(self):
        self.calls.append(("drop",))
        return True


def test_the_stream_passes_a_lead_that_held_once_per_size_and_drops_it_when_it_goes(model):
    """``HealthStream._pass_on`` by hand: while a change is being named, its leading candidate goes
    to the adapter provisionally once it has led for ``_LEAD_HOLD_S``, again only when its size
    moves; another candidate leading drops it (and must hold in turn); named, the name goes as
    before (the adapter settles the lead itself); gone unnamed (reported so, set aside, or the
    data ending), the lead is dropped."""
    from bldc_propulsion.core.estimator import ThrustEstimator
    from bldc_propulsion.core.health import _LEAD_HOLD_S, UNNAMED, HealthEvent, HealthStream

    stream = HealthStream(ThrustEstimator(model))
    mon, ad = _Monitor(), _Adapter()
    stream.monitor = mon  # type: ignore[assignment]
    ev = HealthEvent(50.0, 50.5, UNNAMED, None, "", 40.0)
    mon.pending, mon.leading = ev, ("motor_heating", 20.0)
    stream._pass_on(ad, [], 50.5)
    stream._pass_on(ad, [], 50.5 + 0.5 * _LEAD_HOLD_S)
    assert ad.calls == []  # not held long enough yet
    stream._pass_on(ad, [], 50.5 + _LEAD_HOLD_S)
    stream._pass_on(ad, [], 51.0 + _LEAD_HOLD_S)
    mon.leading = ("motor_heating", 22.0)
    stream._pass_on(ad, [], 51.5 + _LEAD_HOLD_S)
    assert ad.calls == [("motor_heating", 20.0, 50.0, True), ("motor_heating", 22.0, 50.0, True)]
    mon.leading = None  # its statistic dipped: the lead stays
    stream._pass_on(ad, [], 52.0 + _LEAD_HOLD_S)
    assert len(ad.calls) == 2
    mon.leading = ("bearing_friction", 2.0)  # another leads: dropped, and it must hold in turn
    stream._pass_on(ad, [], 52.5 + _LEAD_HOLD_S)
    assert ad.calls[2:] == [("drop",)]
    stream._pass_on(ad, [], 52.5 + 2.0 * _LEAD_HOLD_S)
    assert ad.calls[3:] == [("bearing_friction", 2.0, 50.0, True)]
    mon.pending = None  # reported unnamed
    stream._pass_on(ad, [ev], 60.0)
    assert ad.calls[4:] == [("drop",)]
    ad.calls.clear()
    ev2 = HealthEvent(70.0, 70.4, UNNAMED, None, "", 40.0)
    mon.pending, mon.leading = ev2, ("motor_heating", 30.0)
    stream._pass_on(ad, [], 70.4)
    stream._pass_on(ad, [], 70.4 + _LEAD_HOLD_S)
    named = HealthEvent(70.0, 70.4, "motor_heating", 31.0, "K", 90.0)
    mon.pending, mon.leading = named, None
    stream._pass_on(ad, [], 75.0)
    mon.pending = None
    stream._pass_on(ad, [named], 80.0)
    assert ad.calls == [("motor_heating", 30.0, 70.0, True), ("motor_heating", 31.0, 70.0, False), ("drop",)]
    ad.calls.clear()  # a pack's factor goes with what it is relative to
    mon.pending = None
    stream._pass_on(ad, [HealthEvent(80.0, 80.4, "pack_resistance", 1.9, "factor", 90.0, reference=0.05)], 85.0)
    assert ad.calls == [("pack_resistance", 1.9, 80.0, False)] and ad.references[-1] == 0.05
    ad.calls.clear()  # the data end while a lead is taken: the change is left unnamed, the lead dropped
    stream.estimator.adapter = ad  # type: ignore[assignment]
    mon.pending, mon.leading = HealthEvent(90.0, 90.3, UNNAMED, None, "", 40.0), ("motor_heating", 25.0)
    stream._pass_on(ad, [], 90.3)
    stream._pass_on(ad, [], 90.3 + _LEAD_HOLD_S)
    stream.last_s = 93.0
    assert [e.name for e in stream.finish()] == [UNNAMED]
    assert ad.calls == [("motor_heating", 25.0, 90.0, True), ("drop",)]


def test_replay_with_both_on_takes_the_named_heating(model, hot_flight, tmp_path):
    """``replay --adapt --health`` (the API the command runs; the node shares ``HealthStream``):
    the summary lists the heating the monitor named as taken, the estimator's status carries the
    rise, and --save-adapted writes the hotter winding."""
    from bldc_propulsion.core.health import heated
    from bldc_propulsion.model import load_model, save_model
    from bldc_propulsion.replay import replay_bag
    from bldc_propulsion.sim.record import write_sim_bag

    save_model(model, tmp_path / "m.npz")
    write_sim_bag(hot_flight[0], tmp_path / "hot")
    out = replay_bag(tmp_path / "hot", tmp_path / "out", model_path=tmp_path / "m.npz", adapt=True, health=True,
                     save_adapted=tmp_path / "adapted.npz")
    taken = out["adaptation"]["named_changes_taken"]
    assert [e["name"] for e in out["health"]["events"]] == ["motor_heating"]
    assert [t["name"] for t in taken] == ["motor_heating"] and taken[0]["size"] == pytest.approx(30.0, rel=0.3)
    assert taken[0]["onset_s"] == out["health"]["events"][0]["onset_s"]
    saved = load_model(tmp_path / "adapted.npz")
    assert saved.params.winding_resistance_ohm == pytest.approx(
        heated(model.params, taken[0]["size"]).winding_resistance_ohm, rel=0.02)
