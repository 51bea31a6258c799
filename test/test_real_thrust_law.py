"""The thrust law T = b w^2 on the real esc_test logs (../shared/real/esc_test, MIT licence; read
from there, never copied): six ESC + motor pairs on one propeller, so b is the propeller's and
must agree across motors, whatever commanded each log (four were commanded from outside the
stand: no command is needed for the thrust law)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bldc_propulsion.errors import BadInputError
from bldc_propulsion.training.import_csv import thrust_law_samples

REAL = Path(__file__).resolve().parents[2] / "shared" / "real"
LOGS = sorted((REAL / "esc_test").glob("Log_*.csv"))


def test_one_propeller_one_b_across_six_motors():
    assert len(LOGS) == 6, f"expected the six esc_test logs in {REAL / 'esc_test'}"
    bs = []
    for log in LOGS:
        w, thrust = thrust_law_samples(log)
        assert len(w) > 400 and w.max() > 1000.0  # rad/s: a 7 in propeller at 16 V
        b = np.linalg.lstsq((w**2)[:, None], thrust, rcond=None)[0][0]  # reference least squares
        bs.append(b)
        rms = np.sqrt(np.mean((thrust - b * w**2) ** 2))
        assert rms < 0.1 * thrust.max(), (log.name, rms)  # the law holds, transients aside
    bs = np.array(bs)
    # CT = b 4 pi^2 / (rho D^4) of a 7 in three-blade propeller: 0.10-0.18 (mechanical RPM, not electrical)
    ct = bs * 4 * np.pi**2 / (1.225 * (7 * 0.0254) ** 4)
    assert np.all((ct > 0.10) & (ct < 0.18)), ct
    assert np.ptp(bs) / np.median(bs) < 0.10, bs  # one propeller: 4.30-4.57e-6 N s^2/rad^2


def test_a_log_without_thrust_has_no_thrust_law(tmp_path):
    log = tmp_path / "no_thrust.csv"
    log.write_text("Time (s),ESC signal (µs),Motor Electrical Speed (RPM)\n0,1000,0\n0.1,1100,3000\n", encoding="utf-8")
    with pytest.raises(BadInputError, match="no_thrust.csv: no thrust column"):
        thrust_law_samples(log)
