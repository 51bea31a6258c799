"""Physics of the test bench (no I/O): battery, ESC, motor, propeller and the bench's sensors.

``simulate(profile, duration_s, seed, ...) -> SimResult``; see docs/architecture.md.
"""

from __future__ import annotations

from .bench import EFFECT_DOCS, SimResult, simulate
from .params import BenchParams, params_with_overrides
from .profiles import PROFILES, make_profile

__all__ = [
    "EFFECT_DOCS",
    "PROFILES",
    "BenchParams",
    "SimResult",
    "make_profile",
    "params_with_overrides",
    "simulate",
]
