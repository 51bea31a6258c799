"""LeanExecutor: rclpy's single-threaded executor with a cheap path for messages and timers.

Why by hand: ``propulsion_all --executor single`` (and ``mixed``) is the choice for an rclpy
whose experimental EventsExecutor (every node's default) misbehaves, and rclpy 7.1.6's
``SingleThreadedExecutor`` rebuilds its entity lists, a wait set, a task and a coroutine for
every message (~150 µs per message here, most of a tachometer node's CPU). Our timing rules
(``stream_time.py``) need the publisher's sequence numbers and timestamps, which any executor
gives (``common.WithInfo``). This executor waits on one wait set of the nodes'
subscriptions and timers, takes EVERY queued message of a ready subscription with
``take_message`` (message info included: a burst after a stall costs one wake-up, not one per
message) and calls the callbacks directly. Services (parameters), clients and the nodes' guard
conditions are in the same wait set: when one of them is ready the base class serves it. QoS
event waitables (incompatible-QoS warnings) are not (adding every publisher's and
subscription's event handlers to each wait would cost more than it saves): the base class polls
them every ``POLL_S`` and whenever the executor is woken (a node added an entity). Before
services woke it, a poll every 0.1 s was a third of an idle node's CPU (0.25-0.55 % of a core
per process, 3 % for a quadrotor's nine processes).

Supported rclpy: 7.1 (ROS 2 Jazzy), checked on 7.1.6 (the ros-jazzy-rclpy wheel). The lean path
uses names rclpy does not publish (``PRIVATE_API``: the executor's ``_context``, ``_guard``,
``_sigint_gc``, ``_is_shutdown``, a subscription's ``_callback_type`` and the C extension's wait
set and handles); test/test_lean_executor.py fails naming the one an rclpy update dropped. At
run time an rclpy without one of them gets rclpy's own SingleThreadedExecutor (one WARN line,
slower per message, the same callbacks), never a crash.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Mapping
from importlib.metadata import PackageNotFoundError, version
from typing import Any, NamedTuple

import rclpy.logging
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.subscription import Subscription

#: How often the base class looks at what is not in the lean wait set (QoS event waitables),
#: s; each look costs one pass of the base executor (~0.3 ms).
POLL_S = 1.0

#: The rclpy release line whose private names the lean path uses (see the module docstring).
SUPPORTED_RCLPY = "7.1"

#: rclpy names outside its public API that the lean path uses, by owner: the executor's and a
#: subscription's attributes, and the methods of the C extension's classes (``_rclpy``).
PRIVATE_API: dict[str, tuple[str, ...]] = {
    "Executor": ("_context", "_guard", "_sigint_gc", "_is_shutdown"),
    "Subscription": ("_callback_type",),
    "_rclpy.WaitSet": ("clear_entities", "add_subscription", "add_timer", "add_service", "add_client",
                       "add_guard_condition", "wait", "get_ready_entities"),
    "_rclpy.Subscription": ("take_message", "pointer"),
    "_rclpy.Timer": ("is_timer_ready", "call_timer", "pointer"),
    "_rclpy.GuardCondition": ("pointer",),
}

_WITH_INFO = getattr(getattr(Subscription, "CallbackType", None), "WithMessageInfo", None)


def rclpy_version() -> str:
    """The installed rclpy's version (PyPI wheel or a ROS install's egg-info), for messages."""
    for dist in ("ros-jazzy-rclpy", "ros-rclpy", "rclpy"):
        with contextlib.suppress(PackageNotFoundError):
            return version(dist)
    return "unknown"


def missing_private_api(executor: object = None, subscription: object = None) -> list[str]:
    """The names of ``PRIVATE_API`` this rclpy lacks ("Executor._guard", ...); [] when all are
    there. The executor's and the subscription's attributes are looked up on the instances given
    (they are set in ``__init__``), the C extension's on its classes."""
    missing = [f"{owner}.{name}" for owner, names in PRIVATE_API.items() if owner.startswith("_rclpy.")
               for name in names if not hasattr(getattr(_rclpy, owner.split(".")[1], None), name)]
    if _WITH_INFO is None:
        missing.append("Subscription.CallbackType.WithMessageInfo")
    for owner, instance in (("Executor", executor), ("Subscription", subscription)):
        if instance is not None:
            missing += [f"{owner}.{name}" for name in PRIVATE_API[owner] if not hasattr(instance, name)]
    return missing


class _Lean(NamedTuple):
    """What one wait of the lean path adds and looks up (rebuilt when an entity changes). The
    handles and the wait set are the C extension's (``_rclpy``, which has no type information):
    untyped where the lean path calls them, object where it only hands them to the wait set."""

    subscriptions: list[object]
    #: pointer -> (handle, callback, message type, raw, with message info)
    by_sub: Mapping[int, tuple[Any, Callable[..., None], object, bool, bool]]
    by_timer: Mapping[int, tuple[Any, Callable[[], None]]]  #: pointer -> (handle, callback)
    services: list[object]
    clients: list[object]
    guards: list[Any]
    wait_set: Any


