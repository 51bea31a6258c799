"""import-log: each flight-log format, written from the simulator, imported and checked against
the simulator's truth (commands, speeds after the unit conversions, voltage), the vehicle
namespaces, the mapping note that `info` prints, and the bad inputs (one-line errors)."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from _flightlog_writers import (
    RPM_PER_RAD_S,
    Vehicle,
    simulate_vehicle,
    write_betaflight_csv,
    write_dataflash,
    write_ulog,
)
from bldc_propulsion import cli
from bldc_propulsion.bagio import open_recording
from bldc_propulsion.errors import BadInputError, OutputExistsError
from bldc_propulsion.flightlogs import import_log
from bldc_propulsion.info import recording_info, summary_text
from bldc_propulsion.recordings import load_signals

MOTORS = [0, 1, 2, 3]
#: Half a quantum of each logged unit, in the contract's units (plus float32 rounding in bags).
DSHOT_HALF_STEP = 0.05 / 1999 / 2
ERPM_HALF_STEP_RAD_S = 100 / 7 / RPM_PER_RAD_S / 2  # eRPM/100 integers, 7 pole pairs
RPM_HALF_STEP_RAD_S = 0.5 / RPM_PER_RAD_S  # PX4's integer esc_rpm
CENTI_HALF_STEP = 0.005  # blackbox_decode writes volts and amperes with 2 decimals
FLOAT32 = 1e-5  # relative: BatteryState.voltage and the binary logs' floats are float32


@pytest.fixture(scope="module")
def vehicle() -> Vehicle:
    return simulate_vehicle()


def scalars(bag: Path, topic: str) -> tuple[np.ndarray, np.ndarray]:
    with open_recording(bag) as rec:
        if topic == "battery/voltage":
            return rec.battery_voltages()
        return rec.scalars(topic)


def check_vehicle(bag: Path, v: Vehicle, *, cmd_tol: float, speed_tol: float, volt_tol: float,
                  amp_tol: float) -> None:
    """Every motor's /motorN/pwm (50 Hz from t = 0) and /motorN/rotor/speed against the truth."""
    with open_recording(bag) as rec:
        assert set(rec.topics()) == {*(f"motor{m}/{t}" for m in MOTORS for t in ("pwm", "rotor/speed")),
                                     "battery/voltage", "battery/current", "import/source"}
    for m in MOTORS:
        t, pwm = scalars(bag, f"motor{m}/pwm")
        np.testing.assert_allclose(np.diff(t), 0.02, atol=1e-9)
        assert t[0] == 0.0
        np.testing.assert_allclose(pwm, v.command(m, t), rtol=0, atol=cmd_tol)
        assert pwm.max() > 0.06  # the motors ran: not a trivially stopped log
        t, speed = scalars(bag, f"motor{m}/rotor/speed")
        assert len(t) > 100 and speed.max() > 200.0
        np.testing.assert_allclose(speed, v.speed_at(m, t), rtol=0, atol=speed_tol)
    t, volts = scalars(bag, "battery/voltage")
    np.testing.assert_allclose(volts, v.voltage_at(t), rtol=FLOAT32, atol=volt_tol)
    assert np.ptp(volts) > 0.1  # the pack sags under load: the voltage is not a constant
    t, amps = scalars(bag, "battery/current")
    np.testing.assert_allclose(amps, v.current_at(t), rtol=FLOAT32, atol=amp_tol)


# --- the formats against the simulator's truth -------------------------------------------
def test_betaflight_csv_dshot_erpm_against_truth(tmp_path: Path, vehicle: Vehicle) -> None:
    src = write_betaflight_csv(tmp_path / "flight.csv", vehicle, pole_count=14)
    out = tmp_path / "flight.bag"
    info = import_log(src, out, pole_count=14)
    assert info["path"] == str(out) and info["format"] == "Betaflight CSV"
    assert info["motors"] == MOTORS and info["motor_protocol"] == "dshot"
    assert info["rows"] == 1499  # 500 Hz over the 3 s simulated: rows at 0 .. 2.996 s
    assert info["duration_s"] == pytest.approx(2.996)
    assert info["speed_source"] == "eRPM (electrical RPM / 100) x 100 / 7 pole pairs"
    assert info["warnings"] == [] and info["header_lines"] == 4
    check_vehicle(out, vehicle, cmd_tol=DSHOT_HALF_STEP + 1e-12, speed_tol=ERPM_HALF_STEP_RAD_S + 1e-9,
                  volt_tol=CENTI_HALF_STEP, amp_tol=CENTI_HALF_STEP + 1e-9)
    # the same log read with the wrong unit (pole count 2: eRPM taken as shaft RPM) is 7x too fast
    wrong = import_log(src, tmp_path / "wrong.bag", pole_count=2)
    assert wrong["speed_max_rad_s"]["motor1"] == pytest.approx(7 * info["speed_max_rad_s"]["motor1"])


