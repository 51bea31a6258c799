"""The one place that reads and writes rosbag2 recordings (MCAP and SQLite3), via ``rosbags``.

Times handed to and from this module are float seconds relative to the recording's first
message (``Recording.t0_ns``), so that 20 kHz sample times keep their precision; absolute
nanoseconds are only used inside the bag. Everything streams: a recording is never loaded
whole unless a caller asks for a whole topic.

Two fast paths, for replay: ``Recording.bulk`` / ``bulk_windows`` read several topics a window
at a time as arrays, in exactly the order and with exactly the values ``Recording.messages``
gives (MCAP chunks read through their message indexes; SQLite3 through rosbags' own query),
and ``BagWriter`` appends MCAP message records itself, making the bytes rosbags' writer makes.
Both fall back on rosbags where they cannot be sure (see each docstring; tests compare them).
"""

from __future__ import annotations

import contextlib
import math
import os
import struct
import types
from collections import defaultdict
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from io import BytesIO
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any, BinaryIO, Protocol, TypeAlias, cast

import numpy as np
from rosbags.rosbag2 import Reader, Writer
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode, StoragePlugin
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.stores.ros2_jazzy import builtin_interfaces__msg__Time as TimeMsg
from rosbags.typesys.stores.ros2_jazzy import diagnostic_msgs__msg__DiagnosticArray as DiagnosticArrayMsg
from rosbags.typesys.stores.ros2_jazzy import diagnostic_msgs__msg__DiagnosticStatus as DiagnosticStatusMsg
from rosbags.typesys.stores.ros2_jazzy import diagnostic_msgs__msg__KeyValue as KeyValueMsg
from rosbags.typesys.stores.ros2_jazzy import sensor_msgs__msg__BatteryState as BatteryStateMsg
from rosbags.typesys.stores.ros2_jazzy import std_msgs__msg__Float32MultiArray as Float32MultiArrayMsg
from rosbags.typesys.stores.ros2_jazzy import std_msgs__msg__Float64MultiArray as Float64MultiArrayMsg
from rosbags.typesys.stores.ros2_jazzy import std_msgs__msg__Header as HeaderMsg
from rosbags.typesys.stores.ros2_jazzy import std_msgs__msg__MultiArrayDimension as MultiArrayDimensionMsg
from rosbags.typesys.stores.ros2_jazzy import std_msgs__msg__MultiArrayLayout as MultiArrayLayoutMsg

from . import contract as c
from .atomic import RECORDING, RECORDING_MARK, atomic_output, recording_custom_data
from .errors import BagError, one_line
from .specs import split_spec

if TYPE_CHECKING:
    from mcap.records import Message as McapMessage
    from numpy.typing import NDArray
    from rosbags.interfaces import Connection
    from rosbags.rosbag2.storage_mcap import McapReader, McapWriter

    from .core.status import CoreStatus
    from .sim.faults import Fault

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
_CDR_LE = b"\x00\x01\x00\x00"  # CDR encapsulation header, little endian
_FLOAT64 = struct.Struct("<d")

#: Start of simulated recordings: a fixed, plausible wall-clock epoch so that bags look like
#: real ones to ``ros2 bag play`` and stay byte-for-byte reproducible.
SIM_EPOCH_NS = 1_767_225_600 * 10**9  # 2026-01-01T00:00:00Z

STRING = "std_msgs/msg/String"
#: Added topic (not in the contract's tables): one String at the start of an imported recording
#: saying where it came from and how the log's units were mapped, so that ``info`` can show it.
TOPIC_IMPORT_SOURCE = "import/source"


def _slash(topic: str) -> str:
    return topic if topic.startswith("/") else "/" + topic


def is_recording(path: str | os.PathLike[str]) -> bool:
    """True for a rosbag2 directory (with metadata.yaml) or a single .mcap/.db3 file."""
    p = Path(path)
    return (p.is_dir() and (p / "metadata.yaml").is_file()) or (
        p.is_file() and p.suffix in (".mcap", ".db3")
    )


#: Largest SQLite3 recording :meth:`Recording.bulk_windows` reads at once (MCAP goes by windows).
BULK_SQLITE_MAX_BYTES = 512 * 2**20

#: Topics one vehicle shares between its motors (one pack, one battery filter): with a
#: namespace they are read from it when it has them, else from the root (interfaces.md).
SHARED_TOPICS: tuple[str, ...] = (c.TOPIC_BATTERY_ADC, c.TOPIC_BATTERY_VOLTAGE, "battery/current")
#: A motor's own topics: a vehicle's recording has them under the motors' namespaces only.
MOTOR_TOPICS: tuple[str, ...] = (c.TOPIC_PWM, c.TOPIC_TACH_ADC)
#: Most topic names a missing-topic message lists.
_LIST_TOPICS = 12


def vehicle_topic(topic: str, namespace: str | None) -> str:
    """Where a quadrotor records or publishes ``topic`` of the motor ``namespace``
    (interfaces.md, "A quadrotor"): the pack's topics at the root, the rest under the motor."""
    name = c.bare(topic)
    return name if namespace is None or name in SHARED_TOPICS else f"{namespace}/{name}"


def check_namespace(namespace: str | None) -> str | None:
    """``motor0``, ``/motor0`` or ``motor0/`` -> ``motor0``; None or '' -> None (the root)."""
    if namespace is None:
        return None
    ns = namespace.strip().strip("/")
    if not ns:
        return None
    if any(not part or not (part[0].isalpha() or part[0] == "_")
           or not all(ch.isalnum() or ch == "_" for ch in part) for part in ns.split("/")):
        raise BagError(f"--namespace {namespace}: not a ROS namespace (letters, digits, _ and /, "
                       "each part starting with a letter)")
    return ns


class _Typed(Protocol):
    """A connection's message type: all that decoding a message needs."""

    @property
    def msgtype(self) -> str: ...


#: A connection as Recording reads it: rosbags' own, or a salvaged MCAP file's channel.
_ReadConn: TypeAlias = "Connection | _SalvageConn"
#: One topic's messages as Recording.bulk decodes them: the values of Float64 or BatteryState
#: messages, or the samples of each Float32MultiArray.
BulkValues: TypeAlias = "NDArray[np.float64] | list[NDArray[np.float32]]"