class LeanExecutor(SingleThreadedExecutor):
    """Single-threaded; subscriptions and timers on a lean path, the rest by the base class."""

    def __init__(self, *, context: Context | None = None) -> None:
        super().__init__(context=context)
        self._lean: _Lean | None = None
        self._next_poll_s = 0.0
        #: private rclpy names this rclpy lacks: then spin_once is the base class's
        self.missing: list[str] = []
        self._fall_back(missing_private_api(self))

    def _fall_back(self, missing: list[str]) -> bool:
        """With names of PRIVATE_API missing: say so once, and be rclpy's own executor."""
        if missing and not self.missing:
            self.missing = missing
            rclpy.logging.get_logger("lean_executor").warning(
                f"rclpy {rclpy_version()} lacks {', '.join(missing)} (LeanExecutor supports rclpy "
                f"{SUPPORTED_RCLPY}): running rclpy's SingleThreadedExecutor instead, slower per message")
        return bool(self.missing)

    def _entities(self) -> _Lean | None:
        """Handles to add, ready-pointer lookups and a wait set sized for them (rebuilt when
        woken: a node that creates an entity wakes its executor); None if a subscription lacks
        the private attribute the lean path reads (then it falls back)."""
        nodes = self.get_nodes()
        subs = [s for n in nodes for s in n.subscriptions]
        if subs and self._fall_back(missing_private_api(subscription=subs[0])):
            return None
        timers = [t for n in nodes for t in n.timers]
        services = [s.handle for n in nodes for s in n.services]
        clients = [c.handle for n in nodes for c in n.clients]
        guards = [g.handle for n in nodes for g in n.guards]
        wait_set = _rclpy.WaitSet(len(subs), 2 + len(guards), len(timers), len(clients),
                                  len(services), 0, self._context.handle)
        by_sub = {s.handle.pointer: (s.handle, s.callback, s.msg_type, s.raw,
                                     s._callback_type is _WITH_INFO) for s in subs}
        by_timer = {t.handle.pointer: (t.handle, t.callback) for t in timers}
        return _Lean([s.handle for s in subs], by_sub, by_timer, services, clients, guards, wait_set)

    def spin_once(self, timeout_sec: float | None = None) -> None:
        if self.missing:
            super().spin_once(timeout_sec=timeout_sec)
            return
        now = time.monotonic()
        if now >= self._next_poll_s:  # services, parameters, events: the base class's way
            self._next_poll_s = now + POLL_S
            super().spin_once(timeout_sec=0)
        if self._lean is None:
            self._lean = self._entities()
            if self._lean is None:
                super().spin_once(timeout_sec=timeout_sec)
                return
        lean = self._lean
        by_sub, by_timer, wait_set = lean.by_sub, lean.by_timer, lean.wait_set
        wait_s = POLL_S if timeout_sec is None or timeout_sec < 0 else min(timeout_sec, POLL_S)
        wait_set.clear_entities()
        for handle in lean.subscriptions:
            wait_set.add_subscription(handle)
        for handle, _ in by_timer.values():
            wait_set.add_timer(handle)
        for handle in lean.services:
            wait_set.add_service(handle)
        for handle in lean.clients:
            wait_set.add_client(handle)
        for handle in lean.guards:
            wait_set.add_guard_condition(handle)
        wait_set.add_guard_condition(self._guard.handle)
        wait_set.add_guard_condition(self._sigint_gc.handle)
        wait_set.wait(int(wait_s * 1e9))
        if self._is_shutdown or not self._context.ok():
            return
        ready_guards = wait_set.get_ready_entities('guard_condition')
        if self._guard.handle.pointer in ready_guards:
            self._lean = None  # an entity was added or removed (or wake()): rebuild, poll
            self._next_poll_s = 0.0
        elif (wait_set.get_ready_entities('service') or wait_set.get_ready_entities('client')
              or any(g.pointer in ready_guards for g in lean.guards)):
            self._next_poll_s = 0.0  # the base class serves it on the next turn, before waiting
        # Messages before timers: a timer that fires in the same wake-up as a late input then
        # sees it (the estimator's timer emits grid times the inputs should have reached).
        for pointer in wait_set.get_ready_entities('subscription'):
            handle, callback, msg_type, raw, with_info = by_sub[pointer]
            while True:  # drain: every message queued since the last wake-up
                taken = handle.take_message(msg_type, raw)
                if taken is None:
                    break
                if with_info:
                    callback(taken[0], taken[1])
                else:
                    callback(taken[0])
        for pointer in wait_set.get_ready_entities('timer'):
            handle, callback = by_timer[pointer]
            if handle.is_timer_ready():  # rcl may report a cancelled timer
                handle.call_timer()
                callback()
