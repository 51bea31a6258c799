"""Throughput of the cores (prints figures, asserts nothing).

Run: PYTHONPATH=. python benchmarks/bench_cores.py
Goals: tachometer >= 5e6 samples/s on one core; one estimator update + predict < 20 us; one
update of the physics model's stream < 20 us.
Times are CPU time of this process (best of several runs), so other load on the machine
disturbs them little.
"""

from __future__ import annotations

import array
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "test"))
from _tachsignal import make_signal  # noqa: E402
from bldc_propulsion.contract import EFFECTS, INPUT_PHYSICS_SPEED  # noqa: E402
from bldc_propulsion.core.battery_filter import BatteryFilter  # noqa: E402
from bldc_propulsion.core.estimator import ThrustEstimator  # noqa: E402
from bldc_propulsion.core.tachometer import TachometerDecoder  # noqa: E402
from bldc_propulsion.model import HybridModel, NetworkModel  # noqa: E402
from bldc_propulsion.physics.fallback import fallback_model  # noqa: E402
from bldc_propulsion.physics.params import BenchParams  # noqa: E402
from bldc_propulsion.physics.plant_model import PlantModel  # noqa: E402
from bldc_propulsion.physics.stream import PlantStream  # noqa: E402
from bldc_propulsion.sim import simulate  # noqa: E402

#: what was printed, for --json: a label -> (value, unit, goal or "")
FIGURES: dict[str, tuple[float, str, str]] = {}


def best(fn, repeat: int = 5) -> float:
    """Least CPU seconds of ``repeat`` runs of fn()."""
    out = float("inf")
    for _ in range(repeat):
        t0 = time.process_time()
        fn()
        out = min(out, time.process_time() - t0)
    return out


def bench_tachometer() -> None:
    for speed in (300.0, 650.0, 1500.0):
        x = make_signal(speed, 5.0, seed=1).x
        for bs in (200, 1000, None):
            s = best(lambda x=x, bs=bs: TachometerDecoder().process(0.0, x, batch_size=bs))
            label = "one array" if bs is None else f"batches of {bs}"
            print(f"tachometer  {speed:6.0f} rad/s, {label:15s}: {len(x) / s / 1e6:6.2f} M samples/s (goal >= 5)")
            FIGURES[f"tachometer at {speed:.0f} rad/s, {label}"] = (len(x) / s / 1e6, "M samples/s", ">= 5")
        # what a live node decodes: rclpy's float32 array.array of 200 samples per message
        live = [array.array("f", x[a:a + 200].astype(np.float32).tobytes())
                for a in range(0, len(x) - 199, 200)]

        def node(live=live):
            d = TachometerDecoder()
            for k, b in enumerate(live):
                d.process_batch((k + 1) * 0.01, b, result=False)
        s = best(node)
        print(f"tachometer  {speed:6.0f} rad/s, a node's batch  : {s / len(live) * 1e6:6.1f} us per "
              "200-sample array (warm caches; live about 3x)")
        FIGURES[f"tachometer at {speed:.0f} rad/s, a node's 200-sample batch"] = (
            s / len(live) * 1e6, "µs", "")


def bench_battery() -> None:
    n = 1_000_000
    t = np.arange(n) / 1000.0
    adc = 5.6 + 0.5 * np.random.default_rng(0).normal(size=n)
    s = best(lambda: BatteryFilter().process(t, adc), repeat=3)
    print(f"battery filter, process(): {n / s / 1e6:6.2f} M samples/s")
    FIGURES["battery filter, process() on an array"] = (n / s / 1e6, "M samples/s", "")
    tl, al = t[:50000].tolist(), adc[:50000].tolist()

    def stream():
        f = BatteryFilter()
        for ti, ai in zip(tl, al, strict=True):
            f.update(ti, ai)

    s = best(stream, repeat=3)
    print(f"battery filter, update():  {len(tl) / s / 1e6:6.2f} M samples/s ({s / len(tl) * 1e6:.2f} us/sample)")
    FIGURES["battery filter, one update()"] = (s / len(tl) * 1e6, "µs", "")


def bench_estimator() -> None:
    rng = np.random.default_rng(0)
    net = NetworkModel(("battery_voltage", "pwm", "pwm_filtered"), [9.5, 0, 0], [12.6, 1, 1], 0.0, 650.0,
                       rng.normal(size=(25, 3)), rng.normal(size=25), rng.normal(size=25) / 25, 0.0)
    plant = PlantModel(BenchParams(sim_step_s=0.005), dict.fromkeys(EFFECTS, 1.0), 12.0)
    residual = NetworkModel((INPUT_PHYSICS_SPEED, "pwm", "pwm_filtered"), [0, 0, 0], [650, 1, 1], -50.0, 50.0,
                            rng.normal(size=(25, 3)), rng.normal(size=25), rng.normal(size=25) / 25, 0.0)
    for label, model in (("3-25-1 network", net), ("physics fallback", fallback_model()),
                         ("physics model, 5 ms steps", plant),
                         ("hybrid: physics + 3-25-1", HybridModel(plant, residual))):
        n = 20000

        def run(model=model, n=n):  # bound now: timed within this iteration
            est = ThrustEstimator(model)
            est.update_voltage(0.0, 11.0)
            for i in range(n):
                t = i * 1e-3
                est.update_pwm(t, 0.07)
                est.predict(t)

        s = best(run, repeat=3)
        print(f"estimator ({label}): update_pwm + predict {s / n * 1e6:6.2f} us (goal < 20)")
        FIGURES[f"estimator, {label}: update_pwm + predict"] = (s / n * 1e6, "µs", "< 20")