class Recording:
    """A rosbag2 recording opened for streaming reads; use as a context manager.

    With ``namespace`` (one motor of a vehicle's recording, e.g. ``motor0``) every topic a
    caller names (``pwm``) is read from the namespace (``/motor0/pwm``), the battery topics
    from the namespace if present there, else from the root; callers keep using the contract's
    names, and ``raw``/``messages`` report those names.
    """

    def __init__(self, path: str | os.PathLike[str], namespace: str | None = None) -> None:
        self.path = Path(path)
        self.namespace = check_namespace(namespace)
        if not self.path.exists():
            raise BagError(f"{self.path}: no such recording")
        if self.path.is_dir() and not (self.path / "metadata.yaml").is_file():
            raise BagError(f"{self.path}: not a rosbag2 directory (metadata.yaml is missing)")
        if self.path.is_file() and self.path.suffix not in (".mcap", ".db3"):
            raise BagError(f"{self.path}: not a recording (expected a bag directory or .mcap file)")
        #: set when a tolerant read stopped early on a damaged part of the recording
        self.read_error: str | None = None
        #: set when the recording could only be opened by scanning it (truncated MCAP)
        self.salvaged: str | None = None
        try:
            self._reader: Reader | _SalvageReader = Reader(self.path)
            self._reader.open()
        except Exception as exc:  # rosbags raises many types for corrupt input
            reason = one_line(exc)
            salvage = _SalvageReader.open(self.path)
            if salvage is None:
                raise BagError(f"{self.path}: cannot open recording ({reason})") from None
            self._reader = salvage
            self.salvaged = (f"{self.path}: recording is damaged ({reason}); readable part "
                             f"ends after {salvage.readable_s:.3f} s ({salvage.why})")
        conns = self._reader.connections
        self._conns: dict[str, list[_ReadConn]] = {}
        for conn in conns:
            self._conns.setdefault(c.bare(conn.topic), []).append(conn)
        self.t0_ns: int = int(self._reader.start_time) if self._reader.message_count else 0
        self.end_ns: int = int(self._reader.end_time) if self._reader.message_count else 0

    # -- context manager -------------------------------------------------------------------
    def __enter__(self) -> Recording:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self._reader.close()

    # -- what is in it ---------------------------------------------------------------------
    @property
    def duration_s(self) -> float:
        return max(0.0, (self.end_ns - self.t0_ns) * 1e-9)

    @property
    def message_count(self) -> int:
        return int(self._reader.message_count)

    def topics(self) -> dict[str, str]:
        """Every topic of the recording (without leading slash, whatever the namespace) -> type."""
        return {name: conns[0].msgtype for name, conns in self._conns.items()}

    def resolve(self, topic: str) -> str:
        """The recording's name (bare) of a contract topic, under this recording's namespace."""
        name = c.bare(topic)
        if self.namespace is None:
            return name
        inside = f"{self.namespace}/{name}"
        if inside not in self._conns and name in SHARED_TOPICS and name in self._conns:
            return name
        return inside

    def namespaces_with(self, topic: str) -> list[str]:
        """Namespaces under which the recording has ``topic`` (e.g. ['motor0', 'motor1'])."""
        name = c.bare(topic)
        return sorted(t[: -len(name) - 1] for t in self._conns if t.endswith("/" + name))

    def motors_elsewhere(self) -> list[str]:
        """The namespaces that hold the motor topics when this recording's level (the root, or
        the namespace given) has none of them: a vehicle's recording read without the right
        --namespace; [] otherwise."""
        if any(self.has(t) for t in MOTOR_TOPICS):
            return []
        return sorted({ns for t in MOTOR_TOPICS for ns in self.namespaces_with(t)} - {self.namespace or ""})

    def missing_error(self, topics: Sequence[str]) -> BagError:
        """BagError for contract topics of which none is recorded: names them (as looked up),
        lists what the recording has, and suggests --namespace when they are under one."""
        names = [f"/{self.resolve(t)}" for t in topics]
        what = (f"topic {names[0]} is missing" if len(names) == 1 else
                f"neither {names[0]} nor {names[1]} is recorded" if len(names) == 2 else
                f"none of the input topics ({', '.join(names)}) is recorded")
        have = sorted(f"/{t}" for t in self._conns)
        listed = ", ".join(have[:_LIST_TOPICS]) + (f", ... ({len(have)} topics)" if len(have) > _LIST_TOPICS else "")
        hint = ""
        spaces = sorted({ns for t in topics for ns in self.namespaces_with(t)} - {self.namespace or ""})
        if spaces:
            hint = (f"; it has {c.bare(topics[0])} under namespace(s) {', '.join(spaces)}: "
                    f"give --namespace {spaces[0]}")
        return BagError(f"{self.path}: {what} (the recording has {listed or 'no topics'}){hint}")

    def count(self, topic: str) -> int:
        return sum(conn.msgcount for conn in self._conns.get(self.resolve(topic), []))

    def has(self, topic: str, msgtype: str | None = None) -> bool:
        conns = self._conns.get(self.resolve(topic), [])
        return bool(conns) and (msgtype is None or conns[0].msgtype == msgtype)

    def require(self, topic: str, msgtype: str) -> list[_ReadConn]:
        """Connections of ``topic``; BagError naming the file and topic if absent or mistyped."""
        name = self.resolve(topic)
        conns = self._conns.get(name)
        if not conns:
            raise self.missing_error([topic])
        found = {conn.msgtype for conn in conns}
        if found != {msgtype}:
            raise BagError(
                f"{self.path}: topic /{name} has type {', '.join(sorted(found))}, expected {msgtype}"
            )
        return conns

    # -- streaming -------------------------------------------------------------------------
    def raw(self, topics: Iterable[str], tolerant: bool = False) -> Iterator[tuple[str, int, _ReadConn, bytes]]:
        """(bare topic, bag time ns, connection, raw CDR) in bag-time order.

        With ``tolerant`` a damaged part ends the stream and is recorded in ``read_error``
        instead of raising, so that callers can keep what was readable.
        """
        logical = {self.resolve(t): c.bare(t) for t in topics}
        conns = [conn for name in logical for conn in self._conns.get(name, [])]
        if not conns:
            return
        # each reader is only ever given its own connections (rosbags' Reader: Connection)
        it: Iterator[tuple[_ReadConn, int, bytes]] = self._reader.messages(connections=conns)  # type: ignore[arg-type]
        if self.salvaged is not None and not tolerant:
            # a truncated recording is only good for tolerant readers (replay): a model
            # trained or evaluated on part of a file must not pass for the whole file
            raise BagError(self.salvaged)
        while True:
            try:
                conn, ns, data = next(it)
            except StopIteration:
                if self.salvaged is not None:
                    self.read_error = self.salvaged
                return
            except Exception as exc:
                msg = f"{self.path}: recording is damaged after {self._done_s(conns)} ({one_line(exc)})"
                if tolerant:
                    self.read_error = msg
                    return
                raise BagError(msg) from None
            self._last_ns = ns
            bare = c.bare(conn.topic)
            yield logical.get(bare, bare), ns, conn, data

    def bulk(self, topics: Sequence[str], start_ns: int | None = None, stop_ns: int | None = None
             ) -> Bulk | None:
        """Every message of ``topics`` at once, in the order :meth:`raw` yields them, decoded
        to arrays (Float64 -> its ``data``, BatteryState -> its ``voltage``, Float32MultiArray
        -> a float32 array per message); None when only :meth:`raw` can read the recording
        exactly (damaged or salvaged, split into several files, compressed per message,
        unchunked MCAP, another message type): the caller then streams with :meth:`messages`.
        With ``start_ns``/``stop_ns``, only the messages of bag times in [start_ns, stop_ns)
        (MCAP only: an SQLite3 recording is read whole, else None).

        MCAP: the chunks rosbags' reader would read (the same chunk selection and time bounds,
        decompressed and CRC-checked by rosbags' own ``decompress``), their messages located
        through the chunks' message index records (the MCAP specification has one per channel
        and chunk) and ordered as rosbags' merge orders them: by time, then chunk offset, then
        position in the chunk. SQLite3: the rows of rosbags' own query. Decoding matches
        :meth:`_decode` value for value.
        """
        if self.salvaged is not None:
            return None
        names = [self.resolve(t) for t in topics]
        logical = [c.bare(t) for t in topics]
        conns = [conn for name in names for conn in self._conns.get(name, [])]
        kinds = {conn.msgtype for conn in conns}
        if not conns or not kinds <= {c.FLOAT64, c.FLOAT32_ARRAY, c.BATTERY_STATE}:
            return None
        code_of_topic = {f"/{name}": k for k, name in enumerate(names)}
        try:
            # not salvaged (checked above): the reader is rosbags' own
            rows = _bulk_rows(cast(Reader, self._reader), conns, code_of_topic, start_ns, stop_ns)
        except Exception:  # anything unexpected: the streaming path decides what it means
            return None
        if rows is None:
            return None
        code, ns, payload = rows
        values: dict[str, BulkValues] = {}
        for k, (name, topic) in enumerate(zip(names, logical, strict=True)):
            sel = np.flatnonzero(code == k)
            msgtype = self._conns[name][0].msgtype if name in self._conns else c.FLOAT64
            values[topic] = self._decode_bulk(payload, sel, msgtype, name)
        return Bulk(topics=logical, code=code, ns=ns, values=values)

    def bulk_windows(self, topics: Sequence[str], window_s: float) -> Iterator[Bulk | None]:
        """:meth:`bulk` over successive windows of ``window_s`` of bag time (MCAP; SQLite3 in one
        window if its file is under BULK_SQLITE_MAX_BYTES), so memory stays bounded whatever
        the recording's length. A None means that from there on only :meth:`messages` reads
        the recording exactly (the caller starts again with it)."""
        files = [self.path] if self.path.is_file() else [*self.path.glob("*.mcap"), *self.path.glob("*.db3")]
        if any(f.suffix == ".db3" for f in files):
            if sum(f.stat().st_size for f in files) > BULK_SQLITE_MAX_BYTES:
                yield None
                return
            yield self.bulk(topics)
            return
        step = max(1, int(window_s * 1e9))
        start = self.t0_ns
        while True:
            stop = start + step
            last = stop >= self.end_ns
            yield self.bulk(topics, start, None if last else stop)
            if last:
                return
            start = stop

    def _decode_bulk(self, payload: _Payload, sel: np.ndarray, msgtype: str, name: str) -> BulkValues:
        """Messages ``sel`` of ``payload``, decoded as :meth:`_decode` decodes them."""
        start, length = payload.start[sel], payload.length[sel]
        n = len(sel)
        if msgtype == c.FLOAT64:
            vals = np.zeros(n)
            ok = length == 12
            if ok.any():
                head = payload.gather(start[ok], 12)
                good = (head[:, :4] == np.frombuffer(_CDR_LE, dtype=np.uint8)).all(axis=1)
                vals[np.flatnonzero(ok)[good]] = head[good, 4:].copy().view("<f8").reshape(-1)
                ok[np.flatnonzero(ok)[~good]] = False
            for i in np.flatnonzero(~ok).tolist():
                vals[i] = float(self._decode(payload.bytes(start[i], length[i]), _Conn(msgtype), name).data)
            return vals
        if msgtype == c.BATTERY_STATE:
            return np.array([float(self._decode(payload.bytes(a, m), _Conn(msgtype), name).voltage)
                             for a, m in zip(start.tolist(), length.tolist(), strict=True)])
        # Float32MultiArray without layout dims: a 16-byte head (CDR header, 0 dims,
        # data_offset, count), then the floats; anything else through the typestore
        out: list[np.ndarray] = []
        if n == 0:
            return out
        head = payload.gather(start, 16, min_length=length)
        count = head[:, 12:16].copy().view("<u4").reshape(-1).astype(np.int64)
        plain = ((head[:, :8] == np.frombuffer(_CDR_LE + bytes(4), dtype=np.uint8)).all(axis=1)
                 & (length == 16 + 4 * count))
        raw = payload.raw
        for a, m, k, ok in zip(start.tolist(), length.tolist(), count.tolist(), plain.tolist(), strict=True):
            if ok:
                out.append(np.frombuffer(raw, dtype="<f4", count=k, offset=a + 16))
            else:
                out.append(np.asarray(self._decode(payload.bytes(a, m), _Conn(msgtype), name).data))
        return out

    def topic_stats(self) -> list[TopicStats]:
        """Per topic of the recording (all namespaces): type, messages, rate and gaps, from the
        message times alone (nothing decoded; a damaged part ends the scan, see read_error)."""
        times: dict[str, list[int]] = {name: [] for name in self._conns}
        saved, self.namespace = self.namespace, None  # every topic under its own name
        try:
            for name, ns, _, _ in self.raw(list(self._conns), tolerant=True):
                times[name].append(ns)
        finally:
            self.namespace = saved
        out = []
        for name, ts in sorted(times.items()):
            t = (np.asarray(ts, dtype=np.int64) - self.t0_ns) * 1e-9
            dt = np.diff(t)
            span = float(t[-1] - t[0]) if len(t) > 1 else 0.0
            big = pauses(t)
            out.append(TopicStats(
                topic="/" + name, msgtype=self._conns[name][0].msgtype, count=len(t),
                first_s=float(t[0]) if len(t) else math.nan, last_s=float(t[-1]) if len(t) else math.nan,
                rate_hz=(len(t) - 1) / span if span > 0 else math.nan,
                gaps=int(np.count_nonzero(big)), max_gap_s=float(dt.max()) if len(dt) else math.nan))
        return out

    def _done_s(self, conns: list[_ReadConn]) -> str:
        ns = getattr(self, "_last_ns", None)
        return "the start" if ns is None else f"{(ns - self.t0_ns) * 1e-9:.3f} s"

    def messages(self, topics: Iterable[str], tolerant: bool = False) -> Iterator[tuple[str, float, Any]]:
        """(bare topic, t [s from t0], decoded message) in time order. The message is whatever
        rosbags' typestore decodes (or a ``_Float64``): callers read its fields by name."""
        for name, ns, conn, data in self.raw(topics, tolerant=tolerant):
            yield name, (ns - self.t0_ns) * 1e-9, self._decode(data, conn, name)

    def _decode(self, data: bytes, conn: _Typed, name: str) -> Any:  # a rosbags message
        if conn.msgtype == c.FLOAT64 and len(data) == 12 and data[:4] == _CDR_LE:
            return _Float64(_FLOAT64.unpack_from(data, 4)[0])  # fast path: 12-byte CDR
        try:
            return TYPESTORE.deserialize_cdr(data, conn.msgtype)
        except Exception as exc:
            raise BagError(f"{self.path}: topic /{name}: cannot decode {conn.msgtype} ({one_line(exc)})") from None

    def scalars(self, topic: str) -> tuple[np.ndarray, np.ndarray]:
        """Whole Float64 topic as (t [s], value) arrays."""
        self.require(topic, c.FLOAT64)
        t, v = [], []
        for _, ts, msg in self.messages([topic]):
            t.append(ts)
            v.append(msg.data)
        return np.asarray(t, dtype=float), np.asarray(v, dtype=float)

    def battery_voltages(self, topic: str = c.TOPIC_BATTERY_VOLTAGE) -> tuple[np.ndarray, np.ndarray]:
        """Whole BatteryState topic as (t [s], voltage): bag time, as the node publishes it."""
        self.require(topic, c.BATTERY_STATE)
        t, v = [], []
        for _, ts, msg in self.messages([topic]):
            t.append(ts)
            v.append(msg.voltage)
        return np.asarray(t, dtype=float), np.asarray(v, dtype=float)

    def tachometer(self, topic: str = c.TOPIC_TACH_ADC) -> Iterator[tuple[float, np.ndarray]]:
        """Stream of (t of the batch's last sample [s], float32 samples)."""
        self.require(topic, c.FLOAT32_ARRAY)
        for _, ts, msg in self.messages([topic]):
            yield ts, np.asarray(msg.data, dtype=np.float32)

    def texts(self, topic: str) -> list[str]:
        """Every String of ``topic`` at the recording's root, whatever the namespace (notes such
        as TOPIC_IMPORT_SOURCE); [] when it is not recorded as String."""
        saved, self.namespace = self.namespace, None
        try:
            if not self.has(topic, STRING):
                return []
            return [str(msg.data) for _, _, msg in self.messages([topic])]
        finally:
            self.namespace = saved

    @property
    def faults(self) -> list[Fault]:
        """The faults the simulator injected into this recording, by onset (its rosbag2
        custom_data ``faults``): the truth a health monitor is judged against; [] when there
        were none or another tool wrote the recording."""
        from .sim.faults import FAULTS_KEY, parse_faults  # late: the simulator imports scipy

        text = recording_custom_data(self.path).get(FAULTS_KEY) or ""
        return parse_faults(str(text), f"{self.path}: metadata custom_data {FAULTS_KEY}:")