def test_betaflight_csv_pwm_without_telemetry(tmp_path: Path, vehicle: Vehicle) -> None:
    src = write_betaflight_csv(tmp_path / "pwm.csv", vehicle, protocol="pwm", erpm=False,
                               explorer_header=False, rate_hz=250.0)
    info = import_log(src, tmp_path / "pwm.bag")
    assert info["motor_protocol"] == "pwm" and info["speed_source"] is None
    assert any("taken as PWM microseconds" in w for w in info["warnings"])
    assert any("no eRPM column" in w for w in info["warnings"])
    for m in MOTORS:
        t, pwm = scalars(tmp_path / "pwm.bag", f"motor{m}/pwm")
        np.testing.assert_allclose(pwm, np.round(vehicle.command(m, t) * 20000) / 20000, rtol=0, atol=1e-15)
    # the option overrides the values' verdict: 1000..2000 read as DShot is another (lower) level
    dshot = import_log(src, tmp_path / "forced.bag", motor_protocol="dshot")
    assert dshot["motor_protocol"] == "dshot" and dshot["motor_protocol_from"] == "--motor-protocol"


def test_ulog_actuator_motors_against_truth(tmp_path: Path, vehicle: Vehicle) -> None:
    src = write_ulog(tmp_path / "flight.ulg", vehicle)
    out = tmp_path / "flight.bag"
    info = import_log(src, out)
    assert info["format"] == "PX4 ULog" and info["command_topic"] == "actuator_motors"
    assert info["motors"] == MOTORS and info["rows"] == 299 and info["warnings"] == []
    assert info["mot_pole_count"] == 14
    assert info["speed_source"] == "esc_status esc_rpm (mechanical RPM)"
    # control[i] = (level - 0.05) / 0.05 as float32; NaN (disarmed before 0.5 s) -> 0.05
    check_vehicle(out, vehicle, cmd_tol=1e-8, speed_tol=RPM_HALF_STEP_RAD_S + 1e-9, volt_tol=1e-6, amp_tol=1e-5)


def test_ulog_actuator_outputs_in_microseconds(tmp_path: Path, vehicle: Vehicle) -> None:
    src = write_ulog(tmp_path / "outputs.ulg", vehicle, command_topic="actuator_outputs")
    out = tmp_path / "outputs.bag"
    info = import_log(src, out, motors="0,2")
    assert info["command_topic"] == "actuator_outputs" and info["motors"] == [0, 2]
    assert info["motors_with_speed"] == [0, 2]
    t, pwm = scalars(out, "motor2/pwm")
    np.testing.assert_allclose(pwm, np.round(vehicle.command(2, t) * 20000) / 20000, rtol=0, atol=1e-15)
    with open_recording(out) as rec:
        assert not rec.has("motor1/pwm")


def test_dataflash_against_truth(tmp_path: Path, vehicle: Vehicle) -> None:
    src = write_dataflash(tmp_path / "flight.bin", vehicle)
    out = tmp_path / "flight.bag"
    info = import_log(src, out)
    assert info["format"] == "ArduPilot DataFlash" and info["motors_from"] == "SERVOn_FUNCTION"
    # channel 5 pulses 1500 us all flight but is a servo (SERVO5_FUNCTION=1): not a motor
    assert info["motors"] == MOTORS and info["rows"] == 149 and info["warnings"] == []
    assert info["servo_blh_poles"] == 14
    check_vehicle(out, vehicle, cmd_tol=0.5 / 20000 + 1e-15, speed_tol=1e-3, volt_tol=1e-6, amp_tol=1e-5)
    # without SERVOn_FUNCTION every channel with a pulse is a motor, and the log says so
    bare = write_dataflash(tmp_path / "bare.bin", vehicle, servo_functions=False)
    info = import_log(bare, tmp_path / "bare.bag")
    assert info["motors"] == [0, 1, 2, 3, 4] and "no SERVOn_FUNCTION" in info["warnings"][0]


