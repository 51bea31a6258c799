"""A quiet start-up for this package's programs: a signal that lands while a program is still
importing leaves the process at once, with its documented status and no traceback.

Both the command line (``cli``: status 130, the shell's convention for Ctrl-C) and the node
executables (``nodes``: status 0, as a node stopped later exits) import this first, before
numpy, scipy or rclpy: those imports take about a second on a loaded 2-core computer, and
Python's KeyboardInterrupt would land inside one of them with a 50-line traceback. Nothing is
running or written yet in that window, so there is nothing to clean up and ``os._exit`` is
right. Imported as a library (tests, ``python -c``), nothing changes. Standard library only.
"""

from __future__ import annotations

import _thread
import os
import signal
import sys
from collections.abc import Collection, Iterable
from itertools import pairwise
from types import FrameType

#: The handler installed for each signal (so that ``active`` and ``end`` know it is still ours).
_HANDLERS: dict[int, object] = {}
#: Whether a SIGINT came while the program worked (after ``end``). A KeyboardInterrupt can be
#: swallowed on its way (raised inside a C call or a finalizer that only reports it) and the
#: work then runs on to its end: outputs look here before they are moved into place.
_INTERRUPTED = False
#: The unraisable hook that was in place before ``end`` installed ``_pass_on_lost_interrupt``.
_PREVIOUS_UNRAISABLE_HOOK = sys.unraisablehook


def started_as(programs: Collection[str], modules: Collection[str] = ()) -> bool:
    """Whether this process is one of ``programs`` (console scripts, by ``argv[0]``'s name) or
    runs one of ``modules`` with ``python -m``: a program being started, not a library imported."""
    if os.path.basename(sys.argv[0]) in programs:
        return True
    argv = getattr(sys, "orig_argv", [])
    return any(a == "-m" and b in modules for a, b in pairwise(argv))


def install(status: int, signums: Iterable[int] = (signal.SIGINT,)) -> None:
    """Until ``end``: each of ``signums`` ends the process at once with exit ``status``. A
    signal the parent ignores (a background job's SIGINT) stays ignored."""
    def leave(_signum: int, _frame: object) -> None:
        os._exit(status)

    for signum in signums:
        if signal.getsignal(signum) is not signal.SIG_IGN:
            signal.signal(signum, leave)
            _HANDLERS[signum] = leave


def active(signum: int = signal.SIGINT) -> bool:
    """Whether ``signum`` still has the start-up handler (nobody took it over since)."""
    return signum in _HANDLERS and signal.getsignal(signum) is _HANDLERS[signum]


def end(signum: int = signal.SIGINT) -> None:
    """The program is about to do work that must clean up when interrupted: Python's own
    handling of ``signum`` again (for SIGINT, ``interrupt``: KeyboardInterrupt, recorded), if the
    start-up handler is still the one installed."""
    global _PREVIOUS_UNRAISABLE_HOOK
    if active(signum):
        signal.signal(signum, interrupt if signum == signal.SIGINT else signal.SIG_DFL)
        if signum == signal.SIGINT and sys.unraisablehook is not _pass_on_lost_interrupt:
            _PREVIOUS_UNRAISABLE_HOOK = sys.unraisablehook
            sys.unraisablehook = _pass_on_lost_interrupt
    _HANDLERS.pop(signum, None)


def _pass_on_lost_interrupt(unraisable: sys.UnraisableHookArgs) -> None:
    """A KeyboardInterrupt raised inside a finalizer (a weakref callback of a lazy import's
    module lock, a ``__del__``) cannot leave it: Python would print "Exception ignored" with a
    traceback and run on. Instead the signal is tripped again for the main thread, silently, so
    that the interrupt lands in the work itself at a later step and ends it as a Ctrl-C should
    (landing in a finalizer again, it comes back here)."""
    if not (isinstance(unraisable.exc_value, KeyboardInterrupt) and _INTERRUPTED):
        _PREVIOUS_UNRAISABLE_HOOK(unraisable)
        return
    # tripped from another thread: tripped here, Python would run the handler at once, inside
    # this hook, and report that as a failed hook
    while True:
        try:
            _thread.start_new_thread(_thread.interrupt_main, (signal.SIGINT,))
            return
        except KeyboardInterrupt:  # the new thread was quicker than this return: once more
            continue


def interrupt(signum: int, frame: FrameType | None) -> None:
    """SIGINT while working: recorded (``interrupted``), then Python's KeyboardInterrupt."""
    global _INTERRUPTED
    _INTERRUPTED = True
    signal.default_int_handler(signum, frame)


def interrupted() -> bool:
    """Whether a SIGINT came while the program worked, even if its KeyboardInterrupt was lost."""
    return _INTERRUPTED