@dataclass
class Bulk:
    """Messages of several topics read at once (:meth:`Recording.bulk`), in stream order."""

    topics: list[str]  #: contract names; message k is of topic ``topics[code[k]]``
    code: np.ndarray  #: (n,) int, topic index of each message
    ns: np.ndarray  #: (n,) int64, bag time of each message
    #: per topic, its messages decoded in order (see Recording.bulk); each reader (replay) narrows
    #: it to the form it knows the topic's type gives
    values: dict[str, BulkValues]


@dataclass
class _Conn:
    msgtype: str


_UINT32 = struct.Struct("<I")


@dataclass
class _Payload:
    """Raw CDR of many messages: message k is ``raw[start[k]:start[k] + length[k]]``."""

    raw: bytes
    start: np.ndarray
    length: np.ndarray

    def bytes(self, start: int, length: int) -> bytes:
        return self.raw[start:start + length]

    def gather(self, start: np.ndarray, width: int, min_length: np.ndarray | None = None) -> np.ndarray:
        """(len(start), width) uint8: the first ``width`` bytes of each message (zeros past
        the end of a message shorter than that, when ``min_length`` gives the lengths)."""
        u8 = np.frombuffer(self.raw, dtype=np.uint8)
        idx = start[:, None] + np.arange(width)
        if min_length is None:
            return u8[idx]
        inside = np.arange(width) < min_length[:, None]
        return np.where(inside, u8[np.where(inside, idx, 0)], 0).astype(np.uint8)