# --- the vehicle recording as the other commands read it ---------------------------------
def test_load_signals_reads_motor2_and_info_prints_the_mapping(tmp_path: Path, vehicle: Vehicle) -> None:
    src = write_betaflight_csv(tmp_path / "flight.csv", vehicle)
    out = tmp_path / "flight.bag"
    import_log(src, out, pole_count=14)
    sig = load_signals(out, namespace="motor2")
    assert sig.namespace == "motor2" and sig.speed_source == "rotor/speed (recorded)"
    np.testing.assert_allclose(sig.pwm, vehicle.command(2, sig.t), rtol=0, atol=DSHOT_HALF_STEP + 1e-12)
    assert not np.allclose(sig.pwm, vehicle.command(1, sig.t), atol=1e-3)  # motor 2's, not another's
    np.testing.assert_allclose(sig.speed, vehicle.speed_at(2, sig.t), rtol=0, atol=ERPM_HALF_STEP_RAD_S + 0.3)
    np.testing.assert_allclose(sig.voltage, vehicle.voltage_at(sig.t), rtol=0, atol=0.01)

    info = recording_info(str(out), "motor2")
    assert info["import_source"] == [
        "imported from Betaflight CSV flight.csv: motor[i] DShot 48-2047 -> pwm level 0.05-0.10 (below 48: "
        "stop, 0.05), held on 50 Hz frames; eRPM[i] (eRPM/100) x 100 / 7 pole pairs -> rotor/speed rad/s; "
        "vbatLatest (V) -> battery/voltage; amperageLatest (A) -> battery/current; motor[i] -> /motor<i>"]
    assert {"train", "evaluate", "discrepancy"} <= set(info["usable_for"])
    text = summary_text(info)
    assert "Source:           imported from Betaflight CSV flight.csv: motor[i] DShot 48-2047" in text


