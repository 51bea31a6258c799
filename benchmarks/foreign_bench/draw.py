"""Randomized foreign benches: every constant drawn per seed over the span real multirotor and
thrust-stand hardware covers, chosen so the parts fit each other (a propeller a motor can turn at
full throttle on its pack, a current the pack can give)."""

from __future__ import annotations

import math

import numpy as np

from .model import ForeignBench, cell_ocv, pack_ocv, steady_speed

INCH = 0.0254
#: The package's tachometer decoder rejects speeds above 2000 rad/s (TachometerConfig
#: max_speed_rad_s): full throttle stays below this so a user's default decoder reads the bench.
MAX_FULL_SPEED_RAD_S = 1700.0
MIN_CELLS, MAX_CELLS = 3, 4
MAX_CURRENT_A = 60.0  #: at 90 % charge; a full pack gives ~15 % more


def draw_bench(seed: int) -> ForeignBench:
    """The bench of ``seed``. Design order: pack and propeller, a tip speed at full throttle, the
    share of the no-load speed the motor keeps under that load (sets Kv and, from the torque
    balance, the winding resistance), then the rest scaled from the full-throttle operating point."""
    rng = np.random.default_rng(np.random.SeedSequence([30, 4, int(seed)]))
    u = rng.uniform
    d_in = u(5.0, 15.0)
    diameter = d_in * INCH
    # 3S or 4S: behind the contract's 1:2 divider a 5S/6S pack puts more than the battery
    # filter's default 10 V ADC limit on the pin, and a user with no CONFIG reads no voltage
    cells = int(rng.integers(MIN_CELLS, MAX_CELLS + 1))
    pd = u(0.45, 0.9) if d_in < 8.0 else u(0.35, 0.7)  # small props are pitched steeper
    ct0 = 0.05 + 0.12 * pd
    cp0 = -0.01 + 0.115 * pd
    cq0 = cp0 / (2.0 * math.pi)
    rho = u(1.12, 1.25)
    # m/s at full throttle: large propellers run slower tips (noise, power)
    tip = u(100.0, min(200.0 - 4.0 * (d_in - 5.0), MAX_FULL_SPEED_RAD_S * 0.5 * diameter))
    w_full = min(tip / (0.5 * diameter), MAX_FULL_SPEED_RAD_S)
    keep = u(0.72, 0.86)  # loaded / no-load speed at full throttle
    v_pack = cells * float(cell_ocv(0.9))
    # a propeller's power grows as w^3: slow it to what a 3S/4S drive carries
    p_max = MAX_CURRENT_A * keep * v_pack  # shaft power = Ke w I = keep V I
    p_full = cp0 * rho * (w_full / (2.0 * math.pi)) ** 3 * diameter ** 5
    if p_full > p_max:
        w_full *= (p_max / p_full) ** (1.0 / 3.0)
    ke = keep * v_pack / w_full
    kv = 60.0 / (2.0 * math.pi * ke)
    n = w_full / (2.0 * math.pi)
    q_prop = cq0 * rho * n * n * diameter ** 5
    fric_share = u(0.01, 0.03)  # friction / propeller torque at full throttle
    coulomb = 0.4 * fric_share * q_prop
    viscous = 0.6 * fric_share * q_prop / w_full
    i_full = (q_prop * (1.0 + fric_share)) / ke
    r_w = (v_pack - ke * w_full) / i_full
    # propeller mass ~ D^2.5 (4 g at 5 in, ~60 g at 15 in); J of a tapered blade pair + the bell
    m_prop = u(0.8, 1.2) * 0.004 * (d_in / 5.0) ** 2.5
    j_prop = 0.7 * m_prop * diameter ** 2 / 12.0
    inertia = j_prop * (1.0 + u(0.2, 0.6))
    # pack: capacity for a 4-10 C full-throttle draw; R0 for a 3-8 % sag at that current
    i_bat = i_full  # duty 1 at full throttle
    capacity = i_bat / u(4.0, 10.0)
    r0 = u(0.03, 0.08) * v_pack / i_bat
    # thermal: 40-100 K rise at sustained full throttle, a 60-300 s time constant
    p_cu = i_full ** 2 * r_w
    r_th = u(40.0, 100.0) / p_cu
    base = ForeignBench(
        cells=cells, capacity_ah=capacity, r0_ohm=r0, r1_ohm=r0 * u(0.3, 0.8), tau1_s=u(1.0, 5.0),
        r2_ohm=r0 * u(0.2, 0.6), tau2_s=u(15.0, 60.0),
        throttle_linear=u(0.45, 0.9), start_level=u(0.052, 0.058), dead_time_s=u(0.005, 0.030),
        esc_frame_s=u(0.001, 0.002), ripple_ohm=u(0.5, 2.0) * r0,
        kv_rpm_per_v=kv, r_winding_ohm=r_w, inductance_h=r_w * u(1e-4, 6e-4),
        coulomb_torque_nm=coulomb, viscous_nm_s=viscous,
        thermal_resistance_k_per_w=r_th, thermal_tau_s=u(60.0, 300.0), ambient_c=u(15.0, 30.0),
        diameter_m=diameter, pitch_m=pd * diameter, ct0=ct0, cq0=cq0, ct_slope=u(-0.12, 0.05),
        cq_slope=u(-0.15, 0.05), omega_ref_rad_s=w_full, inertia_kg_m2=inertia, air_density=rho,
        divider=0.5 * u(0.98, 1.02), adc_noise_v=u(0.002, 0.01), adc_lsb_v=20.0 / 4096,
        tach_high_v=u(2.6, 3.3), tach_low_v=u(0.1, 0.5), blade_fraction=u(0.05, 0.12),
        beam_fraction=u(0.005, 0.02), blade_offset_rad=u(-0.03, 0.03), tach_tau_s=u(15e-6, 60e-6),
        tach_gain=u(1.0, 3.0), tach_noise_v=u(0.01, 0.04), flicker_v=u(0.0, 0.03),
        load_cell_noise_n=0.002 * ct0 * rho * n * n * diameter ** 4 * u(0.5, 1.5),
    )
    return base


def full_throttle(b: ForeignBench, soc: float = 1.0) -> dict[str, float]:
    """The bench at full throttle on a stiff supply at ``soc``'s open-circuit voltage, cold:
    speed (rad/s), current (A), tip speed (m/s), electrical power (W)."""
    v = pack_ocv(b, soc)
    w = steady_speed(b, 1.0, v)
    i = (v - b.ke_v_s * w) / b.r_winding_ohm
    return {"speed_rad_s": w, "current_a": i, "tip_speed_m_s": 0.5 * b.diameter_m * w, "power_w": v * i}
