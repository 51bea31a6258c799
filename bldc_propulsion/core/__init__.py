"""ROS-free signal processing: battery filter, tachometer decoder, model inputs, estimator.

Each core validates its own input, keeps counters and reports them with ``status()``; the
streaming and batch entry points of a core share one code path.

The names below are imported from their modules on first use (PEP 562), not when the package
is: a node that imports ``core.status`` or ``core.tachometer`` then does not pay for the
estimator, the model and the plant it never uses (benchmarks/bench_node_start.py).
"""

from __future__ import annotations

import importlib
from typing import Any

#: name -> the module of this package that defines it
_HOME = {
    "BatteryFilter": "battery_filter", "BatteryFilterConfig": "battery_filter",
    "Prediction": "estimator", "ThrustEstimator": "estimator",
    "FeatureState": "features", "compute_features": "features", "register_feature": "features",
    "ERROR": "status", "OK": "status", "WARN": "status", "CoreStatus": "status",
    "TachBatchResult": "tachometer", "TachometerConfig": "tachometer",
    "TachometerDecoder": "tachometer",
}

__all__ = sorted(_HOME)


def __getattr__(name: str) -> Any:
    if name not in _HOME:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{_HOME[name]}", __name__), name)
    globals()[name] = value  # once: later lookups do not come here
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_HOME})
