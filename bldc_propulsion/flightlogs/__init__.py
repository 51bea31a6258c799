"""Flight-controller logs -> vehicle recordings (`bldc-propulsion import-log`).

Users have flight logs, not bench bags. One reader per format turns a log into a ``FlightLog``
in the contract's units, ``common.write_recording`` writes it with the quadrotor's namespaced
topics (``/motorN/pwm``, ``/motorN/rotor/speed``, ``/battery/voltage``, ``/battery/current``)
and the mapping it applied on ``/import/source``, which ``info`` prints:

| format | module | read with |
|---|---|---|
| ``betaflight-csv`` | betaflight.py | the csv module (the CSV blackbox_decode or Blackbox Explorer writes) |
| ``ulog`` | ulog.py | pyulog (BSD-3, extra ``px4``) |
| ``dataflash`` | dataflash.py | pymavlink (LGPL-3.0, optional extra ``ardupilot``, imported only there) |

The format is told by the file's first bytes (ULog and DataFlash magic, a CSV header with
``motor[0]``); binary Betaflight logs (.bbl/.bfl) are refused with the way to export them.
"""

from __future__ import annotations

import os
from pathlib import Path

from ..atomic import RECORDING, check_output
from ..errors import BadInputError
from . import betaflight, dataflash, ulog
from .common import ImportSummary, check_pole_count, parse_motors, summary_text, write_recording

FORMATS: dict[str, str] = {
    "betaflight-csv": betaflight.KIND,
    "ulog": ulog.KIND,
    "dataflash": dataflash.KIND,
}
#: How much of a file is looked at to tell its format (Explorer's header lines come first).
_SNIFF_BYTES = 256 * 1024
_BINARY_BETAFLIGHT_SUFFIXES = (".bbl", ".bfl")

__all__ = ["FORMATS", "detect_format", "import_log", "summary_text"]


def _head(path: Path) -> bytes:
    if not path.exists():
        raise BadInputError(f"{path}: no such file")
    if path.is_dir():
        raise BadInputError(f"{path}: is a directory, not a flight log")
    try:
        with open(path, "rb") as fh:
            return fh.read(_SNIFF_BYTES)
    except OSError as exc:
        raise BadInputError(f"{path}: cannot read ({exc.strerror or exc})") from None


def detect_format(path: str | os.PathLike[str], fmt: str | None = None) -> str:
    """The log's format name (a key of FORMATS): ``fmt`` checked against the file's first bytes,
    or guessed from them; BadInputError naming the file when it is none of them."""
    src = Path(path)
    if fmt is not None and fmt not in FORMATS:
        raise BadInputError(f"--format {fmt}: unknown format (one of {', '.join(FORMATS)})")
    head = _head(src)
    if betaflight.is_blackbox_binary(head) or src.suffix.lower() in _BINARY_BETAFLIGHT_SUFFIXES:
        raise BadInputError(f"{src}: {betaflight.BBL_REFUSAL}")
    if not head:
        raise BadInputError(f"{src}: file is empty")
    found = ("ulog" if head.startswith(ulog.MAGIC) else
             "dataflash" if head.startswith(dataflash.MAGIC) else
             "betaflight-csv" if betaflight.looks_like_csv(head) else None)
    if fmt is None:
        if found is None:
            raise BadInputError(f"{src}: cannot tell the log's format: not a PX4 ULog, an ArduPilot "
                                "DataFlash .bin or a Betaflight blackbox CSV (give --format if it is one)")
        return found
    if fmt == "ulog" and found != "ulog":
        raise BadInputError(f"--format ulog: {src} does not start as a ULog file does (ULog magic)")
    if fmt == "dataflash" and found != "dataflash":
        raise BadInputError(f"--format dataflash: {src} does not start as a DataFlash .bin does (0xA3 0x95)")
    if fmt == "betaflight-csv" and found in ("ulog", "dataflash"):
        raise BadInputError(f"--format betaflight-csv: {src} is a {FORMATS[found]} log (give --format {found})")
    return fmt


def import_log(
    log_path: str | os.PathLike[str],
    out_path: str | os.PathLike[str],
    *,
    fmt: str | None = None,
    pole_count: int | None = None,
    motors: str | list[int] | None = None,
    motor_protocol: str | None = None,
    force: bool = False,
) -> ImportSummary:
    """Convert a flight log into a vehicle recording at ``out_path``; returns the summary
    (``path``, ``rows``, ``motors``, ``duration_s``, ``command_mapping``, ``speed_source``,
    ``warnings`` and more). ``pole_count`` is the motor's magnet poles (Betaflight eRPM needs
    it), ``motors`` the log's motor indices to import (default: every motor with a command),
    ``motor_protocol`` ('dshot' or 'pwm') overrides how Betaflight motor values are read.
    Raises BadInputError (one line naming the file or option) on bad input and when
    ``out_path`` may not be written; nothing is written then."""
    src, out = Path(log_path), Path(out_path)
    pole_count = check_pole_count(pole_count)
    wanted = parse_motors(motors) if isinstance(motors, str) else (None if motors is None else list(motors))
    check_output(out, RECORDING, force=force, inputs=[src])
    kind = detect_format(src, fmt)
    if kind == "betaflight-csv":
        log = betaflight.read_betaflight_csv(src, pole_count=pole_count, motors=wanted,
                                             motor_protocol=motor_protocol)
    else:
        if motor_protocol is not None:
            raise BadInputError(f"--motor-protocol {motor_protocol}: only for Betaflight CSV logs "
                                f"({src} is a {FORMATS[kind]} log, whose commands say their own units)")
        reader = ulog.read_ulog if kind == "ulog" else dataflash.read_dataflash
        log = reader(src, pole_count=pole_count, motors=wanted)
    return write_recording(log, out, force=force)
