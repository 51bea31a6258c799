"""The stamped outputs (``rotor/state``, ``predicted/state``, ``predicted/wrench``) in a recording,
as the nodes publish them: what ``replay`` writes beside the Float64 topics.

A message's bag time is when the node would publish it (the batch, the grid time); its
header.stamp the instant the value describes (``core.tach_output.revolution_middle`` for a
measured speed). Each kind is serialised once with sentinel values and patched per message
(``bagio._Template``'s approach: the typestore costs ~25 us a message, replay writes up to 300
a second of recording); ``test/test_stamped_outputs.py`` checks the bytes against the typestore.
"""

from __future__ import annotations

import struct
from typing import TYPE_CHECKING, cast

import numpy as np

from . import contract as c
from .bagio import TYPESTORE, BagWriter

if TYPE_CHECKING:  # the classes TYPESTORE.types holds under these names (typed there as MsgType)
    from rosbags.typesys.stores.ros2_jazzy import builtin_interfaces__msg__Time as TimeMsg
    from rosbags.typesys.stores.ros2_jazzy import geometry_msgs__msg__WrenchStamped as WrenchStampedMsg
    from rosbags.typesys.stores.ros2_jazzy import sensor_msgs__msg__JointState as JointStateMsg

_SEC, _NSEC = 0x5EC5EC01, 0x0A5EC0DE  #: sentinel stamp
_A, _B = 1234.5678125, -8765.4321875  #: sentinel doubles


def _stamp(sec: int, nanosec: int) -> TimeMsg:
    return cast("TimeMsg", TYPESTORE.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec))


def joint_state(joint_name: str, sec: int, nanosec: int, velocity: float) -> JointStateMsg:
    """JointState of one joint, velocity only (position and effort empty: unknown)."""
    T = TYPESTORE.types
    return cast("JointStateMsg", T[c.JOINT_STATE](
        header=T["std_msgs/msg/Header"](stamp=_stamp(sec, nanosec), frame_id=""),
        name=[joint_name], position=np.zeros(0),
        velocity=np.array([velocity], dtype=np.float64), effort=np.zeros(0)))


def wrench_stamped(frame_id: str, sec: int, nanosec: int, force_z: float, torque_z: float) -> WrenchStampedMsg:
    """WrenchStamped with force.z and torque.z, the rest 0."""
    T = TYPESTORE.types
    V = T["geometry_msgs/msg/Vector3"]
    wrench = T["geometry_msgs/msg/Wrench"](force=V(x=0.0, y=0.0, z=force_z),
                                          torque=V(x=0.0, y=0.0, z=torque_z))
    return cast("WrenchStampedMsg", T[c.WRENCH_STAMPED](
        header=T["std_msgs/msg/Header"](stamp=_stamp(sec, nanosec), frame_id=frame_id), wrench=wrench))


class _Patch:
    """CDR bytes of one message with its stamp and up to two doubles patched in."""

    def __init__(self, raw: bytes, n_values: int) -> None:
        self.raw = raw
        self.off_sec = raw.index(struct.pack("<i", _SEC))
        self.off_nsec = raw.index(struct.pack("<I", _NSEC))
        self.off = [raw.index(struct.pack("<d", v)) for v in (_A, _B)[:n_values]]

    def bytes(self, t_ns: int, *values: float) -> bytes:
        buf = bytearray(self.raw)
        sec, nanosec = divmod(t_ns, 10**9)
        struct.pack_into("<i", buf, self.off_sec, sec)
        struct.pack_into("<I", buf, self.off_nsec, nanosec)
        for off, v in zip(self.off, values, strict=True):
            struct.pack_into("<d", buf, off, v)
        return bytes(buf)


class StampedWriter:
    """Writes the stamped outputs of one motor into ``bag`` (topics already namespaced)."""

    def __init__(self, bag: BagWriter, rotor_topic: str, state_topic: str, wrench_topic: str,
                 joint_name: str = c.DEFAULT_JOINT_NAME, frame_id: str = c.DEFAULT_FRAME_ID) -> None:
        self.bag = bag
        self.rotor_topic, self.state_topic, self.wrench_topic = rotor_topic, state_topic, wrench_topic
        ser = TYPESTORE.serialize_cdr
        self._joint = _Patch(bytes(ser(joint_state(joint_name, _SEC, _NSEC, _A), c.JOINT_STATE)), 1)
        self._wrench = _Patch(bytes(ser(wrench_stamped(frame_id, _SEC, _NSEC, _A, _B),
                                        c.WRENCH_STAMPED)), 2)

    def _ns(self, t: float) -> int:
        return self.bag.t0_ns + int(round(t * 1e9))

    def rotor_state(self, t: float, stamp_t: float, speed_rad_s: float) -> None:
        """A measured speed published at ``t`` (s, the batch) describing ``stamp_t``."""
        self.bag.write_raw(self.rotor_topic, c.JOINT_STATE, t,
                           self._joint.bytes(self._ns(stamp_t), speed_rad_s))

    def prediction(self, t: float, speed_rad_s: float, thrust_n: float | None,
                   torque_nm: float) -> None:
        """predicted/state at grid time ``t`` (s) and, with a thrust, predicted/wrench."""
        ns = self._ns(t)
        self.bag.write_raw(self.state_topic, c.JOINT_STATE, t, self._joint.bytes(ns, speed_rad_s))
        if thrust_n is not None:
            self.bag.write_raw(self.wrench_topic, c.WRENCH_STAMPED, t,
                               self._wrench.bytes(ns, thrust_n, torque_nm))
