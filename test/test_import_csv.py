"""RCbenchmark / Tyto CSV importer: hand-computed truth, the two real logs, bad input."""

from __future__ import annotations

import argparse
import csv
import math
from pathlib import Path

import numpy as np
import pytest

from bldc_propulsion.bagio import open_recording
from bldc_propulsion.errors import BadInputError, OutputExistsError
from bldc_propulsion.commands import import_csv as import_command
from bldc_propulsion.training.import_csv import import_csv

REAL = Path(__file__).resolve().parents[2] / "shared" / "real"
STEPS = REAL / "rcbenchmark_steps_90percent.csv"
COAST = REAL / "rcbenchmark_step_coastdown_16v_10in.csv"
RPM = 2.0 * math.pi / 60.0
G = 9.80665

HEADER = ("Time (s),ESC signal (µs),Voltage (V),Current (A),Thrust (kgf),"
          "Motor Electrical Speed (RPM),Motor Optical Speed (RPM),Extra (x),App message,")
# line numbers in comments count the header as line 1
SMALL_ROWS = [
    "0,1000,16.0,0.5,0.0,0,0,1,,",            # 2: kept (t=0)
    "0,1000,16.1,0.5,0.0,0,0,1,,",            # 3: same time: skipped
    "0.05,1200,15.9,,0.1,,600,1,,",           # 4: kept, current not recorded
    "0.1,1500,15.8,3.0,0.5,7000,6000,abc,,",  # 5: kept; the extra column is ignored
    "0.08,1600,15.0,9.0,0.9,9000,9000,1,,",   # 6: time goes backwards: skipped
    ",,,,,,,,Test started,",                  # 7: app message: skipped
    "0.13,1500,,3.1,,7100,6100,,,",           # 8: kept, voltage and thrust not recorded
]


def write_csv(path: Path, header: str = HEADER, rows: list[str] = SMALL_ROWS, bom: bool = True) -> Path:
    text = "\r\n".join([header, *rows]) + "\r\n"
    path.write_bytes(("\ufeff" if bom else "").encode() + text.encode("utf-8"))
    return path


def read(bag: Path, topic: str) -> tuple[np.ndarray, np.ndarray]:
    with open_recording(bag) as rec:
        if topic == "battery/voltage":
            return rec.battery_voltages()
        return rec.scalars(topic)


# --- hand-computed truth -----------------------------------------------------------------
def test_small_csv_against_hand_computed_truth(tmp_path: Path) -> None:
    src = write_csv(tmp_path / "log.csv")
    out = tmp_path / "log.bag"
    info = import_csv(src, out)
    assert info["path"] == str(out)
    assert info["rows"] == 4
    assert info["skipped_rows"] == 3
    assert info["skipped"] == {"no_time_or_esc": 1, "time_not_increasing": 2}
    assert info["duration_s"] == pytest.approx(0.13)
    assert info["speed_source"] == "optical"
    assert info["columns_used"]["thrust"] == "Thrust (kgf)"
    assert "Extra (x)" not in info["columns_used"].values()

    with open_recording(out) as rec:
        assert set(rec.topics()) == {"pwm", "battery/voltage", "rotor/speed", "thrust/measured",
                                     "battery/current"}
    # /pwm: 50 Hz frames from 0 to 0.13 s -> 0, 0.02, ..., 0.12; the command held from each row
    t, pwm = read(out, "pwm")
    np.testing.assert_allclose(t, np.arange(7) * 0.02, atol=1e-9)
    np.testing.assert_allclose(pwm, [0.05, 0.05, 0.05, 0.06, 0.06, 0.075, 0.075], rtol=0, atol=1e-15)
    # the frame at exactly 0.10 s sees the row logged at 0.10 s; 0.08 s still holds 1200 us
    assert pwm[5] == 1500 / 20000 and pwm[4] == 1200 / 20000

    t, v = read(out, "battery/voltage")
    np.testing.assert_allclose(t, [0.0, 0.05, 0.1], atol=1e-9)
    np.testing.assert_allclose(v, [16.0, 15.9, 15.8])
    t, w = read(out, "rotor/speed")
    np.testing.assert_allclose(t, [0.0, 0.05, 0.1, 0.13], atol=1e-9)
    np.testing.assert_allclose(w, np.array([0, 600, 6000, 6100]) * 2 * math.pi / 60)
    t, f = read(out, "thrust/measured")
    np.testing.assert_allclose(t, [0.0, 0.05, 0.1], atol=1e-9)
    np.testing.assert_allclose(f, np.array([0.0, 0.1, 0.5]) * G)
    t, i = read(out, "battery/current")
    np.testing.assert_allclose(t, [0.0, 0.1, 0.13], atol=1e-9)
    np.testing.assert_allclose(i, [0.5, 3.0, 3.1])


