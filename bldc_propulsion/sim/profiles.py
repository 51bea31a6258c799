"""Seeded, reproducible ESC command profiles: one PWM level per 50 Hz frame (zero-order hold).

Each profile is ``f(duration_s, rng) -> levels`` with one level in [PWM_STOP, PWM_FULL] per
frame; frame k starts at k / PWM_FRAME_HZ. The same seed always gives the same profile.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from ..contract import PWM_FRAME_HZ, PWM_FULL, PWM_STOP
from ..errors import BadInputError

Profile = Callable[[float, np.random.Generator], np.ndarray]

_MID = 0.5 * (PWM_STOP + PWM_FULL)

#: A bench run starts with the ESC being armed at the stop level (ESCs refuse to start until
#: they have seen ~1 s of a 1 ms pulse), so every recording begins with the rotor at rest and
#: the command at 0.05 (kept only when the duration leaves room for the profile itself).
ARMING_S = 1.0


def _frames(duration_s: float) -> int:
    """Frames needed to cover [0, duration_s)."""
    return max(1, int(math.ceil(duration_s * PWM_FRAME_HZ - 1e-9)))


def _frame_t(n: int) -> np.ndarray:
    return np.arange(n, dtype=float) / PWM_FRAME_HZ


def _hold(levels: list[float], holds_s: list[float], n: int) -> np.ndarray:
    """Piecewise-constant sequence of (level, hold) cut or padded (last level) to n frames."""
    counts = np.maximum(1, np.round(np.asarray(holds_s) * PWM_FRAME_HZ).astype(int))
    out = np.repeat(np.asarray(levels, dtype=float), counts)
    if len(out) < n:
        out = np.concatenate([out, np.full(n - len(out), out[-1] if len(out) else PWM_STOP)])
    return out[:n]


def staircase(duration_s: float, rng: np.random.Generator) -> np.ndarray:
    """Steps of 0.005 up from 0.05 to 0.10 and back down, 2-3 s each (the paper's training data).

    The rotor settles within ~0.7 s (time constant ~0.15 s), so 2-3 s holds show each level's
    steady state and its step response, and one cycle up and down takes ~50 s: a 30 s
    recording still reaches full throttle (with 4-6 s holds it stopped at PWM 0.075).
    """
    n = _frames(duration_s)
    up = list(np.round(np.arange(PWM_STOP, PWM_FULL + 1e-9, 0.005), 6))
    cycle = up + up[-2:0:-1]  # 0.05 .. 0.10 .. 0.055, then repeats from 0.05
    levels: list[float] = []
    holds: list[float] = []
    total = 0.0
    while total < duration_s:
        for lvl in cycle:
            h = float(rng.uniform(2.0, 3.0))
            levels.append(float(lvl))
            holds.append(h)
            total += h
            if total >= duration_s:
                break
    return _hold(levels, holds, n)


def triangle(duration_s: float, rng: np.random.Generator) -> np.ndarray:
    """Linear sweep 0.05 -> 0.10 -> 0.05 over 20 s, repeated (paper Fig. 5).

    10 s per ramp is quasi-static for the rotor (~0.15 s) and lets a 30 s recording sweep up
    and down, with the battery sagging and recovering along the way.
    """
    del rng  # deterministic: the paper's sweep
    t = _frame_t(_frames(duration_s))
    period = 20.0
    phase = (t % period) / period
    tri = 1.0 - np.abs(2.0 * phase - 1.0)  # 0 -> 1 -> 0
    return PWM_STOP + (PWM_FULL - PWM_STOP) * tri


def constant(duration_s: float, rng: np.random.Generator) -> np.ndarray:
    """One level, 0.085, for the whole run: battery drain at a fixed command (paper Figs. 3-4)."""
    del rng
    return np.full(_frames(duration_s), 0.085)


def chirp(duration_s: float, rng: np.random.Generator) -> np.ndarray:
    """Noisy chirp around mid throttle, 0.05 Hz rising to 3 Hz (paper Fig. 13, validation data).

    The frequency rises exponentially so each octave gets the same time; frame noise of
    0.002 mimics the paper's "noisy pwm input".
    """
    t = _frame_t(_frames(duration_s))
    f0, f1 = 0.05, 3.0
    span = max(duration_s, 1e-9)
    k = math.log(f1 / f0) / span
    phase = 2.0 * math.pi * f0 * (np.expm1(k * t) / k)
    lvl = _MID + 0.015 * np.sin(phase) + rng.normal(0.0, 0.002, len(t))
    return np.clip(lvl, PWM_STOP, PWM_FULL)


def random_steps(duration_s: float, rng: np.random.Generator) -> np.ndarray:
    """Random levels over the whole range held for random 0.5-5 s: rich excitation."""
    n = _frames(duration_s)
    levels: list[float] = []
    holds: list[float] = []
    total = 0.0
    while total < duration_s:
        levels.append(float(np.round(rng.uniform(PWM_STOP, PWM_FULL), 4)))
        holds.append(float(rng.uniform(0.5, 5.0)))
        total += holds[-1]
    return _hold(levels, holds, n)


def high_load(duration_s: float, rng: np.random.Generator) -> np.ndarray:
    """Long high throttle (0.095-0.10) with brief dips every 15-40 s: heats the motor."""
    n = _frames(duration_s)
    levels: list[float] = []
    holds: list[float] = []
    total = 0.0
    while total < duration_s:
        levels.append(float(np.round(rng.uniform(0.095, PWM_FULL), 4)))
        holds.append(float(rng.uniform(15.0, 40.0)))
        levels.append(float(np.round(rng.uniform(0.065, 0.08), 4)))
        holds.append(float(rng.uniform(0.5, 2.0)))
        total += holds[-1] + holds[-2]
    return _hold(levels, holds, n)


#: A multirotor's idle in flight: the flight controller never lets a motor stop while flying
#: (Betaflight's airmode and PX4's idle keep it turning), so it stays above every start level
#: the randomized benches draw (0.052-0.058).
FLIGHT_IDLE = 0.060


def flight(duration_s: float, rng: np.random.Generator) -> np.ndarray:
    """One motor of a multirotor in flight: never stopped, hovering with manoeuvres.

    Take-off to a hover level drawn per flight (0.068-0.082: a 35-65 % hover throttle), which
    wanders slowly (a random walk of 0.0002 per square-root second, as wind and the pack's sag move it);
    manoeuvres of 0.3-3 s each move the motor -0.012 to +0.015 about it, one in ten a punch-out
    to 0.095-0.10; the attitude loop's frame-to-frame noise (0.0015) rides on top. Clipped to
    [FLIGHT_IDLE, PWM_FULL]: what a health monitor sees between take-off and landing, where
    ``random_steps`` stops the motor for seconds at a time.
    """
    n = _frames(duration_s)
    t = _frame_t(n)
    hover = float(rng.uniform(0.068, 0.082))
    walk = hover + np.cumsum(rng.normal(0.0, 0.0002 / math.sqrt(PWM_FRAME_HZ), n))
    offsets: list[float] = []
    holds: list[float] = []
    total = 0.0
    while total < duration_s:
        if rng.uniform() < 0.1:
            offsets.append(float(rng.uniform(0.095, PWM_FULL)) - hover)  # a punch-out
            holds.append(float(rng.uniform(0.5, 2.0)))
        else:
            offsets.append(float(rng.uniform(-0.012, 0.015)))
            holds.append(float(rng.uniform(0.3, 3.0)))
        total += holds[-1]
    lvl = walk + _hold(offsets, holds, n) + rng.normal(0.0, 0.0015, n)
    take_off = np.clip(t / 2.0, 0.0, 1.0)  # 2 s from idle up to the flight's levels
    lvl = FLIGHT_IDLE + take_off * (lvl - FLIGHT_IDLE)
    return np.clip(lvl, FLIGHT_IDLE, PWM_FULL)


PROFILES: dict[str, Profile] = {
    "staircase": staircase,
    "triangle": triangle,
    "constant": constant,
    "chirp": chirp,
    "random_steps": random_steps,
    "high_load": high_load,
    "flight": flight,
}


#: Longest simulated recording: the 20 kHz tachometer alone is 72 M samples per hour, and the
#: simulator holds every stream in memory (about 1 GB per 30 min); longer runs go in parts.
MAX_DURATION_S = 1800.0


def check_duration(duration_s: float) -> float:
    """A finite duration in (0, MAX_DURATION_S] (BadInputError otherwise)."""
    try:
        d = float(duration_s)
    except (TypeError, ValueError):
        raise BadInputError(f"--duration {duration_s!r}: not a number") from None
    if not math.isfinite(d) or d <= 0.0:
        raise BadInputError(f"--duration {duration_s!r}: must be a finite number of seconds > 0")
    if d > MAX_DURATION_S:
        raise BadInputError(f"--duration {duration_s!r}: at most {MAX_DURATION_S:g} s (the simulator holds "
                            "the whole 20 kHz recording in memory); simulate longer runs in parts")
    return d


def make_profile(
    name: str, duration_s: float, seed_or_rng: int | np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """(frame start times [s], PWM levels) of profile ``name`` covering [0, duration_s)."""
    if name not in PROFILES:
        raise BadInputError(f"--profile {name}: unknown profile (known: {', '.join(PROFILES)})")
    d = check_duration(duration_s)
    if isinstance(seed_or_rng, np.random.Generator):
        rng = seed_or_rng
    else:
        if isinstance(seed_or_rng, bool) or not isinstance(seed_or_rng, (int, np.integer)) or seed_or_rng < 0:
            raise BadInputError(f"--seed {seed_or_rng!r}: must be a whole number >= 0")
        rng = np.random.default_rng(int(seed_or_rng))
    n = _frames(d)
    n_arm = _frames(ARMING_S) if d >= 4.0 * ARMING_S else 0
    body = np.asarray(PROFILES[name](d - n_arm / PWM_FRAME_HZ, rng), dtype=float)
    levels = np.concatenate([np.full(n_arm, PWM_STOP), body])[:n]
    return _frame_t(len(levels)), levels
