"""Recordings that exercise every branch of ``replay``, and an exact comparison of two replays.

Used by test/test_replay_fast.py (the fast path against the reference path, message by
message) and by benchmarks/compare_replay.py (one code version against another).
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import numpy as np

from bldc_propulsion import contract as c
from bldc_propulsion.bagio import BagWriter, open_recording
from bldc_propulsion.sim import simulate
from bldc_propulsion.sim.record import _streams, write_sim_bag


def _write(path: Path, streams, storage: str = "mcap") -> None:
    """Streams [(topic, times, values)] in time order (stable: stream order on ties)."""
    rows = [(float(t[i]), k, i) for k, (_, t, _) in enumerate(streams) for i in range(len(t))]
    rows.sort(key=lambda r: (r[0], r[1]))
    with BagWriter(path, storage=storage) as bag:
        for t, k, i in rows:
            topic, _, values = streams[k]
            if c.bare(topic).endswith(c.TOPIC_TACH_ADC):
                bag.write_float32_array(topic, t, values[i])
            elif c.bare(topic).endswith(c.TOPIC_BATTERY_VOLTAGE):
                bag.write_battery_state(topic, t, float(values[i]))
            else:
                bag.write_float64(topic, t, float(values[i]))


def _faulty(res) -> list:
    """The recording with dropped tachometer batches, NaN samples, a battery gap, out-of-range
    and repeated battery samples, a tachometer batch stamped back in time."""
    out = []
    for topic, t, values in _streams(res):
        t = np.array(t, dtype=float)
        values = np.array(values, dtype=np.float32 if topic == c.TOPIC_TACH_ADC else float)
        keep = np.ones(len(t), dtype=bool)
        if topic == c.TOPIC_TACH_ADC:
            keep[150:153] = False  # three dropped batches
            keep[400:430] = False  # 0.3 s without batches
            values[250, 17] = np.nan  # one NaN sample
            values[260, :] = np.nan  # a whole batch of NaN
            values[261, 190:] = np.inf
            values[300, 5] = 1e6  # not an ADC reading
            t[500] = t[498]  # stamped back in time: rejected
        elif topic == c.TOPIC_BATTERY_ADC:
            keep[3000:3800] = False  # 0.8 s gap: the filter restarts
            values[1000] = np.nan
            values[1500:1505] = 50.0  # out of range
            t[2000] = t[1999]  # not later than the previous sample
            t[2500] = t[2500] + 0.0004  # an irregular step
        elif topic == c.TOPIC_PWM:
            keep[100:110] = False
        out.append((topic, t[keep], values[keep]))
    return out


def build_corpus(root: Path, duration_s: float = 8.0) -> dict[str, Path]:
    """name -> recording; each a few seconds of simulated bench."""
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    bags: dict[str, Path] = {}
    for k, profile in enumerate(("staircase", "chirp", "random_steps")):
        bags[profile] = root / profile
        write_sim_bag(simulate(profile, duration_s, seed=30 + k), bags[profile])
    res = simulate("random_steps", duration_s, seed=40, soc=0.5)
    bags["sqlite3"] = root / "sqlite3"
    write_sim_bag(res, bags["sqlite3"], storage="sqlite3")
    bags["single_file.mcap"] = root / "single_file.mcap"
    write_sim_bag(res, bags["single_file.mcap"])
    bags["faults"] = root / "faults"
    _write(bags["faults"], _faulty(res))
    bags["faults_sqlite3"] = root / "faults_sqlite3"
    _write(bags["faults_sqlite3"], _faulty(res), storage="sqlite3")
    # an imported thrust-stand log carries battery/voltage (BatteryState) and no battery/adc
    streams = _streams(res)
    volts = [(c.TOPIC_BATTERY_VOLTAGE, res.battery_t[::50], 2.0 * res.battery_adc[::50])]
    bags["voltage"] = root / "voltage"
    _write(bags["voltage"], [s for s in streams if s[0] != c.TOPIC_BATTERY_ADC] + volts)
    bags["voltage_and_adc"] = root / "voltage_and_adc"
    _write(bags["voltage_and_adc"], streams + volts)
    # a vehicle: motor topics under /motor0 and /motor1, the pack at the root
    other = simulate("chirp", duration_s, seed=41)
    vehicle = [s for s in streams if s[0] == c.TOPIC_BATTERY_ADC]
    for m, run in enumerate((res, other)):
        vehicle += [(f"motor{m}/{topic}", t, v) for topic, t, v in _streams(run)
                    if topic != c.TOPIC_BATTERY_ADC and not topic.startswith(c.TRUTH_PREFIX)]
    bags["vehicle"] = root / "vehicle"
    _write(bags["vehicle"], vehicle)
    # no tachometer; tachometer only
    bags["no_tach"] = root / "no_tach"
    _write(bags["no_tach"], [s for s in streams if s[0] != c.TOPIC_TACH_ADC])
    bags["tach_only"] = root / "tach_only"
    _write(bags["tach_only"], [s for s in streams if s[0] == c.TOPIC_TACH_ADC])
    # a chunk damaged in the middle of the recording: the bulk path gives way to the reference
    bags["corrupt_chunk"] = root / "corrupt_chunk.mcap"
    write_sim_bag(simulate("random_steps", 2.5 * duration_s, seed=42), bags["corrupt_chunk"])
    data = bytearray(bags["corrupt_chunk"].read_bytes())
    with open_recording(bags["corrupt_chunk"]) as rec:
        chunks = rec._reader.storage.chunks
        assert len(chunks) >= 3
        mid = chunks[1].chunk_start_offset + chunks[1].chunk_length // 2
    data[mid:mid + 64] = bytes(b ^ 0xFF for b in data[mid:mid + 64])
    bags["corrupt_chunk"].write_bytes(bytes(data))
    # a truncated MCAP (replay keeps the readable part)
    src = next(bags["random_steps"].glob("*.mcap"))
    data = src.read_bytes()
    bags["truncated.mcap"] = root / "truncated.mcap"
    bags["truncated.mcap"].write_bytes(data[: int(len(data) * 0.8)])
    return bags


#: (name, replay keyword arguments) of the cases the corpus is replayed with
CASES: list[tuple[str, dict[str, Any]]] = [
    ("staircase", {}), ("chirp", {}), ("random_steps", {}), ("sqlite3", {}),
    ("single_file.mcap", {}), ("faults", {}), ("faults_sqlite3", {}), ("voltage", {}),
    ("voltage_and_adc", {}), ("vehicle", {"namespace": "motor1"}), ("no_tach", {}),
    ("tach_only", {}), ("truncated.mcap", {}), ("corrupt_chunk", {}),
]


def output_messages(path: Path) -> dict[str, list[tuple[int, bytes]]]:
    """Every message of a recording: topic -> [(bag time ns, raw CDR)] in bag order."""
    out: dict[str, list[tuple[int, bytes]]] = {}
    with open_recording(path) as rec:
        for name, ns, _, data in rec.raw(list(rec.topics())):
            out.setdefault(name, []).append((ns, bytes(data)))
    return out


def differences(a: Path, b: Path, info_a: dict, info_b: dict) -> list[str]:
    """What differs between two replays (outputs a/b, summaries): [] when identical."""
    diffs = []
    ma, mb = output_messages(a), output_messages(b)
    if sorted(ma) != sorted(mb):
        diffs.append(f"topics {sorted(ma)} != {sorted(mb)}")
    for topic in sorted(set(ma) & set(mb)):
        if len(ma[topic]) != len(mb[topic]):
            diffs.append(f"{topic}: {len(ma[topic])} != {len(mb[topic])} messages")
        # a length difference is reported above; the common prefix is compared message by message
        for k, (x, y) in enumerate(zip(ma[topic], mb[topic], strict=False)):
            if x != y:
                diffs.append(f"{topic}: message {k} differs ({x[0]} vs {y[0]})")
                break
    ia = {k: v for k, v in info_a.items() if k != "path"}
    ib = {k: v for k, v in info_b.items() if k != "path"}
    if repr(ia) != repr(ib):
        diffs.append(f"summary differs: {ia} != {ib}")
    return diffs


def copy_tree(src: Path, dst: Path) -> None:
    if src.is_dir():
        shutil.copytree(src, dst)
    else:
        shutil.copy2(src, dst)