def test_electrical_speed_and_pole_pairs(tmp_path: Path) -> None:
    header = "Time (s),ESC signal (µs),Thrust (N),Motor Electrical Speed (RPM),Motor Optical Speed (RPM)"
    rows = ["0,1100,0.0,0,0", "0.5,1300,1.5,7000,0", "1.0,1300,1.6,7700,0"]
    src = write_csv(tmp_path / "e.csv", header, rows)
    info = import_csv(src, tmp_path / "a.bag")
    assert info["speed_source"] == "electrical" and info["pole_pairs"] is None
    assert "shaft RPM" in info["speed_assumption"]
    np.testing.assert_allclose(read(tmp_path / "a.bag", "rotor/speed")[1], np.array([0, 7000, 7700]) * RPM)
    np.testing.assert_allclose(read(tmp_path / "a.bag", "thrust/measured")[1], [0.0, 1.5, 1.6])

    info = import_csv(src, tmp_path / "b.bag", pole_pairs=7)
    assert info["speed_source"] == "electrical" and info["pole_pairs"] == 7
    assert "pole_pairs=7" in info["speed_assumption"]
    np.testing.assert_allclose(read(tmp_path / "b.bag", "rotor/speed")[1], np.array([0, 1000, 1100]) * RPM)
    # no voltage column: said so, not invented
    assert any("voltage" in w for w in info["warnings"])
    with open_recording(tmp_path / "b.bag") as rec:
        assert not rec.has("battery/voltage")


def test_output_is_reproducible_byte_for_byte(tmp_path: Path) -> None:
    src = write_csv(tmp_path / "log.csv")
    (tmp_path / "x").mkdir()
    (tmp_path / "y").mkdir()
    import_csv(src, tmp_path / "x" / "r.bag")
    import_csv(src, tmp_path / "y" / "r.bag")
    for name in ("metadata.yaml", "r.bag.mcap"):
        assert (tmp_path / "x" / "r.bag" / name).read_bytes() == (tmp_path / "y" / "r.bag" / name).read_bytes()


def test_existing_output_refused_and_untouched(tmp_path: Path) -> None:
    src = write_csv(tmp_path / "log.csv")
    out = tmp_path / "out.bag"
    out.mkdir()
    (out / "keep.txt").write_text("precious")
    with pytest.raises(OutputExistsError, match="out.bag"):
        import_csv(src, out)
    assert (out / "keep.txt").read_text() == "precious"
    with pytest.raises(BadInputError, match="not a recording"):  # --force replaces recordings only
        import_csv(src, out, force=True)
    assert (out / "keep.txt").read_text() == "precious"
    bag = tmp_path / "log_bag"
    import_csv(src, bag)
    info = import_csv(src, bag, force=True)
    assert info["rows"] == 4
    assert not list(tmp_path.glob(".*partial*"))


# --- command line --------------------------------------------------------------------------
def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="import-csv")
    import_command.add_arguments(p)
    p.set_defaults(run=import_command.run)
    return p


