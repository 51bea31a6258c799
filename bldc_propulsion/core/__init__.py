"""ROS-free signal processing: battery filter, tachometer decoder, model inputs, estimator.

Each core validates its own input, keeps counters and reports them with ``status()``; the
streaming and batch entry points of a core share one code path.
"""

from .battery_filter import BatteryFilter, BatteryFilterConfig
from .estimator import PhysicsModel, Prediction, ThrustEstimator, fallback_model
from .features import FeatureState, compute_features, register_feature
from .status import ERROR, OK, WARN, CoreStatus
from .tachometer import TachBatchResult, TachometerConfig, TachometerDecoder

__all__ = [
    "ERROR", "OK", "WARN", "BatteryFilter", "BatteryFilterConfig", "CoreStatus", "FeatureState",
    "PhysicsModel", "Prediction", "TachBatchResult", "TachometerConfig", "TachometerDecoder",
    "ThrustEstimator", "compute_features", "fallback_model", "register_feature",
]