def bench_adapting_estimator() -> None:
    """The physics model (5 ms steps) with online adaptation (core/adaptation.py) on, as in
    bench_estimator, then with a measured speed every 5 ms (a tachometer at ~300 rad/s)."""
    from bldc_propulsion.core.adaptation import adapter_for

    plant = PlantModel(BenchParams(sim_step_s=0.005), dict.fromkeys(EFFECTS, 1.0), 12.0)
    n = 20000

    def run(speed: bool) -> None:
        est = ThrustEstimator(plant, adapter=adapter_for(plant))
        est.update_voltage(0.0, 11.0)
        for i in range(n):
            t = i * 1e-3
            est.update_pwm(t, 0.07)
            est.predict(t)
            if speed and i % 5 == 0 and i:
                est.update_speed(t - 0.01, 300.0)

    s = best(lambda: run(False), repeat=3)
    print(f"estimator (physics model, 5 ms steps, with adaptation): update_pwm + predict {s / n * 1e6:6.2f} us "
          f"(goal < 20)")
    FIGURES["estimator, physics model with adaptation: update_pwm + predict"] = (s / n * 1e6, "µs", "< 20")
    s2 = best(lambda: run(True), repeat=3)
    per = (s2 - s) / (n // 5)
    print(f"  ... and per measured speed update (every 5 ms): {per * 1e6:6.2f} us")
    FIGURES["estimator, physics model with adaptation: one measured speed update"] = (per * 1e6, "µs", "")


def bench_plant_stream() -> None:
    """The physics model as a stream (5 ms steps, every effect on) fed as a vehicle feeds it:
    PWM at 50 Hz, battery/voltage at 20 Hz, a prediction at 100 Hz."""
    res = simulate("random_steps", 60.0, 1)
    volt_t, volts = res.truth_t[::50].tolist(), res.truth_voltage[::50].tolist()
    events = sorted([(t, 0, x) for t, x in zip(res.pwm_t.tolist(), res.pwm.tolist(), strict=True)]
                    + [(t, 1, x) for t, x in zip(volt_t, volts, strict=True)]
                    + [(k / 100.0, 2, 0.0) for k in range(6000)])
    params = BenchParams(sim_step_s=0.005)

    def run():
        s = PlantStream(params, {}, 12.0, 2.0)
        upd_pwm, upd_volt, speed = s.update_pwm, s.update_voltage, s.speed_at
        for t, kind, x in events:
            if kind == 0:
                upd_pwm(t, x)
            elif kind == 1:
                upd_volt(t, x)
            else:
                speed(t)

    s = best(run, repeat=3)
    print(f"physics stream (plant, 5 ms steps): {s / len(events) * 1e6:6.2f} us per update "
          f"(pwm 50 Hz, voltage 20 Hz, speed_at 100 Hz; {s / 6000 * 1e6:.1f} us per prediction "
          f"with its share of the inputs) (goal < 20)")
    FIGURES["physics stream (5 ms steps), one update"] = (s / len(events) * 1e6, "µs", "< 20")


def bench_health_monitor() -> None:
    """The health monitor (core/health.py) as the node runs it: a 120 s flight of random steps of
    the nominal bench, its model the nominal physics (5 ms steps), the filtered voltage at 1 kHz
    and a measured speed every 5 ms (the truth: decoding is the tachometer's figure above). Per
    measured speed: the estimator, the fault twins' plant steps and the tests, all in."""
    from bldc_propulsion.core.health import run_health

    res = simulate("random_steps", 120.0, 1)
    plant = PlantModel(BenchParams(sim_step_s=0.005), dict.fromkeys(EFFECTS, 1.0), 12.0)
    volts = BatteryFilter().process(res.battery_t, res.battery_adc)
    ok = np.isfinite(volts)
    step = max(1, int(round(0.005 / float(res.truth_t[1] - res.truth_t[0]))))
    speed = (res.truth_t[::step], res.truth_speed[::step])
    s = best(lambda: run_health(plant, (res.pwm_t, res.pwm), (res.battery_t[ok], volts[ok]), speed), repeat=2)
    per = s / len(speed[0])
    print(f"health monitor with its estimator (physics model, 5 ms steps): {per * 1e6:6.1f} us per measured "
          f"speed ({per * 200 * 100:.1f} % of a core at 200 Hz)")
    FIGURES["health monitor with its estimator: one measured speed (5 ms steps)"] = (per * 1e6, "µs", "")


if __name__ == "__main__":
    import argparse

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from results import check_record_path, write_record

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", metavar="PATH",
                    help="also write the figures to PATH (benchmarks/results.py renders them)")
    args = ap.parse_args()
    check_record_path(args.json)
    t_all = time.perf_counter()
    bench_tachometer()
    bench_battery()
    bench_estimator()
    bench_adapting_estimator()
    bench_plant_stream()
    bench_health_monitor()
    if args.json:
        write_record(args.json, {"figures": [{"what": k, "value": v, "unit": u, "goal": g}
                                             for k, (v, u, g) in FIGURES.items()]},
                     seconds=time.perf_counter() - t_all)