def test_command_arguments_and_result(tmp_path: Path) -> None:
    src = write_csv(tmp_path / "log.csv")
    args = _parser().parse_args([str(src), "-o", str(tmp_path / "c.bag")])
    assert args.pole_pairs is None and args.force is False
    result = args.run(args)
    assert result.data["path"] == str(tmp_path / "c.bag") and result.data["rows"] == 4
    assert "4 rows" in result.text
    args = _parser().parse_args([str(src), "--output", str(tmp_path / "c.bag"), "--pole-pairs", "6"])
    with pytest.raises(OutputExistsError):
        args.run(args)
    args = _parser().parse_args([str(src), "-o", str(tmp_path / "c.bag"), "--force", "--pole-pairs", "6"])
    assert args.run(args).data["pole_pairs"] == 6
    with pytest.raises(SystemExit):
        _parser().parse_args([str(src), "-o", "x", "--pole-pairs", "0"])
    with pytest.raises(SystemExit):
        _parser().parse_args([str(src)])  # -o is required


# --- bad input: one line naming the file ---------------------------------------------------
GOOD = ["0,1000,16", "0.5,1100,16"]
H3 = "Time (s),ESC signal (µs),Voltage (V)"


def _bad_cases(d: Path) -> list[tuple[str, Path, str]]:
    cases: list[tuple[str, Path, str]] = [
        ("missing", d / "nope.csv", "no such file"),
        ("directory", d, "directory"),
    ]
    binary = d / "bin.csv"
    binary.write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR" + bytes(range(256)))
    cases.append(("binary", binary, "binary"))
    latin = d / "latin.csv"
    latin.write_bytes(("Time (s),ESC signal (µs)\n0,1000\n1,1100\n").encode("latin-1"))
    cases.append(("not utf-8", latin, "UTF-8"))
    empty = d / "empty.csv"
    empty.write_bytes(b"\xef\xbb\xbf\r\n")
    cases.append(("empty", empty, "empty"))
    cases += [
        ("no time", write_csv(d / "notime.csv", "Seconds,ESC signal (µs)", ["0,1000", "1,1100"]),
         "no 'Time (s)' column"),
        ("no esc", write_csv(d / "noesc.csv", "Time (s),Throttle (%),Voltage (V)", ["0,10,16", "1,20,16"]),
         "'ESC signal (µs)'"),
        ("text", write_csv(d / "prose.csv", "hello world", ["this is not a log"]), "no 'Time (s)' column"),
        ("non-numeric", write_csv(d / "nonnum.csv", H3, [*GOOD, "1.0,1200,abc"]),
         "line 4, column 'Voltage (V)'"),
        ("non-numeric time", write_csv(d / "nonnumt.csv", H3, ["0,1000,16", "x1,1000,16"]),
         "line 3, column 'Time (s)'"),
        ("one row", write_csv(d / "one.csv", H3, ["0,1000,16"]), "at least 2"),
        ("same time", write_csv(d / "same.csv", H3, ["0,1000,16", "0,1100,16"]), "at least 2"),
        ("esc low", write_csv(d / "low.csv", H3, [*GOOD, "1,50,16"]), "line 4"),
        ("esc high", write_csv(d / "high.csv", H3, [*GOOD, "1,2500,16"]), "outside 800..2200"),
        ("nan", write_csv(d / "nan.csv", H3, [*GOOD, "1,1200,nan"]), "not finite"),
        ("inf", write_csv(d / "inf.csv", H3, [*GOOD, "inf,1200,16"]), "not finite"),
    ]
    return cases


def test_every_bad_input_is_one_line_naming_the_file(tmp_path: Path) -> None:
    src_dir = tmp_path / "in"
    src_dir.mkdir()
    for label, path, expected in _bad_cases(src_dir):
        out = tmp_path / f"{label.replace(' ', '_')}.bag"
        with pytest.raises(BadInputError) as err:
            import_csv(path, out)
        msg = str(err.value)
        assert str(path) in msg, label
        assert expected in msg, (label, msg)
        assert "\n" not in msg and "Traceback" not in msg, label
        assert not out.exists(), label


# --- the two real thrust-stand logs --------------------------------------------------------
def _csv_rows(path: Path) -> tuple[list[str], list[list[str]]]:
    with path.open(encoding="utf-8-sig", newline="") as fh:
        rows = list(csv.reader(fh))
    return rows[0], rows[1:]


def _reference_hold(t_rows: np.ndarray, esc: np.ndarray, frames: np.ndarray) -> np.ndarray:
    """Zero-order hold written out plainly: the last row at or before each frame."""
    out = []
    for tf in frames:
        k = 0
        for j, tr in enumerate(t_rows):
            if tr <= tf + 1e-9:
                k = j
        out.append(esc[k] / 20000.0)
    return np.asarray(out)


