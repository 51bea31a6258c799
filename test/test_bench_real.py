"""``benchmarks/bench_real.py``'s table of the command levels the F80 log holds on its staircase's
way up and again on its way down (../shared/real/esc_test, MIT licence; read from there, never
copied), against the log's own rows: the medians the bag gives are the CSV's."""

from __future__ import annotations

import csv
import io
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from bldc_propulsion.training.import_csv import import_csv

ROOT = Path(__file__).resolve().parents[1]
F80 = ROOT.parent / "shared" / "real" / "esc_test" / "Log_2019-11-09_181347.csv"

pytestmark = pytest.mark.skipif(not F80.is_file(), reason="esc_test logs not available")


def csv_holds() -> list[tuple[float, float, float, float]]:
    """(ESC us, start s, settled speed rad/s, settled current A) per hold of the log's rows: the
    ESC column carried forward over its empty cells, each hold's last two thirds in time."""
    rows = list(csv.reader(io.StringIO(F80.read_text(encoding="utf-8-sig"), newline="")))
    head = rows[0]
    col = {name: head.index(name) for name in ("Time (s)", "ESC signal (µs)", "Motor Electrical Speed (RPM)",
                                               "Current (A)")}
    holds: list[list[tuple[float, float, float, float]]] = []
    esc = math.nan
    for r in rows[1:]:
        if r[col["ESC signal (µs)"]].strip():
            if float(r[col["ESC signal (µs)"]]) != esc:
                holds.append([])
            esc = float(r[col["ESC signal (µs)"]])
        if not holds or not r[col["Time (s)"]].strip():
            continue
        rpm, amps = r[col["Motor Electrical Speed (RPM)"]], r[col["Current (A)"]]
        holds[-1].append((esc, float(r[col["Time (s)"]]), float(rpm or "nan"), float(amps or "nan")))
    out = []
    for h in holds:
        a = np.array(h, dtype=float)
        settled = a[a[:, 1] >= a[0, 1] + (a[-1, 1] - a[0, 1]) / 3.0]
        out.append((a[0, 0], a[0, 1], float(np.nanmedian(settled[:, 2])) * 2.0 * math.pi / 60.0,
                    float(np.nanmedian(settled[:, 3]))))
    return out


def test_revisited_levels_are_the_logs_own_settled_medians(tmp_path):
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import bench_real

    import_csv(F80, tmp_path / "whole")
    got = {round(r["us"]): r for r in bench_real.revisited_levels(tmp_path / "whole", 3)}
    holds = csv_holds()
    top = max(range(len(holds)), key=lambda k: holds[k][0])
    up = {round(h[0]): h for h in holds[:top + 1] if h[2] > 0}
    down = {round(h[0]): h for h in holds[top + 1:] if h[2] > 0}
    assert set(got) == {us for us in set(up) & set(down) if us > 1000}  # 1300, 1500, 1700, 1900 us
    assert len(got) >= 3
    for us, r in got.items():
        for way, ref in (("up", up[us]), ("down", down[us])):
            assert r[way]["speed_rad_s"] == pytest.approx(ref[2], rel=0.01), (us, way)
            assert r[way]["current_a"] == pytest.approx(ref[3], rel=0.03, abs=0.1), (us, way)
        # the way down is slower at the same command (the log: 0.96-0.99 of the way up)
        assert r["down"]["speed_rad_s"] < r["up"]["speed_rad_s"]
    # each visit's test part, from its start time over the log's span (0-113.8 s, three parts)
    assert [got[us]["down"]["part"] for us in sorted(got)] == [2] * len(got)
    assert got[1500]["up"]["part"] == 1
