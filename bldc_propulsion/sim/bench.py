"""The simulated bench: LiPo -> ESC -> AXI 2212/34 -> 12x4.5 propeller, plus what its sensors see.

Model (SI units throughout):

* Battery: open-circuit voltage from a state-of-charge table, a series resistance, one RC
  polarisation branch, coulomb counting. Terminal V = OCV(soc) - Vp - Rs * i_batt.
* ESC, motor, propeller, rotor and the winding's temperature: the plant (``physics/plant.py``), driven by
  the battery's terminal voltage behind its series resistance. The battery supplies the motor
  current only during the ESC's on-time: i_batt = duty * i.
* Sensors: battery ADC through the divider with the ESC's switching modulation (zero-mean,
  proportional to battery current) and ADC noise; IR tachometer at 20 kHz, two blades, first-order
  phototransistor response, noise, 12-bit quantisation.
* Faults (``faults.py``): the bench's constants changed from an onset on, the run split there
  with its states carried across, so the health monitor has a known truth to be judged by.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import overload

import numpy as np
from scipy.signal import lfilter

from ..errors import BadInputError
from ..physics.params import BenchParams, check_params, resolve_effects
from ..physics.plant import check_command, esc_duty, make_step
from .faults import Fault, apply_fault, temperature_jump_k
from .profiles import check_duration, make_profile

#: What strength s of each effect scales (0 = off, 1 = realistic nominal).
EFFECT_DOCS: dict[str, str] = {
    "battery_voltage": "s scales the terminal voltage's deviation from the starting open-circuit "
    "voltage (sag under load, polarisation, discharge); 0 is a stiff supply.",
    "rotor_lag": "s scales the rotor inertia (propeller + bell); 0 makes the speed the "
    "instantaneous steady state of the torque balance.",
    "input_delay": "s scales the dead time between command and ESC response, s * 40 ms (one "
    "50 Hz frame to read the pulse plus about one frame of ESC input filtering).",
    "esc_deadband": "s scales the start threshold above PWM 0.05 (0.05 + s*0.005, so 0.055 at 1); "
    "the duty runs from the threshold to 0.10, so 0 is linear from 0.05.",
    "spin_down_asymmetry": "s in [0, 1] is the fraction of the ESC's active braking removed: "
    "0 brakes regeneratively, 1 (nominal) clamps negative motor current to 0 so the rotor coasts.",
    "motor_heating": "s scales copper's temperature coefficient of winding resistance; 0 keeps "
    "the resistance constant (the temperature is still computed).",
}

# OCV lookup resolution: the table is resampled on this many soc steps for the inner loop.
_OCV_STEPS = 1000
# tachometer samples processed per chunk (bounded memory for long runs)
_TACH_CHUNK = 1 << 18


@dataclass
class SimResult:
    """One simulated recording: what the bench records plus ground truth (plain numpy, SI)."""

    pwm_t: np.ndarray  #: command times (s); 50 Hz frames for the named profiles
    pwm: np.ndarray  #: PWM level (0.05..0.10)
    battery_t: np.ndarray  #: 1 kHz ADC sample times (s)
    battery_adc: np.ndarray  #: volts at the ADC pin: divider output with modulation and noise
    tach_rate_hz: float  #: tachometer sample rate (20 kHz)
    tach_t0: float  #: time of the first tachometer sample (s)
    tach: np.ndarray  #: float32 phototransistor voltage, sample k at tach_t0 + k / tach_rate_hz
    truth_t: np.ndarray  #: 1 kHz simulation times (s)
    truth_speed: np.ndarray  #: rotor angular speed (rad/s)
    truth_thrust: np.ndarray  #: thrust b w^2 (N)
    truth_current: np.ndarray  #: battery current (A, average over the PWM period; < 0 charges)
    truth_voltage: np.ndarray  #: battery terminal voltage, modulation-free (V)
    truth_temperature: np.ndarray  #: winding temperature (deg C)
    truth_soc: np.ndarray  #: state of charge (0..1)
    effects: dict[str, float] = field(default_factory=dict)  #: strengths actually used
    params: BenchParams = field(default_factory=BenchParams)
    profile: str = ""
    seed: int = 0
    #: changes injected mid-run, by onset (``sim.faults``); ``params`` is the bench before them
    faults: tuple[Fault, ...] = ()


def _check_seed(seed: int) -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise BadInputError(f"--seed {seed!r}: must be a whole number >= 0")
    return int(seed)


def _check_soc(soc: float) -> float:
    try:
        x = float(soc)
    except (TypeError, ValueError):
        raise BadInputError(f"--soc {soc!r}: not a number") from None
    if not (math.isfinite(x) and 0.0 < x <= 1.0):
        raise BadInputError(f"--soc {soc!r}: state of charge must be in (0, 1]")
    return x


def _check_faults(faults: Sequence[Fault], duration_s: float) -> tuple[Fault, ...]:
    """``faults`` by onset (stable), each a Fault whose onset lies inside the run."""
    if isinstance(faults, (str, Fault)):
        raise BadInputError(f"faults {faults!r}: expected a sequence of Fault (sim.faults)")
    out = []
    for f in faults:
        if not isinstance(f, Fault):
            raise BadInputError(f"faults: {f!r} is not a Fault (sim.faults.parse_fault makes one)")
        if f.onset_s >= duration_s:
            raise BadInputError(f"--fault {f.spec}: onset {f.onset_s:g} s is not inside the "
                                f"recording (0 to {duration_s:g} s)")
        out.append(f)
    return tuple(sorted(out, key=lambda f: f.onset_s))


@overload
def pack_ocv(p: BenchParams, soc: float) -> float: ...
@overload
def pack_ocv(p: BenchParams, soc: np.ndarray) -> np.ndarray: ...
def pack_ocv(p: BenchParams, soc: np.ndarray | float) -> np.ndarray | float:
    """Pack open-circuit voltage (V) at state of charge ``soc`` (clamped to 0..1)."""
    return p.battery_cells * np.interp(soc, p.battery_cell_soc, p.battery_cell_ocv_v)


#: One stretch of a run with constant bench constants: (first step, the bench from that step on,
#: jump of the winding temperature at that step in K). A healthy run is one: [(0, p, 0.0)].
Segment = tuple[int, BenchParams, float]


def _segments(p: BenchParams, faults: Sequence[Fault], dt: float) -> list[Segment]:
    """The run split at the faults' onsets: each stretch's bench has every fault begun by its
    first step applied (a fault at an onset between steps begins at the next step)."""
    out: list[Segment] = [(0, p, 0.0)]
    for f in faults:  # by onset
        k = max(0, int(math.ceil(f.onset_s / dt - 1e-9)))
        if k != out[-1][0]:
            out.append((k, out[-1][1], 0.0))
        first, bench, jump = out[-1]
        out[-1] = (first, apply_fault(bench, f), jump + temperature_jump_k(f))
    return out


def _integrate(p: BenchParams, duty: np.ndarray, eff: dict[str, float], soc0: float,
               segments: Sequence[Segment] | None = None) -> dict[str, np.ndarray]:
    """March the plant and the battery at the fixed step; returns truth arrays.

    A plain Python loop over scalars (locals only, no per-step allocation): the states are
    coupled nonlinearly, each step is a handful of flops, and vectorising is not possible. The
    plant's step (``plant.make_step``) sees the pack's open-circuit voltage less its polarisation
    (``battery_voltage`` strength s scales their deviation from the starting OCV) behind the
    series resistance s R_s. ``segments`` (faults injected mid-run, see :func:`_segments`)
    restart the loop with another bench's constants, carrying the states (speed, temperature,
    charge, polarisation) across; one segment runs exactly the arithmetic of a healthy run.
    """
    n = len(duty)
    dt = p.sim_step_s
    sbv = eff["battery_voltage"]
    v0 = float(pack_ocv(p, soc0))  # the run's starting OCV: the battery_voltage reference
    steps = float(_OCV_STEPS)
    grid = np.linspace(0.0, 1.0, _OCV_STEPS + 1)
    duty_all = duty.tolist()
    stretches = list(segments) if segments else [(0, p, 0.0)]

    w = 0.0
    temp = p.ambient_temperature_c
    soc = soc0
    vp = 0.0
    vp2 = 0.0
    out_w = [0.0] * n
    out_ib = [0.0] * n
    out_v = [0.0] * n
    out_temp = [0.0] * n
    out_soc = [0.0] * n
    for s, (first, ps, jump) in enumerate(stretches):
        stop = stretches[s + 1][0] if s + 1 < len(stretches) else n
        rs = ps.battery_series_resistance_ohm
        step = make_step(ps, eff, sbv * rs)
        r1 = ps.battery_polarisation_resistance_ohm
        e1 = math.exp(-dt / ps.battery_polarisation_time_constant_s)
        r2 = ps.battery_polarisation2_resistance_ohm
        e2 = math.exp(-dt / ps.battery_polarisation2_time_constant_s)
        q_c = ps.battery_capacity_c
        ocv_tab = pack_ocv(ps, grid)
        ocv = ocv_tab.tolist()
        slope = np.append(np.diff(ocv_tab), 0.0).tolist()
        if jump:
            temp += jump
        for k, d in enumerate(duty_all[first:stop], first):
            x = soc * steps
            if x <= 0.0:
                voc = ocv[0]
            else:
                j = int(x)
                voc = ocv[j] + (x - j) * slope[j] if j < _OCV_STEPS else ocv[_OCV_STEPS]
            out_w[k], w_next, i, temp_next = step(w, temp, d, v0 + sbv * (voc - vp - vp2 - v0))
            ib = d * i
            out_ib[k] = ib
            out_v[k] = v0 + sbv * (voc - vp - vp2 - rs * ib - v0)
            out_temp[k] = temp
            out_soc[k] = soc
            # advance the slow states
            temp = temp_next
            soc -= ib * dt / q_c
            if soc < 0.0:
                soc = 0.0  # empty: the model holds the empty-pack voltage (no cutoff modelled)
            elif soc > 1.0:
                soc = 1.0
            vp = vp * e1 + r1 * ib * (1.0 - e1)
            vp2 = vp2 * e2 + r2 * ib * (1.0 - e2)
            w = w_next
    return {
        "speed": np.asarray(out_w),
        "current": np.asarray(out_ib),
        "voltage": np.asarray(out_v),
        "temperature": np.asarray(out_temp),
        "soc": np.asarray(out_soc),
    }


def _battery_adc(
    p: BenchParams, t: np.ndarray, truth_t: np.ndarray, volts: np.ndarray, amps: np.ndarray,
    rng: np.random.Generator,
) -> np.ndarray:
    """Terminal voltage + switching modulation, through the divider, noisy, quantised.

    The modulation: each 1 kHz sample lands at a random phase of the ESC's ~10 kHz chopping, so
    it sees the terminal either during the current pulse or between pulses, plus lead ringing.
    Zero-mean, amplitude proportional to the battery current (regeneration included).
    """
    v = np.interp(t, truth_t, volts)
    ib = np.interp(t, truth_t, amps)
    n = len(t)
    shape = 0.8 * rng.choice((-1.0, 1.0), n) + 0.2 * rng.standard_normal(n)
    adc = (v + p.battery_modulation_ohm * np.abs(ib) * shape) / p.adc_divider_ratio
    adc += rng.normal(0.0, p.adc_noise_v, n) if p.adc_noise_v > 0 else 0.0
    if p.adc_resolution_v > 0:
        adc = np.round(adc / p.adc_resolution_v) * p.adc_resolution_v
    return adc


def _tachometer(
    p: BenchParams, duration_s: float, truth_t: np.ndarray, speed: np.ndarray,
    rng: np.random.Generator,
) -> np.ndarray:
    """Phototransistor voltage at the tachometer rate (float32), processed in bounded chunks.

    The rotor angle is the trapezoidal integral of the 1 kHz speed, linearly interpolated. Each
    sample's input is the fraction of the preceding sample interval during which a blade blocked
    the beam (so edge timing is not quantised to the sample grid); the sensor's first-order
    response is then discretised exactly for that held input (lfilter, state carried across chunks).
    """
    fs = p.tach_sample_rate_hz
    ns = max(1, int(math.ceil(duration_s * fs - 1e-9)))
    dt = p.sim_step_s
    two_pi = 2.0 * math.pi
    # angle at the simulation nodes, one extra node past the end (last speed held)
    node_t = np.arange(len(speed) + 1) * dt
    w_ext = np.append(speed, speed[-1])
    theta = np.empty(len(w_ext))
    theta[0] = rng.uniform(0.0, two_pi)
    np.cumsum(0.5 * (w_ext[1:] + w_ext[:-1]) * dt, out=theta[1:])
    theta[1:] += theta[0]
    # blocked measure over one turn: blade 1 from 0, blade 2 near half a turn (slightly off)
    w1 = two_pi * p.tach_blade_width_fraction
    w2 = w1 * (1.0 + p.tach_blade_width_asymmetry_fraction)
    s2 = math.pi * (1.0 + p.tach_blade_spacing_asymmetry_fraction)
    knots = np.array([0.0, w1, s2, s2 + w2, two_pi])
    cum = np.array([0.0, w1, w1, w1 + w2, w1 + w2])
    per_turn = w1 + w2

    hi, lo = p.tach_high_v, p.tach_low_v
    if p.tach_time_constant_s > 0:
        a = math.exp(-1.0 / (fs * p.tach_time_constant_s))
    else:
        a = 0.0
    b_f, a_f = [1.0 - a], [1.0, -a]
    lsb = p.tach_adc_full_scale_v / (1 << int(p.tach_adc_bits))
    top = ((1 << int(p.tach_adc_bits)) - 1) * lsb
    out = np.empty(ns, dtype=np.float32)
    zi = None
    theta_prev = None
    for start in range(0, ns, _TACH_CHUNK):
        stop = min(ns, start + _TACH_CHUNK)
        ts = np.arange(start, stop) / fs
        th = np.interp(ts, node_t, theta)
        turns = np.floor(th / two_pi)
        phi = th - turns * two_pi
        bm = turns * per_turn + np.interp(phi, knots, cum)  # blocked angle since 0
        blocked_now = (phi < w1) | ((phi >= s2) & (phi < s2 + w2))
        if theta_prev is None:
            th_before = np.concatenate([[th[0]], th[:-1]])
            bm_before = np.concatenate([[bm[0]], bm[:-1]])
        else:
            th_before = np.concatenate([[theta_prev[0]], th[:-1]])
            bm_before = np.concatenate([[theta_prev[1]], bm[:-1]])
        dth = th - th_before
        moving = dth > 1e-12
        frac = np.where(moving, (bm - bm_before) / np.where(moving, dth, 1.0), blocked_now)
        np.clip(frac, 0.0, 1.0, out=frac)
        u = hi - frac * (hi - lo)
        if zi is None:
            zi = np.array([a * u[0]])
        y, zi = lfilter(b_f, a_f, u, zi=zi)
        if p.tach_noise_v > 0:
            y += rng.normal(0.0, p.tach_noise_v, len(y))
        np.clip(np.round(y / lsb) * lsb, 0.0, top, out=y)
        out[start:stop] = y
        theta_prev = (th[-1], bm[-1])
    return out


def simulate(
    profile: str,
    duration_s: float,
    seed: int,
    effects: dict[str, float] | None = None,
    soc: float = 1.0,
    params: BenchParams | None = None,
    pwm: tuple[np.ndarray, np.ndarray] | None = None,
    faults: Sequence[Fault] = (),
) -> SimResult:
    """Simulate the bench for ``duration_s`` under a named profile (or the command ``pwm``).

    ``effects=None`` is the realistic bench (every effect at 1.0); a dict sets the named ones.
    ``pwm=(t, level)`` replaces the named profile (``profile`` is then only a label); the ESC
    holds each level until the next, PWM_STOP before the first, levels clipped to 0.05..0.10.
    ``faults`` change the bench from their onsets on (``sim.faults``; several allowed, each from
    its own onset, which must lie inside the run); before the first onset the run is the healthy
    one, number for number. Same arguments, same arrays: noise comes from independent streams
    of ``seed``.
    """
    d = check_duration(duration_s)
    seed = _check_seed(seed)
    eff = resolve_effects(effects)
    soc0 = _check_soc(soc)
    p = check_params(params if params is not None else BenchParams())
    injected = _check_faults(faults, d)
    streams = np.random.SeedSequence(seed).spawn(3)  # independent: profile, battery ADC, tachometer
    rng_profile, rng_batt, rng_tach = (np.random.default_rng(s) for s in streams)

    if pwm is None:
        cmd_t, cmd = make_profile(profile, d, rng_profile)
        pwm_t, pwm_lv = cmd_t, cmd
    else:
        cmd_t, cmd = check_command(pwm)
        inside = (cmd_t >= 0.0) & (cmd_t < d)
        pwm_t, pwm_lv = cmd_t[inside], cmd[inside]

    dt = p.sim_step_s
    n = max(1, int(math.ceil(d / dt - 1e-9)))
    truth_t = np.arange(n) * dt
    duty = esc_duty(p, eff, cmd_t, cmd, truth_t)

    segments = _segments(p, injected, dt)
    truth = _integrate(p, duty, eff, soc0, segments)
    speed = truth["speed"]
    thrust = np.empty_like(speed)
    for s, (first, bench, _) in enumerate(segments):  # b w^2 with each stretch's propeller
        stop = segments[s + 1][0] if s + 1 < len(segments) else n
        thrust[first:stop] = bench.thrust_coefficient * speed[first:stop] ** 2

    battery_t = np.arange(max(1, int(math.ceil(d * p.adc_sample_rate_hz - 1e-9)))) / p.adc_sample_rate_hz
    battery_adc = _battery_adc(p, battery_t, truth_t, truth["voltage"], truth["current"], rng_batt)
    tach = _tachometer(p, d, truth_t, speed, rng_tach)

    return SimResult(
        pwm_t=np.asarray(pwm_t, dtype=float),
        pwm=np.asarray(pwm_lv, dtype=float),
        battery_t=battery_t,
        battery_adc=battery_adc,
        tach_rate_hz=float(p.tach_sample_rate_hz),
        tach_t0=0.0,
        tach=tach,
        truth_t=truth_t,
        truth_speed=speed,
        truth_thrust=thrust,
        truth_current=truth["current"],
        truth_voltage=truth["voltage"],
        truth_temperature=truth["temperature"],
        truth_soc=truth["soc"],
        effects=eff,
        params=p,
        profile=str(profile),
        seed=seed,
        faults=injected,
    )