def _bulk_rows(reader: Reader, conns: list[_ReadConn], code_of_topic: dict[str, int],
               start_ns: int | None = None, stop_ns: int | None = None
               ) -> tuple[np.ndarray, np.ndarray, _Payload] | None:
    """(topic code, bag time ns, raw CDR) of every message of ``conns``, in the order rosbags'
    ``Reader.messages`` yields them; None where that order or content cannot be reproduced."""
    from rosbags.rosbag2.reader import DirectoryReader
    from rosbags.rosbag2.storage_mcap import McapReader
    from rosbags.rosbag2.storage_sqlite3 import Sqlite3Reader

    storage = reader.storage
    if isinstance(storage, DirectoryReader):
        if storage.metadata.compression_mode or len(storage.storages) != 1:
            return None
        storage = storage.storages[0]
    want = {(conn.topic, conn.msgtype) for conn in conns}
    ids = {x.id: code_of_topic[x.topic] for x in storage.connections if (x.topic, x.msgtype) in want}
    if not ids:
        return None
    if isinstance(storage, Sqlite3Reader):
        if start_ns is not None or stop_ns is not None:
            return None  # equal timestamps: only the whole query's order is rosbags' order
        by_id = {x.id: x for x in storage.connections}
        rows = list(storage.messages([by_id[i] for i in ids]))
        code = np.fromiter((ids[conn.id] for conn, _, _ in rows), dtype=np.int64, count=len(rows))
        ns = np.fromiter((t for _, t, _ in rows), dtype=np.int64, count=len(rows))
        length = np.fromiter((len(d) for _, _, d in rows), dtype=np.int64, count=len(rows))
        start = np.concatenate(([0], np.cumsum(length)[:-1])) if len(rows) else length
        return code, ns, _Payload(b"".join(d for _, _, d in rows), start, length)
    if not isinstance(storage, McapReader) or not storage.chunks:
        return None
    return _mcap_rows(storage, ids, start_ns, stop_ns)