@pytest.mark.skipif(not STEPS.is_file(), reason=f"real log not available: {STEPS}")
def test_real_steps_log(tmp_path: Path) -> None:
    info = import_csv(STEPS, tmp_path / "steps.bag")
    header, rows = _csv_rows(STEPS)
    assert info["rows"] == len(rows) - 1 == 622  # two rows at Time 0: the second is skipped
    assert info["skipped"]["time_not_increasing"] == 1
    assert info["duration_s"] == pytest.approx(14.222355, abs=1e-6)
    assert info["speed_source"] == "electrical"  # the optical column is all zeros
    # the stand's own mechanical power = torque x this speed: the column is already shaft RPM
    assert info["speed_check_power_over_torque_ratio"] == pytest.approx(1.0, abs=1e-3)
    assert info["warnings"] == []

    t, pwm = read(tmp_path / "steps.bag", "pwm")
    assert sorted(set(np.round(pwm, 6))) == [0.0575, 0.0645, 0.0715, 0.0785, 0.0855]
    assert len(t) == int(14.222355 * 50) + 1
    np.testing.assert_allclose(np.diff(t), 0.02, atol=1e-8)
    ti, ei = header.index("Time (s)"), header.index("ESC signal (µs)")
    t_rows = np.array([float(r[ti]) for r in rows])
    esc = np.array([float(r[ei]) for r in rows])
    keep = np.r_[True, np.diff(t_rows) > 0]
    np.testing.assert_allclose(pwm, _reference_hold(t_rows[keep], esc[keep], t), atol=1e-15)

    tw, w = read(tmp_path / "steps.bag", "rotor/speed")
    assert len(w) == 622
    assert w.max() == pytest.approx(21240 * RPM)
    _, v = read(tmp_path / "steps.bag", "battery/voltage")
    assert 13.0 < v.min() < 14.0 and v.max() == pytest.approx(16.8, abs=0.01)  # sag under ~10 A
    tc, i = read(tmp_path / "steps.bag", "battery/current")
    assert 9.0 < np.median(i[tc > 12.5]) < 11.0  # ~10 A at 1710 us (the step itself peaks higher)


@pytest.mark.skipif(not COAST.is_file(), reason=f"real log not available: {COAST}")
def test_real_coastdown_log(tmp_path: Path) -> None:
    info = import_csv(COAST, tmp_path / "coast.bag")
    assert info["rows"] == 75 and info["skipped_rows"] == 0
    assert info["duration_s"] == pytest.approx(18.513783 - 0.112515, abs=1e-6)
    assert info["speed_source"] == "optical"
    assert info["thrust_unit_in_log"] == "kgf"

    t, pwm = read(tmp_path / "coast.bag", "pwm")
    assert sorted(set(np.round(pwm, 6))) == [0.05, 0.063, 0.0825]  # 1000, 1260, 1650 us
    header, rows = _csv_rows(COAST)
    thrust_kgf = np.array([float(r[header.index("Thrust (kgf)")]) for r in rows])
    _, f = read(tmp_path / "coast.bag", "thrust/measured")
    np.testing.assert_allclose(f, thrust_kgf * G)

    tw, w = read(tmp_path / "coast.bag", "rotor/speed")
    plateau = np.median(w[(tw > 10.0) & (tw < 13.0)])
    assert plateau == pytest.approx(8316 * RPM, rel=0.01)
    # the command returns to 1000 us (stop) at ~13.9 s after the bag start; no active braking:
    t_stop = t[np.nonzero(pwm > 0.05)[0][-1]]  # last frame before the stop command
    after = tw > t_stop
    assert np.all(np.diff(w[after][:8]) <= 20 * RPM)  # falling (the log is noisy by ~20 rpm)
    t_5pct = tw[after][np.nonzero(w[after] < 0.05 * plateau)[0][0]]
    assert t_5pct - t_stop > 1.5, "coast-down to 5 % takes seconds, not one ESC frame"
    assert w[after][0] > 0.5 * plateau
