"""Health report of a core, independent of ROS (adapters turn it into DiagnosticStatus)."""

from __future__ import annotations

from dataclasses import dataclass, field

#: Levels, numbered as diagnostic_msgs/DiagnosticStatus numbers them.
OK = 0
WARN = 1
ERROR = 2


@dataclass(frozen=True)
class CoreStatus:
    """One named status line: level (OK/WARN/ERROR), one-line message, counters as strings."""

    name: str
    level: int
    message: str
    values: dict[str, str] = field(default_factory=dict)


def counters(**kw: object) -> dict[str, str]:
    """Counter values as the strings diagnostics carry (floats with 6 significant digits)."""
    out: dict[str, str] = {}
    for k, v in kw.items():
        out[k] = f"{v:.6g}" if isinstance(v, float) else str(v)
    return out
