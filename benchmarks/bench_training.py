"""Benchmark of ``train_lm`` at the paper's size against MINPACK's Levenberg-Marquardt.

Usage::

    PYTHONPATH=. python benchmarks/bench_training.py [--small] [--cap-factor 10] [--seed 0]

Data: 62,050 training + 62,050 validation patterns (the paper's split) from two different
synthetic recordings of staircase and ramp PWM profiles with a sagging battery. The target is a
smooth function with the problem's shape: rotor speed ~ V * sqrt(effective throttle), where
the effective throttle mixes pwm and pwm_filtered (tau = 0.25 s, the rotor lag) and saturates
at both ends (ESC deadband and full throttle), plus 1 % noise. Inputs and target are scaled to
[-1, 1] with the training set's min/max, as the paper does.

Then ``scipy.optimize.least_squares(method="lm")`` (MINPACK lmder, analytic Jacobian) starts
from the SAME Nguyen-Widrow weights. Its residual function is wrapped to record, for every
evaluated point, the training cost, the validation cost and the time (the recording's own time
is subtracted). MINPACK's current iterate is the lowest-training-cost point evaluated so far;
the reported time is the first moment that iterate's validation cost is <= ours. MINPACK is
stopped at ``cap-factor`` x our training time. Prints only; asserts nothing.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time

import numpy as np
import scipy
from scipy.optimize import least_squares

from bldc_propulsion.training.lm import train_lm
from bldc_propulsion.training.network import (
    forward,
    jacobian,
    minmax_apply,
    minmax_fit,
    n_params,
    nguyen_widrow,
)

FRAME_HZ = 50.0


def cpu_pressure() -> str:
    """Linux PSI 'some avg10' (% of time runnable tasks waited for a CPU): other load skews timings."""
    try:
        with open("/proc/pressure/cpu") as fh:
            return fh.readline().split()[1].split("=")[1] + " %"
    except (OSError, IndexError):
        return "n/a"
TAU_S = 0.25


def synthetic_recording(n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(battery_voltage, pwm, pwm_filtered) (n, 3) and speed (n,) in physical units at 50 Hz."""
    pwm = np.empty(n)
    i = 0
    while i < n:  # alternate staircase holds and ramps, as the paper's experiments
        length = int(rng.integers(50, 400))
        a, b = rng.uniform(0.05, 0.10, 2)
        seg = np.full(length, a) if rng.random() < 0.6 else np.linspace(a, b, length)
        pwm[i : i + length] = seg[: n - i]
        i += length
    dt = 1.0 / FRAME_HZ
    alpha = dt / (TAU_S + dt)
    pwm_f = np.empty(n)
    acc = pwm[0]
    for k in range(n):  # first-order filter, tau = 0.25 s (setup only, not timed)
        acc += alpha * (pwm[k] - acc)
        pwm_f[k] = acc
    throttle = (pwm - 0.05) / 0.05
    throttle_f = (pwm_f - 0.05) / 0.05
    soc = np.linspace(1.0, 0.2, n)
    voltage = 10.6 + 2.0 * soc - 1.2 * throttle_f**1.5 + 0.02 * rng.standard_normal(n)
    effective = 0.25 * throttle + 0.75 * throttle_f
    sat = np.clip((effective - 0.06) / 0.9, 0.0, 1.0)  # ESC deadband and full-throttle limit
    speed = 95.0 * voltage * np.sqrt(sat) * (1.0 - 0.08 * sat)
    speed += 0.01 * speed.std() * rng.standard_normal(n)
    return np.column_stack([voltage, pwm, pwm_f]), speed


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--small", action="store_true", help="quick smoke run (2,000 patterns)")
    ap.add_argument("--cap-factor", type=float, default=10.0, help="MINPACK time cap / our time")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)

    P = 2000 if args.small else 62050
    H = 25
    rng = np.random.default_rng(1234)
    Xtr_raw, dtr_raw = synthetic_recording(P, rng)
    Xva_raw, dva_raw = synthetic_recording(P, rng)
    xlo, xhi = minmax_fit(Xtr_raw)
    ylo, yhi = minmax_fit(dtr_raw)
    X, d = minmax_apply(Xtr_raw, xlo, xhi), minmax_apply(dtr_raw, ylo, yhi)
    Xv, dv = minmax_apply(Xva_raw, xlo, xhi), minmax_apply(dva_raw, ylo, yhi)
    N = n_params(3, H)
    phi0 = nguyen_widrow(3, H, np.random.default_rng(args.seed))

    print(f"python {platform.python_version()}, numpy {np.__version__}, scipy {scipy.__version__}, "
          f"{os.cpu_count()} CPUs, OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}")
    print(f"patterns: {P} training + {P} validation, network 3-{H}-1, N = {N} parameters, "
          f"J = {P} x {N} ({P * N * 8 / 1e6:.0f} MB)")

    # --- ours -------------------------------------------------------------------------------
    res = train_lm(X, d, Xv, dv, H, phi0=phi0)
    ours_t = res.seconds
    ours_v = res.val_cost
    print("\n[train_lm]")
    print(f"  stop reason      : {res.stop_reason}")
    print(f"  epochs           : {res.epochs} (best validation at epoch {res.best_epoch})")
    print(f"  total time       : {ours_t:.2f} s  ({ours_t / max(res.epochs, 1) * 1e3:.1f} ms/epoch)")
    print(f"  train cost (2)   : {res.train_cost:.6g}  (MSE {res.train_mse:.3g})")
    print(f"  val cost (2)     : {ours_v:.6g}  (MSE {res.val_mse:.3g}, "
          f"RMSE {np.sqrt(res.val_mse) * (yhi - ylo) / 2:.3g} rad/s)")
    print(f"  goal < 30 s      : {'met' if ours_t < 30.0 else 'NOT met'}")
    print(f"  CPU pressure     : {cpu_pressure()} (10 s average after the run; > a few % = contended)")

    # --- MINPACK, same start -------------------------------------------------------------------
    cap = args.cap_factor * ours_t
    rec_t: list[float] = []
    rec_train: list[float] = []
    rec_val: list[float] = []
    state = {"overhead": 0.0, "t0": 0.0, "njev": 0}

    class _Cap(Exception):
        pass

    def fun(phi: np.ndarray) -> np.ndarray:
        r = forward(phi, X, H) - d
        t_rec = time.perf_counter()
        now = t_rec - state["t0"] - state["overhead"]
        rec_t.append(now)
        rec_train.append(0.5 * float(r @ r))
        ev = forward(phi, Xv, H) - dv
        rec_val.append(0.5 * float(ev @ ev))
        state["overhead"] += time.perf_counter() - t_rec
        if now > cap:
            raise _Cap
        return r

    def jac(phi: np.ndarray) -> np.ndarray:
        state["njev"] += 1
        return jacobian(phi, X, H)

    print("\n[scipy.optimize.least_squares(method='lm') = MINPACK lmder, analytic Jacobian]")
    state["t0"] = time.perf_counter()
    status = "ran to its own termination"
    try:
        out = least_squares(fun, phi0, jac=jac, method="lm", max_nfev=100000)
        status = f"terminated by itself: {out.message}"
    except _Cap:
        status = f"stopped at the cap ({args.cap_factor:g} x our time = {cap:.1f} s)"
    wall = time.perf_counter() - state["t0"] - state["overhead"]
    t = np.asarray(rec_t)
    tr = np.asarray(rec_train)
    va = np.asarray(rec_val)
    # MINPACK's iterate = lowest training cost evaluated so far; its validation cost:
    best_idx = np.zeros(len(tr), dtype=int)
    for k in range(1, len(tr)):
        best_idx[k] = k if tr[k] < tr[best_idx[k - 1]] else best_idx[k - 1]
    it_val = va[best_idx]
    print(f"  {status}")
    print(f"  CPU pressure     : {cpu_pressure()}")
    print(f"  evaluations      : {len(tr)} residuals, {state['njev']} Jacobians "
          f"({wall / max(state['njev'], 1):.2f} s per Jacobian/iteration)")
    print(f"  at the end       : train cost {tr[best_idx[-1]]:.6g}, val cost {it_val[-1]:.6g} "
          f"after {wall:.1f} s")
    reached = np.flatnonzero(it_val <= ours_v)
    if reached.size:
        t_mp = float(t[reached[0]])
        print(f"  reached our val cost {ours_v:.6g} after {t_mp:.2f} s")
        print(f"\nours {ours_t:.2f} s vs MINPACK {t_mp:.2f} s: ours is {t_mp / ours_t:.1f}x faster "
              f"(goal >= 3x: {'met' if t_mp / ours_t >= 3 else 'NOT met'})")
    else:
        print(f"  NEVER reached our val cost {ours_v:.6g} (best {it_val.min():.6g}) within "
              f"{t[-1]:.1f} s")
        print(f"\nours {ours_t:.2f} s vs MINPACK > {t[-1]:.1f} s: ours is > {t[-1] / ours_t:.1f}x faster")
    sys.stdout.flush()


if __name__ == "__main__":
    main()
