"""The simulated test bench (no I/O): the plant of ``physics/`` driven by a battery model, and the
bench's sensors. Its constants are ``physics.params.BenchParams``.

``simulate(profile, duration_s, seed, ...) -> SimResult``; see docs/architecture.md.
"""

from __future__ import annotations

from .bench import EFFECT_DOCS, SimResult, simulate
from .faults import FAULT_DOCS, Fault, parse_fault
from .profiles import PROFILES, make_profile

__all__ = [
    "EFFECT_DOCS",
    "FAULT_DOCS",
    "PROFILES",
    "Fault",
    "SimResult",
    "make_profile",
    "parse_fault",
    "simulate",
]