def _mcap_rows(storage: McapReader, ids: dict[int, int], start_ns: int | None, stop_ns: int | None
               ) -> tuple[np.ndarray, np.ndarray, _Payload] | None:
    from rosbags.rosbag2.storage_mcap import decompress

    bio = cast("BinaryIO", storage.bio)  # the reader is open: its file is
    bufs: list[bytes] = []
    parts: list[tuple[np.ndarray, ...]] = []
    base = 0
    for chunk in storage.chunks:
        if not any(chunk.channel_count.get(cid, 0) for cid in ids):
            continue  # rosbags skips chunks whose index lists none of the channels
        if ((start_ns is not None and chunk.message_end_time < start_ns)
                or (stop_ns is not None and chunk.message_start_time >= stop_ns)):
            continue  # outside the window
        bio.seek(chunk.chunk_start_offset + 9 + 24)
        (crc,) = _UINT32.unpack(bio.read(4))
        bio.seek(chunk.chunk_start_offset + 9 + 40 + len(chunk.compression))
        compressed = bio.read(chunk.compressed_size)
        if len(compressed) != chunk.compressed_size:
            return None
        buf = decompress(compressed, chunk.compression, chunk.uncompressed_size, crc)
        index_at = chunk.chunk_start_offset + chunk.chunk_length
        bio.seek(index_at)
        index = bio.read(chunk.message_index_length)
        u8 = np.frombuffer(buf, dtype=np.uint8)
        for cid, code in ids.items():
            where = chunk.message_index_offsets.get(cid)
            if where is None:
                continue
            at = where - index_at
            op, _, rec_cid, nbytes = struct.unpack_from("<BQHI", index, at)
            if op != 0x07 or rec_cid != cid or nbytes % 16:
                return None
            pairs = np.frombuffer(index, dtype="<u8", count=nbytes // 8, offset=at + 15).reshape(-1, 2)
            t, off = pairs[:, 0].astype(np.int64), pairs[:, 1].astype(np.int64)
            if len(off) and (off.max() + 31 > len(buf)):
                return None
            head = u8[off[:, None] + np.arange(31)]
            size = head[:, 1:9].copy().view("<u8").reshape(-1).astype(np.int64)
            if not ((head[:, 0] == 0x05).all() and (size >= 22).all()
                    and (head[:, 9:11].copy().view("<u2").reshape(-1) == cid).all()
                    and (head[:, 23:31].copy().view("<u8").reshape(-1).astype(np.int64) == t).all()
                    and (off + 9 + size <= len(buf)).all()):
                return None  # the index does not point at this channel's messages
            keep = (t >= chunk.message_start_time) & (t < chunk.message_end_time + 1)
            if start_ns is not None:
                keep &= t >= start_ns
            if stop_ns is not None:
                keep &= t < stop_ns
            t, off, size = t[keep], off[keep], size[keep]
            parts.append((t, np.full(len(t), chunk.chunk_start_offset, dtype=np.int64), off,
                          np.full(len(t), code, dtype=np.int64), base + off + 31, size - 22))
        bufs.append(buf)
        base += len(buf)
    if not parts:
        none = np.zeros(0, dtype=np.int64)
        return none, none, _Payload(b"", none, none)
    t, chunk_off, off, codes, start, length = (np.concatenate(p) for p in zip(*parts, strict=True))
    # rosbags: each chunk sorted by time (stable, file order), chunks merged on (time, chunk offset)
    order = np.lexsort((off, chunk_off, t))
    return codes[order], t[order], _Payload(b"".join(bufs), start[order], length[order])


#: A pause between two messages of one topic counts as a gap when it is longer than
#: GAP_FACTOR x the topic's median period and MIN_GAP_S (PWM is sent on change: 50 Hz typical).
GAP_FACTOR = 5.0
MIN_GAP_S = 0.1


def pauses(t: np.ndarray, min_gap_s: float = MIN_GAP_S) -> np.ndarray:
    """Per interval of the sorted times ``t``: True where it is a gap, longer than GAP_FACTOR x
    the median interval and ``min_gap_s`` (``topic_stats``' gaps; ``recordings.speed_gaps``'
    with a floor of its own for a decoded speed)."""
    dt = np.diff(t)
    if not len(dt):
        return np.zeros(0, dtype=bool)
    return dt > max(GAP_FACTOR * float(np.median(dt)), min_gap_s)


@dataclass
class TopicStats:
    """What ``ros2 bag info`` says of one topic, plus gaps (times in s from the recording start)."""

    topic: str
    msgtype: str
    count: int
    first_s: float
    last_s: float
    rate_hz: float  #: mean message rate between the first and last message
    gaps: int  #: pauses longer than GAP_FACTOR x the median period (and MIN_GAP_S)
    max_gap_s: float  #: longest pause between two messages


@dataclass
class _SalvageConn:
    """The parts of a rosbags Connection that Recording uses."""

    id: int
    topic: str
    msgtype: str
    msgcount: int = 0


class _SalvageReader:
    """Sequential reader of an MCAP file whose summary/footer is missing (truncated).

    rosbags needs the footer and summary; the records before the damage are still readable
    in file order with the ``mcap`` stream reader. ``open`` scans the file once (channels,
    counts, times, where the readable part ends) and returns None if it is not MCAP or
    nothing is readable; ``messages`` scans it again, in file order, up to the damage.
    """

    def __init__(self, file: Path) -> None:
        self.file = file
        self.connections: list[_SalvageConn] = []
        self.message_count = 0
        self.start_time = 0
        self.end_time = 0
        self.why = "file ends"

    @classmethod
    def open(cls, path: Path) -> _SalvageReader | None:
        if path.is_dir():
            files = sorted(path.glob("*.mcap"))
            if len(files) != 1:
                return None
            path = files[0]
        if path.suffix != ".mcap" or not path.is_file():
            return None
        self = cls(path)
        by_id: dict[int, _SalvageConn] = {}
        try:
            for rec, _ in self._scan(by_id):
                conn = by_id.get(rec.channel_id)
                if conn is None:
                    continue
                conn.msgcount += 1
                t = int(rec.log_time)
                self.start_time = t if self.message_count == 0 else min(self.start_time, t)
                self.end_time = max(self.end_time, t)
                self.message_count += 1
        except Exception:
            return None
        if self.message_count == 0:
            return None
        self.connections = [c_ for c_ in by_id.values() if c_.msgcount]
        return self

    @property
    def readable_s(self) -> float:
        return (self.end_time - self.start_time) * 1e-9

    def _scan(self, by_id: dict[int, _SalvageConn]) -> Iterator[tuple[McapMessage, None]]:
        from mcap.records import Channel, Message, Schema
        from mcap.stream_reader import StreamReader

        schemas: dict[int, str] = {}
        with open(self.file, "rb") as fh:
            records = StreamReader(fh, validate_crcs=True).records
            while True:
                try:
                    rec = next(records)
                except StopIteration:
                    return
                except Exception as exc:  # the damage: stop here, remember why
                    cut = isinstance(exc, (EOFError, struct.error)) or type(exc).__name__ == "EndOfFile"
                    self.why = "the file is cut short" if cut else one_line(exc)
                    return
                if isinstance(rec, Schema):
                    schemas[rec.id] = rec.name
                elif isinstance(rec, Channel):
                    if rec.id not in by_id:
                        by_id[rec.id] = _SalvageConn(rec.id, rec.topic, schemas.get(rec.schema_id, ""))
                elif isinstance(rec, Message):
                    yield rec, None

    def messages(self, connections: Iterable[_ReadConn]) -> Iterator[tuple[_ReadConn, int, bytes]]:
        wanted = {conn.id: conn for conn in connections}
        by_id = {conn.id: _SalvageConn(conn.id, conn.topic, conn.msgtype) for conn in self.connections}
        for rec, _ in self._scan(by_id):
            conn = wanted.get(rec.channel_id)
            if conn is not None:
                yield conn, int(rec.log_time), bytes(rec.data)

    def close(self) -> None:
        pass


@dataclass
class _Float64:
    """What the fast path decodes a std_msgs/Float64 into (same attribute as the real one)."""

    data: float


def open_recording(path: str | os.PathLike[str], namespace: str | None = None) -> Recording:
    """Open a rosbag2 directory (MCAP or SQLite3) or a single .mcap file for reading; with
    ``namespace``, one motor of a vehicle's recording (see Recording); ``PATH@NS`` names the
    motor in the path itself (specs.py) and wins over ``namespace``."""
    return Recording(*split_spec(path, namespace))


class BagWriter:
    """Write a rosbag2 recording atomically (staged, renamed when closed without error).

    MCAP with zstd chunk compression by default (what ``ros2 bag record`` writes in Jazzy,
    compressed so that 20 kHz tachometer data stays small); ``storage='sqlite3'`` for the
    older format. Times are seconds relative to ``t0_ns``. ``custom_data`` goes into the
    rosbag2 metadata beside the recording mark (the simulator's faults: ``Recording.faults``).
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        force: bool = False,
        t0_ns: int = SIM_EPOCH_NS,
        storage: str = "mcap",
        custom_data: Mapping[str, str] | None = None,
    ) -> None:
        if storage not in ("mcap", "sqlite3"):
            raise BagError(f"{path}: unknown storage {storage!r} (mcap or sqlite3)")
        self.path = Path(path)
        self.force = force
        self.t0_ns = int(t0_ns)
        self.storage = storage
        self.custom_data = dict(custom_data or {})
        self._conns: dict[str, Connection] = {}
        self._stage: contextlib.AbstractContextManager[Path] | None = None
        self._writer: Writer | None = None
        self.messages_written = 0
        #: append MCAP message records directly (the bytes rosbags' McapWriter.write makes,
        #: tested) instead of through Writer.write: 10x less time per message
        self.fast_mcap = True
        self._mcap: McapWriter | None = None
        self._by_topic: dict[tuple[str, str], Connection] = {}

    @property
    def single_file(self) -> bool:
        """``path`` ends in .mcap: write one MCAP file there, not a bag directory."""
        return self.path.suffix.lower() == ".mcap"

    def __enter__(self) -> BagWriter:
        if self.single_file and self.storage != "mcap":
            raise BagError(f"{self.path}: a single .mcap file cannot hold {self.storage} storage "
                           "(give a directory name)")
        self._stage = atomic_output(self.path, force=self.force, kind=RECORDING)
        tmp = self._stage.__enter__()
        try:
            plugin = StoragePlugin.MCAP if self.storage == "mcap" else StoragePlugin.SQLITE3
            # a single .mcap is written as a bag directory beside the staged name, then moved
            self._tmp = tmp
            self._bag_dir = tmp.with_name(tmp.stem + ".bag") if self.single_file else tmp
            self._writer = Writer(self._bag_dir, version=9, storage_plugin=plugin)
            self._writer.set_custom_data(*RECORDING_MARK)  # what lets --force replace it later
            for key, value in self.custom_data.items():
                self._writer.set_custom_data(key, value)
            if self.storage == "mcap":
                self._writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
            self._writer.open()
            self._mcap = _fast_mcap(self._writer) if self.fast_mcap else None
        except BaseException as exc:
            self._stage.__exit__(type(exc), exc, exc.__traceback__)
            raise
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> bool | None:
        assert self._stage is not None and self._writer is not None
        try:
            self._writer.close()
        except Exception as close_exc:
            if exc is None:
                exc_type, exc, tb = type(close_exc), close_exc, close_exc.__traceback__
        if exc is None and self.single_file:
            try:
                (mcap,) = self._bag_dir.glob("*.mcap")
                os.replace(mcap, self._tmp)
            except BaseException as move_exc:
                exc_type, exc, tb = type(move_exc), move_exc, move_exc.__traceback__
        result = self._stage.__exit__(exc_type, exc, tb)
        if exc is not None and exc_type is not None and not result:
            if exc_type.__module__.startswith("rosbags"):
                raise BagError(f"{self.path}: cannot write recording ({one_line(exc)})") from None
        return result

    def _conn(self, topic: str, msgtype: str) -> Connection:
        name = c.bare(topic)
        conn = self._conns.get(name)
        if conn is None:
            assert self._writer is not None, "BagWriter used outside its with-block"
            conn = self._writer.add_connection(_slash(name), msgtype, typestore=TYPESTORE)
            self._conns[name] = conn
        elif conn.msgtype != msgtype:
            raise BagError(f"{self.path}: topic /{name} already written as {conn.msgtype}")
        return conn

    def _ns(self, t: float) -> int:
        return self.t0_ns + int(round(t * 1e9))

    def _connection(self, topic: str, msgtype: str) -> Connection:
        conn = self._by_topic.get((topic, msgtype))
        if conn is None:
            conn = self._by_topic[(topic, msgtype)] = self._conn(topic, msgtype)
        return conn

    def write_raw(self, topic: str, msgtype: str, t: float, data: bytes) -> None:
        assert self._writer is not None
        conn = self._connection(topic, msgtype)
        if self._mcap is None:
            self._writer.write(conn, self._ns(t), data)
            self.messages_written += 1
            return
        ts = self.t0_ns + int(round(t * 1e9))
        self._append(conn.id, ts, _MCAP_MESSAGE.pack(0x05, 22 + len(data), conn.id, 0, ts, ts) + data)

    def _append(self, cid: int, ts: int, record: bytes) -> None:
        """What Writer.write and McapWriter.write do (rosbags 0.11) with a message record made
        by the caller, without their checks (the connection is this writer's own)."""
        self.messages_written += 1
        w, st = self._writer, self._mcap
        assert w is not None and st is not None, "called only while the writer is open, on the fast path"
        w.counts[cid] += 1
        if ts < w.min_timestamp:
            w.min_timestamp = ts
        if ts > w.max_timestamp:
            w.max_timestamp = ts
        if ts < st.message_start_time:
            st.message_start_time = ts
        if ts > st.message_end_time:
            st.message_end_time = ts
        st.channel_stats[cid] += 1
        chunk = st.chunk
        if ts < chunk.message_start_time:
            chunk.message_start_time = ts
        if ts > chunk.message_end_time:
            chunk.message_end_time = ts
        bio = chunk.bio
        at = bio.tell()
        chunk.msgs[cid].append((ts, at))
        bio.write(record)
        if at + len(record) > 2**20:
            st.close_chunk()

    def write_msg(self, topic: str, msgtype: str, t: float, msg: object) -> None:
        self.write_raw(topic, msgtype, t, bytes(TYPESTORE.serialize_cdr(msg, msgtype)))

    def write_float64(self, topic: str, t: float, value: float) -> None:
        # 12-byte CDR written directly: the same bytes serialize_cdr makes (tested), 10x faster.
        if self._mcap is None:
            self.write_raw(topic, c.FLOAT64, t, _CDR_LE + _FLOAT64.pack(float(value)))
            return
        cid = self._connection(topic, c.FLOAT64).id
        ts = self.t0_ns + int(round(t * 1e9))
        self._append(cid, ts, _MCAP_FLOAT64.pack(0x05, 34, cid, 0, ts, ts, _CDR_LE, float(value)))

    def write_float32_array(self, topic: str, t: float, samples: np.ndarray) -> None:
        msg = _multiarray(np.asarray(samples, dtype=np.float32))
        self.write_msg(topic, c.FLOAT32_ARRAY, t, msg)

    def write_float64_array(self, topic: str, t: float, values: Sequence[float], label: str) -> None:
        """A Float64MultiArray of ``values`` with one layout dimension named ``label`` (what the
        values are, e.g. comma-joined names): a few named numbers in one message."""
        msg = named_values(values, label)
        self.write_msg(topic, c.FLOAT64_ARRAY, t, msg)

    def write_battery_state(self, topic: str, t: float, voltage: float) -> None:
        ns = self._ns(t)
        self.write_raw(topic, c.BATTERY_STATE, t, _BATTERY_TEMPLATE.bytes(ns // 10**9, ns % 10**9, voltage))

    def write_diagnostics(self, topic: str, t: float, statuses: Iterable[CoreStatus], prefix: str = "",
                          hardware_id: str = "") -> None:
        self.write_msg(topic, c.DIAGNOSTIC_ARRAY, t, diagnostic_array(self._ns(t), statuses, prefix, hardware_id))

    def write_string(self, topic: str, t: float, text: str) -> None:
        self.write_msg(topic, STRING, t, TYPESTORE.types[STRING](data=str(text)))

    def write_import_source(self, text: str, t: float = 0.0) -> None:
        """The note of an imported recording (TOPIC_IMPORT_SOURCE): where it came from and how
        the log's units became the contract's, written once at its first time ``t``."""
        self.write_string(TOPIC_IMPORT_SOURCE, t, text)

    def write_merged(self, streams: Sequence[tuple[str, np.ndarray, np.ndarray]]) -> None:
        """Scalar streams (topic, times s, values) in message-time order, as a recorder writes them
        (at equal times in the order of ``streams``): ``battery/voltage`` as BatteryState, the rest
        as Float64. What the importers write from a log's columns."""
        streams = [s for s in streams if len(s[1])]
        if not streams:
            return
        times = np.concatenate([s[1] for s in streams])
        which = np.concatenate([np.full(len(s[1]), k) for k, s in enumerate(streams)])
        index = np.concatenate([np.arange(len(s[1])) for s in streams])
        for k in np.lexsort((which, times)):
            topic, ts, vs = streams[which[k]]
            i = index[k]
            if c.bare(topic) == c.TOPIC_BATTERY_VOLTAGE:
                self.write_battery_state(topic, float(ts[i]), float(vs[i]))
            else:
                self.write_float64(topic, float(ts[i]), float(vs[i]))


_MCAP_MESSAGE = struct.Struct("<BQHIQQ")  # opcode, record length, channel, sequence, log/publish time
_MCAP_FLOAT64 = struct.Struct("<BQHIQQ4sd")  # the same, then a std_msgs/Float64's 12 bytes of CDR


def _fast_mcap(writer: Writer) -> McapWriter | None:
    """rosbags' MCAP storage writer, if its message writing is the one BagWriter.write_raw repeats."""
    try:
        from rosbags.rosbag2.storage_mcap import McapWriter
    except ImportError:
        return None
    storage = getattr(writer, "storage", None)
    if (type(storage) is not McapWriter or writer.compression_mode == CompressionMode.MESSAGE
            or not all(hasattr(storage, a) for a in ("chunk", "channel_stats", "message_start_time",
                                                      "message_end_time", "close_chunk"))
            or not all(hasattr(writer, a) for a in ("counts", "min_timestamp", "max_timestamp"))):
        return None
    # a method replaced at run time (an assignment would be mypy method-assign)
    setattr(storage, "close_chunk", types.MethodType(_close_chunk, storage))  # noqa: B010
    return storage


def _close_chunk(self: McapWriter) -> None:
    """``McapWriter.close_chunk`` (rosbags 0.11) with each message index record packed by numpy
    instead of two Python calls per message (the same bytes: test_bagio compares the files)."""
    from rosbags.rosbag2.storage_mcap import PendingChunk, write_record, write_string

    chunk = self.chunk
    size = chunk.bio.tell()
    compressed = self.compressor(chunk.bio.getvalue())
    rec = BytesIO()
    rec.write(struct.pack("<QQQI", chunk.message_start_time, chunk.message_end_time, size, 0))
    write_string(rec, self.compression)
    rec.write(struct.pack("<Q", len(compressed)))
    rec.write(compressed)
    chunk_start = self.bio.tell()
    write_record(self.bio, 0x06, rec)
    chunk_end = self.bio.tell()
    offsets: list[tuple[int, int]] = []
    for cid, msgs in chunk.msgs.items():
        offsets.append((cid, self.bio.tell()))
        index = np.asarray(msgs, dtype="<u8").reshape(-1).tobytes()
        self.bio.write(struct.pack("<BQHI", 0x07, 6 + len(index), cid, len(index)))
        self.bio.write(index)
    rec = BytesIO()
    rec.write(struct.pack("<QQQQI", chunk.message_start_time, chunk.message_end_time, chunk_start,
                          chunk_end - chunk_start, len(offsets) * 10))
    for cid, offset in offsets:
        rec.write(struct.pack("<HQ", cid, offset))
    rec.write(struct.pack("<Q", self.bio.tell() - chunk_end))
    write_string(rec, self.compression)
    rec.write(struct.pack("<QQ", len(compressed), size))
    self.chunks.append(rec)
    self.chunk = PendingChunk(2**63 - 1, 0, BytesIO(), defaultdict(list))


# --- message construction (Jazzy definitions through the rosbags typestore) ---------------
# (the classes are TYPESTORE's own, imported by name so that they are typed)
def _stamp(ns: int) -> TimeMsg:
    return TimeMsg(sec=ns // 10**9, nanosec=ns % 10**9)


def _header(ns: int, frame_id: str = "") -> HeaderMsg:
    return HeaderMsg(stamp=_stamp(ns), frame_id=frame_id)


def _multiarray(samples: np.ndarray) -> Float32MultiArrayMsg:
    layout = MultiArrayLayoutMsg(dim=[], data_offset=0)
    return Float32MultiArrayMsg(layout=layout, data=samples)


def named_values(values: Sequence[float], label: str) -> Float64MultiArrayMsg:
    """Float64MultiArray of ``values``: one dimension labelled ``label``, of their count."""
    data = np.asarray(values, dtype=np.float64)
    dim = MultiArrayDimensionMsg(label=label, size=len(data), stride=len(data))
    return Float64MultiArrayMsg(layout=MultiArrayLayoutMsg(dim=[dim], data_offset=0), data=data)


def battery_state(ns: int, voltage: float) -> BatteryStateMsg:
    """BatteryState with the filtered voltage; unknown fields NaN as the message docs ask."""
    BS = BatteryStateMsg  # TYPESTORE's own class, imported by name so that its constants are typed
    nan = math.nan
    return BS(
        header=_header(ns),
        voltage=float(voltage),
        temperature=nan,
        current=nan,
        charge=nan,
        capacity=nan,
        design_capacity=nan,
        percentage=nan,
        power_supply_status=BS.POWER_SUPPLY_STATUS_UNKNOWN,
        power_supply_health=BS.POWER_SUPPLY_HEALTH_UNKNOWN,
        power_supply_technology=BS.POWER_SUPPLY_TECHNOLOGY_LIPO,
        present=True,
        cell_voltage=np.zeros(0, dtype=np.float32),
        cell_temperature=np.zeros(0, dtype=np.float32),
        location="",
        serial_number="",
    )


class _Template:
    """CDR bytes of a message serialised once, with a few fields patched in per message.

    Serialising a BatteryState through the typestore costs ~25 us; replay writes one per 1 kHz
    battery sample, so the fields that change (stamp, voltage) are patched into a template
    instead (the bytes are checked against the typestore's in the tests).
    """

    _SEC, _NSEC, _VOLT = 0x5EC5EC01, 0x0A5EC0DE, 1234.5678

    def __init__(self) -> None:
        ns = self._SEC * 10**9 + self._NSEC
        raw = bytes(TYPESTORE.serialize_cdr(battery_state(ns, self._VOLT), c.BATTERY_STATE))
        self.raw = raw
        self.off_sec = raw.index(struct.pack("<i", self._SEC))
        self.off_nsec = raw.index(struct.pack("<I", self._NSEC))
        self.off_volt = raw.index(struct.pack("<f", self._VOLT))

    def bytes(self, sec: int, nanosec: int, voltage: float) -> bytes:
        buf = bytearray(self.raw)
        struct.pack_into("<i", buf, self.off_sec, sec)
        struct.pack_into("<I", buf, self.off_nsec, nanosec)
        struct.pack_into("<f", buf, self.off_volt, voltage)
        return bytes(buf)


def diagnostic_array(ns: int, statuses: Iterable[CoreStatus], prefix: str = "", hardware_id: str = ""
                     ) -> DiagnosticArrayMsg:
    """DiagnosticArray from CoreStatus-like objects (name, level, message, values), each named
    ``prefix`` + its name, for the hardware ``hardware_id`` (the motor or pack: monitors group by it)."""
    items = [
        DiagnosticStatusMsg(
            level=int(s.level),
            name=f"{prefix}{s.name}",
            message=str(s.message),
            hardware_id=hardware_id,
            values=[KeyValueMsg(key=str(k), value=str(v)) for k, v in s.values.items()],
        )
        for s in statuses
    ]
    return DiagnosticArrayMsg(header=_header(ns), status=items)


_BATTERY_TEMPLATE = _Template()