def test_cli_json_keys_and_info_text(tmp_path: Path, vehicle: Vehicle, capsys: pytest.CaptureFixture[str]) -> None:
    src = write_dataflash(tmp_path / "flight.bin", vehicle)
    out = tmp_path / "flight.mcap"
    assert cli.main(["import-log", str(src), "-o", str(out), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert {"path", "rows", "motors", "duration_s", "command_mapping", "speed_source", "warnings"} <= set(data)
    assert data["path"] == str(out) and data["motors"] == MOTORS
    assert data["command_mapping"].startswith("imported from ArduPilot DataFlash flight.bin: RCOU Cn us")
    assert cli.main(["info", str(out)]) == 0
    assert "Source:           imported from ArduPilot DataFlash flight.bin" in capsys.readouterr().out


def test_import_csv_states_its_mapping_too(tmp_path: Path) -> None:
    src = tmp_path / "stand.csv"
    src.write_text("Time (s),ESC signal (µs),Voltage (V),Motor Optical Speed (RPM)\n"
                   "0,1000,16.0,0\n0.5,1500,15.5,6000\n1.0,1500,15.4,6100\n", encoding="utf-8")
    from bldc_propulsion.training.import_csv import import_csv
    import_csv(src, tmp_path / "stand.bag")
    (note,) = recording_info(str(tmp_path / "stand.bag"))["import_source"]
    assert note.startswith("imported from RCbenchmark / Tyto CSV stand.csv: ESC command")


# --- bad input: one line naming the file or option; nothing written ----------------------
def _text(path: Path, text: str) -> Path:
    path.write_text(text, encoding="utf-8")
    return path


def _bbl(tmp: Path) -> Path:
    p = tmp / "LOG00001.bbl"
    p.write_bytes(b"H Product:Blackbox flight data recorder by Nicholas Sherlock\nH Data version:2\n\x00\x01")
    return p


BAD = {
    "eRPM without --pole-count": (lambda tmp, v: write_betaflight_csv(tmp / "log.csv", v), {},
                                  ["log.csv", "--pole-count", "electrical"]),
    "odd --pole-count": (lambda tmp, v: write_betaflight_csv(tmp / "log.csv", v), {"pole_count": 13},
                         ["--pole-count 13", "even"]),
    "binary .bbl": (lambda tmp, v: _bbl(tmp), {}, ["LOG00001.bbl", "blackbox_decode", "Blackbox Explorer"]),
    "empty motor columns": (lambda tmp, v: write_betaflight_csv(tmp / "log.csv", v, empty_motors=True),
                            {"pole_count": 14}, ["log.csv", "motor[0]", "hold no values"]),
    "unknown format": (lambda tmp, v: _text(tmp / "notes.txt", "a,b\n1,2\n"), {},
                       ["notes.txt", "cannot tell the log's format"]),
    "--format ulog on a CSV": (lambda tmp, v: write_betaflight_csv(tmp / "log.csv", v), {"fmt": "ulog"},
                               ["--format ulog", "log.csv"]),
    "--pole-count on a ULog": (lambda tmp, v: write_ulog(tmp / "log.ulg", v), {"pole_count": 14},
                               ["--pole-count 14", "mechanical"]),
    "--motor-protocol on a DataFlash log": (lambda tmp, v: write_dataflash(tmp / "log.bin", v),
                                            {"motor_protocol": "dshot"}, ["--motor-protocol dshot", "log.bin"]),
    "--motors not in the log": (lambda tmp, v: write_dataflash(tmp / "log.bin", v), {"motors": "0,7"},
                                ["--motors 0,7", "motor 7", "0,1,2,3"]),
    "DShot value beyond 2047": (lambda tmp, v: _text(tmp / "log.csv", "time (us), motor[0]\n0, 0\n1000, 2100\n"),
                                {"motor_protocol": "dshot"}, ["log.csv", "'motor[0]'", "2100", "DShot 0..2047"]),
    "PWM values read as pulses": (lambda tmp, v: write_betaflight_csv(tmp / "log.csv", v, erpm=False),
                                  {"motor_protocol": "pwm"}, ["log.csv", "motor[0]", "--motor-protocol dshot"]),
    "no such file": (lambda tmp, v: tmp / "missing.ulg", {}, ["missing.ulg", "no such file"]),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_input_is_one_line_naming_the_file_or_option(tmp_path: Path, vehicle: Vehicle, case: str) -> None:
    make, kwargs, needles = BAD[case]
    src = make(tmp_path, vehicle)
    out = tmp_path / "out.bag"
    with pytest.raises(BadInputError) as err:
        import_log(src, out, **kwargs)
    message = str(err.value)
    assert "\n" not in message
    for needle in needles:
        assert needle in message, (needle, message)
    assert not out.exists()


def test_output_exists_and_the_cli_exit_status(tmp_path: Path, vehicle: Vehicle,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    src = write_ulog(tmp_path / "flight.ulg", vehicle)
    out = tmp_path / "flight.bag"
    import_log(src, out)
    with pytest.raises(OutputExistsError, match="flight.bag: already exists .*--force"):
        import_log(src, out)
    import_log(src, out, force=True, motors=[1])  # --force replaces a recording
    with open_recording(out) as rec:
        assert rec.namespaces_with("pwm") == ["motor1"]
    capsys.readouterr()
    assert cli.main(["import-log", str(src), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "already exists" in err[0]
    assert cli.main(["import-log", str(_bbl(tmp_path)), "-o", str(tmp_path / "b.bag")]) == 2
    assert "blackbox_decode" in capsys.readouterr().err


def test_missing_pymavlink_names_the_extra(tmp_path: Path, vehicle: Vehicle, monkeypatch: pytest.MonkeyPatch) -> None:
    src = write_dataflash(tmp_path / "flight.bin", vehicle)
    monkeypatch.setitem(sys.modules, "pymavlink", None)  # import fails as if not installed
    with pytest.raises(BadInputError, match=r"flight.bin: .*pymavlink .*pip install bldc_propulsion\[ardupilot\]"):
        import_log(src, tmp_path / "out.bag")


def test_the_package_imports_no_pymavlink() -> None:
    """pymavlink is LGPL: only a DataFlash import may load it, never the package or the CLI."""
    code = ("import sys, bldc_propulsion.cli, bldc_propulsion.flightlogs\n"
            "assert not [m for m in sys.modules if m.startswith('pymavlink')]\n")
    subprocess.run([sys.executable, "-c", code], check=True, cwd=Path(__file__).resolve().parents[1])


def test_unit_helpers_hand_computed() -> None:
    from bldc_propulsion.flightlogs.common import dshot_to_level, erpm_hundreds_to_rad_s, normalized_to_level

    np.testing.assert_allclose(dshot_to_level([0, 47, 48, 1047.5, 2047]), [0.05, 0.05, 0.05, 0.075, 0.10])
    # 70 (eRPM/100) on a 14-pole motor: 7000 eRPM / 7 = 1000 shaft RPM
    assert erpm_hundreds_to_rad_s(70, 14) == pytest.approx(1000 * 2 * math.pi / 60)
    np.testing.assert_allclose(normalized_to_level([math.nan, -0.5, 0.0, 0.5, 1.0]), [0.05, 0.05, 0.05, 0.075, 0.10])
