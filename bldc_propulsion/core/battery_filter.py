"""Battery voltage filter of the paper, eq. (1), for any sample rate and irregular samples.

The paper filters the ESC-modulated battery voltage with

    H(z) = 4.9975e-4 (z + 1) / (z - 0.9995)   at 1 kHz.

That is the bilinear (Tustin) discretisation of a first-order low-pass K / (tau s + 1) with
tau = 1.9995 s and K = 1.999 (``contract.paper_filter_prototype``: the physics model needs the
same tau for the lag of its voltage input). The DC gain K is the voltage divider in front of the ADC (the
ADC reads under 10 V), so this module keeps the two apart:

    battery volts = divider_ratio * lowpass(adc volts),   lowpass = 1 / (tau s + 1)

With ``divider_ratio = 1.999`` (the default) and 1 kHz samples the output is exactly the
paper's H(z); a bench with a 1:3 divider sets ``divider_ratio = 3.0``. At any other rate the
same continuous filter is rediscretised (Tustin, as scipy.signal.bilinear computes it); the
1 kHz coefficients are never reused with another period.

Sample handling (one code path for ``update`` and ``process``):
- The first valid sample starts the filter in steady state at that value (no 2 s climb from 0 V).
- Each step uses the actual time since the previous accepted sample. Steps within
  ``dt_tolerance`` (relative) of the nominal period use the cached nominal coefficients, so
  clean data is filtered exactly as the paper does; other steps get Tustin coefficients for
  their own dt (the trapezoidal rule applied to the continuous filter).
- A gap longer than ``max_gap_s`` restarts the filter at the new sample (counted as a reset):
  the old state says nothing reliable about the battery after that long.
- Samples with NaN/inf, outside [min_adc_v, max_adc_v] (volts at the ADC pin), or not later
  than the previous accepted sample are rejected, counted, and leave the state untouched.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..contract import PAPER_DIVIDER_RATIO, PAPER_FILTER_RATE_HZ, PAPER_FILTER_TAU_S
from ..errors import BadInputError
from .status import OK, WARN, CoreStatus, counters


def discretise(tau_s: float, sample_rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """(b, a) of the unit-gain low-pass 1/(tau s + 1) discretised by Tustin at sample_rate_hz.

    The arithmetic of scipy.signal.bilinear (scipy 1.17: the factor 2 fs split as sqrt(2 fs)
    between (z + 1) and (z - 1)) written out for the first order, bit-identical to it
    (test/test_node_start.py), without importing scipy.signal: that import was most of a
    node's start (0.6 s of 0.9 s on a quiet machine; benchmarks/bench_node_start.py).
    """
    fac = math.sqrt(sample_rate_hz * 2.0)
    p = 1.0 / fac
    q = tau_s * fac
    d0, d1 = p + q, p - q
    return np.array([p / d0, p / d0]), np.array([d0 / d0, d1 / d0])


def _tustin_step(tau_s: float, dt: float) -> tuple[float, float, float]:
    """(b0, b1, a1) of the same Tustin discretisation for one step of length dt (closed form).

    Used for irregular steps, where calling scipy for every sample would cost 50x more; the
    tests check it equals :func:`discretise`.
    """
    c = 2.0 * tau_s / dt
    b0 = 1.0 / (1.0 + c)
    return b0, b0, (1.0 - c) / (1.0 + c)


@dataclass(frozen=True)
class BatteryFilterConfig:
    """Parameters of :class:`BatteryFilter` (SI units; ADC limits in volts at the ADC pin)."""

    sample_rate_hz: float = PAPER_FILTER_RATE_HZ
    divider_ratio: float = PAPER_DIVIDER_RATIO  #: battery volts per ADC volt (the paper's 1.999)
    min_adc_v: float = 0.0
    max_adc_v: float = 10.0  #: the DS1104 ADC reads under 10 V
    max_gap_s: float = 0.5
    tau_s: float = PAPER_FILTER_TAU_S  #: time constant of the low-pass (paper: 1.9995 s)
    dt_tolerance: float = 0.01  #: relative period jitter still treated as the nominal period

    def __post_init__(self) -> None:
        for name in ("sample_rate_hz", "divider_ratio", "max_gap_s", "tau_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise BadInputError(f"battery filter: {name} must be > 0, got {v!r}")
        if not (math.isfinite(self.min_adc_v) and math.isfinite(self.max_adc_v)
                and self.min_adc_v < self.max_adc_v):
            raise BadInputError(
                f"battery filter: need min_adc_v < max_adc_v, got {self.min_adc_v!r}, {self.max_adc_v!r}")
        if not (0.0 <= self.dt_tolerance < 0.5):
            raise BadInputError(f"battery filter: dt_tolerance must be in [0, 0.5), got {self.dt_tolerance!r}")


class BatteryFilter:
    """Streaming and batch battery filter; ``update`` and ``process`` share state and rules."""

    def __init__(self, config: BatteryFilterConfig | None = None) -> None:
        self.config = config or BatteryFilterConfig()
        cfg = self.config
        self.period_s = 1.0 / cfg.sample_rate_hz
        self.b, self.a = discretise(cfg.tau_s, cfg.sample_rate_hz)  # cached nominal coefficients
        self._b0, self._b1, self._a1 = float(self.b[0]), float(self.b[1]), float(self.a[1])
        self._dt_lo = self.period_s * (1.0 - cfg.dt_tolerance)
        self._dt_hi = self.period_s * (1.0 + cfg.dt_tolerance)
        self.accepted = 0
        self.rejected_nonfinite = 0
        self.rejected_range = 0
        self.rejected_time = 0
        self.resets = 0  #: restarts after a gap longer than max_gap_s
        self.irregular_steps = 0  #: steps filtered with their own dt
        self._reported_rejections = 0
        self._last_rejection = ""
        self.reset()

    def reset(self) -> None:
        """Forget the state (counters stay): the next valid sample starts the filter again."""
        self._t: float | None = None
        self._x = 0.0
        self._y = 0.0

    @property
    def rejected(self) -> int:
        return self.rejected_nonfinite + self.rejected_range + self.rejected_time

    @property
    def voltage(self) -> float | None:
        """Latest filtered battery voltage (V), None before the first valid sample."""
        return None if self._t is None else self.config.divider_ratio * self._y

    # --- streaming ---------------------------------------------------------------------------

    def _reject(self, t: float, x: float) -> str | None:
        """Reason a sample is rejected, or None (the same rules as ``process``)."""
        cfg = self.config
        if not (math.isfinite(t) and math.isfinite(x)):
            return "nonfinite"
        if not (cfg.min_adc_v <= x <= cfg.max_adc_v):
            return "range"
        if self._t is not None and t <= self._t:
            return "time"
        return None

    def _count(self, reason: str, n: int = 1) -> None:
        setattr(self, f"rejected_{reason}", getattr(self, f"rejected_{reason}") + n)
        self._last_rejection = reason

    def update(self, t: float, adc: float) -> float | None:
        """Filter one ADC sample (V at the pin) taken at t (s); battery volts, or None if rejected."""
        t = float(t)
        x = float(adc)
        cfg = self.config
        last = self._t
        # a sample _reject accepts (in range, hence finite; later than the last), tested inline:
        # this runs for every sample, 1 kHz
        if not (cfg.min_adc_v <= x <= cfg.max_adc_v and math.isfinite(t)
                and (last is None or t > last)):
            reason = self._reject(t, x)
            assert reason is not None, "the test above accepts only what _reject accepts"
            self._count(reason)
            return None
        self.accepted += 1
        if last is None:
            self._y = x
        else:
            dt = t - last
            if dt > cfg.max_gap_s:
                self.resets += 1
                self._y = x
            else:
                if self._dt_lo <= dt <= self._dt_hi:
                    b0, b1, a1 = self._b0, self._b1, self._a1
                else:
                    self.irregular_steps += 1
                    b0, b1, a1 = _tustin_step(cfg.tau_s, dt)
                # transposed direct form II, the arithmetic scipy.signal.lfilter does
                self._y = b0 * x + (b1 * self._x - a1 * self._y)
        self._t = t
        self._x = x
        return cfg.divider_ratio * self._y

    # --- batch -------------------------------------------------------------------------------

    def process(self, t: np.ndarray, adc: np.ndarray) -> np.ndarray:
        """Filter arrays of sample times (s) and ADC volts; battery volts, NaN where rejected.

        Same rules and state as calling ``update`` per sample (equal to 1e-12); runs of
        nominal-period samples go through scipy.signal.lfilter.
        """
        t = np.asarray(t, dtype=float)
        x = np.asarray(adc, dtype=float)
        if t.ndim != 1 or t.shape != x.shape:
            raise BadInputError(f"battery filter: t and adc must be 1-D of equal length, got {t.shape}, {x.shape}")
        n = len(t)
        out = np.full(n, np.nan)
        if n == 0:
            return out
        idx = self._accepted_samples(t, x)
        m = len(idx)
        if m == 0:
            return out
        ta, xa = t[idx], x[idx]
        kind, dt = self._step_kinds(ta)
        y = self._filter_steps(ta, xa, kind, dt)
        self._t = float(ta[-1])
        self.accepted += m
        out[idx] = self.config.divider_ratio * y
        return out

    def _accepted_samples(self, t: np.ndarray, x: np.ndarray) -> np.ndarray:
        """Indices of the samples ``update`` would accept; the rejected ones counted by reason."""
        cfg = self.config
        n = len(t)
        finite = np.isfinite(t) & np.isfinite(x)
        with np.errstate(invalid="ignore"):
            in_range = (x >= cfg.min_adc_v) & (x <= cfg.max_adc_v)
        cand = finite & in_range
        # a candidate is accepted iff it is later than every earlier accepted sample
        tv = np.where(cand, t, -np.inf)
        start = -np.inf if self._t is None else self._t
        prev_max = np.maximum.accumulate(np.concatenate(([start], tv)))[:-1]
        acc = cand & (t > prev_max)
        n_nonfinite = int(n - np.count_nonzero(finite))
        n_range = int(np.count_nonzero(finite & ~in_range))
        n_time = int(np.count_nonzero(cand & ~acc))
        for reason, k in (("nonfinite", n_nonfinite), ("range", n_range), ("time", n_time)):
            if k:
                setattr(self, f"rejected_{reason}", getattr(self, f"rejected_{reason}") + k)
        if n_nonfinite or n_range or n_time:  # reason of the last rejected sample, as update
            last_bad = int(np.flatnonzero(~acc)[-1])
            self._last_rejection = ("nonfinite" if not finite[last_bad]
                                    else "range" if not in_range[last_bad] else "time")
        return np.flatnonzero(acc)

    def _step_kinds(self, ta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Each accepted sample's step from the one before (the filter's last sample for the
        first): 0 nominal period, 1 irregular, 2 start/restart; and its length (s)."""
        m = len(ta)
        kind = np.zeros(m, dtype=np.int8)
        dt = np.empty(m)
        dt[1:] = np.diff(ta)
        if self._t is None:
            kind[0] = 2
            dt[0] = np.inf
        else:
            dt[0] = ta[0] - self._t
        irregular = (dt < self._dt_lo) | (dt > self._dt_hi)
        kind[irregular] = 1
        kind[dt > self.config.max_gap_s] = 2
        if self._t is None:
            kind[0] = 2
        return kind, dt

    def _filter_steps(self, ta: np.ndarray, xa: np.ndarray, kind: np.ndarray, dt: np.ndarray) -> np.ndarray:
        """The low-pass output at the accepted samples: runs of nominal steps through
        scipy.signal.lfilter (state carried in zi), the others one at a time as ``update``
        takes them; the state is left at the last sample."""
        m = len(ta)
        y = np.empty(m)
        pos = 0
        tau = self.config.tau_s
        from scipy import signal  # here: a node (update only) starts without scipy.signal

        for brk in np.flatnonzero(kind).tolist() + [m]:
            if brk > pos:  # run of nominal steps: lfilter, state carried in zi
                zi = np.array([self._b1 * self._x - self._a1 * self._y])
                y[pos:brk], _ = signal.lfilter(self.b, self.a, xa[pos:brk], zi=zi)
                self._x, self._y = float(xa[brk - 1]), float(y[brk - 1])
            if brk == m:
                break
            xb = float(xa[brk])
            if kind[brk] == 2:
                if self._t is not None or brk > 0:
                    self.resets += 1
                self._y = xb
            else:
                self.irregular_steps += 1
                b0, b1, a1 = _tustin_step(tau, float(dt[brk]))
                self._y = b0 * xb + (b1 * self._x - a1 * self._y)
            self._x = xb
            self._t = float(ta[brk])  # mark started (exact value set by process)
            y[brk] = self._y
            pos = brk + 1
        return y

    # --- diagnostics -------------------------------------------------------------------------

    def status(self) -> list[CoreStatus]:
        """Counters; WARN while nothing valid has arrived or when samples were rejected since the last call."""
        new_rejections = self.rejected - self._reported_rejections
        self._reported_rejections = self.rejected
        if self.accepted == 0:
            level, msg = WARN, "no valid battery/adc sample yet"
        elif new_rejections:
            level, msg = WARN, f"{new_rejections} samples rejected since last report (last: {self._last_rejection})"
        else:
            level, msg = OK, "filtering"
        v = self.voltage
        return [CoreStatus("battery filter", level, msg, counters(
            voltage_v=float("nan") if v is None else v,
            accepted=self.accepted,
            rejected_nonfinite=self.rejected_nonfinite,
            rejected_out_of_range=self.rejected_range,
            rejected_time_not_increasing=self.rejected_time,
            gap_resets=self.resets,
            irregular_steps=self.irregular_steps,
            divider_ratio=self.config.divider_ratio,
            sample_rate_hz=self.config.sample_rate_hz,
        ))]
