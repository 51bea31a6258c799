"""A node's start pays only for what it uses: no scipy, and the battery filter's coefficients
computed without it, as scipy.signal.bilinear gives them (benchmarks/bench_node_start.py
measures the start)."""

from __future__ import annotations

import itertools
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import signal

from bldc_propulsion.contract import PAPER_FILTER_TAU_S
from bldc_propulsion.core.battery_filter import discretise

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("tau_s,rate_hz", list(itertools.product(
    (PAPER_FILTER_TAU_S, 1e-3, 0.25, 2.0, 37.5, 900.0), (0.5, 50.0, 999.0, 1000.0, 1234.5, 20000.0, 1e6))))
def test_discretise_is_scipy_bilinear(tau_s, rate_hz):
    """Equal to scipy's to the last bit or two, whatever scipy's version (their arithmetic
    differs); bit for bit with scipy 1.17, the one the figures were made with (below)."""
    b, a = discretise(tau_s, rate_hz)
    b_ref, a_ref = signal.bilinear([1.0], [tau_s, 1.0], fs=rate_hz)
    np.testing.assert_allclose(b, b_ref, rtol=5e-16, atol=0)
    np.testing.assert_allclose(a, a_ref, rtol=5e-16, atol=0)
    assert a[0] == 1.0
    assert b.dtype == a.dtype == np.float64 and b.shape == a.shape == (2,)


def test_discretise_gives_the_bytes_scipy_1_17_gave():
    """The coefficients the nodes, replay and training used before the filter stopped
    importing scipy (scipy 1.17.1's bilinear, recorded as hex): no output moves."""
    recorded = {
        1000.0: (["0x1.0624dd2f1a800p-12"] * 2, ["0x1.0000000000000p+0", "-0x1.ffbe76c8b4397p-1"]),
        500.0: (["0x1.0614174a48f22p-11"] * 2, ["0x1.0000000000000p+0", "-0x1.ff7cf5f45adb8p-1"]),
    }
    for rate_hz, (b_hex, a_hex) in recorded.items():
        b, a = discretise(PAPER_FILTER_TAU_S, rate_hz)
        assert [float(x).hex() for x in b] == b_hex
        assert [float(x).hex() for x in a] == a_hex


def test_core_package_names_are_still_importable_from_it():
    import bldc_propulsion.core as core

    for name in core.__all__:
        assert getattr(core, name) is not None, name
    assert {"BatteryFilter", "ThrustEstimator", "TachometerDecoder", "OK"} <= set(dir(core))
    with pytest.raises(AttributeError):
        core.no_such_name  # noqa: B018


@pytest.mark.parametrize("module", [
    "battery_filter_node", "tachometer_node", "thrust_estimator_node", "all_in_one"])
def test_node_modules_import_without_scipy(module):
    """scipy.signal alone was 0.6 s of a node's 0.9 s of imports on a quiet machine."""
    from _ros import require_rclpy

    require_rclpy()
    code = (f"import sys, bldc_propulsion.nodes.{module}; "
            "sys.exit(sorted(m for m in sys.modules if m.split('.')[0] == 'scipy')[:3] or 0)")
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]


def test_the_tachometer_does_not_import_the_estimator_or_the_model():
    code = ("import sys, bldc_propulsion.core.tachometer, bldc_propulsion.core.status, "
            "bldc_propulsion.core.tach_output; "
            "sys.exit([m for m in ('bldc_propulsion.core.estimator', 'bldc_propulsion.model', "
            "'bldc_propulsion.physics.plant') if m in sys.modules] or 0)")
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
