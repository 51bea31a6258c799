"""quiet_start: the one start-up signal handler of the command line (exit 130) and the node
executables (exit 0), on small child processes that signal themselves (no ROS, no numpy)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from bldc_propulsion import quiet_start

ROOT = Path(__file__).resolve().parents[1]


def child(code: str, ignore_sigint: bool = False, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    def preexec() -> None:  # a test run started in the background inherits an ignored SIGINT
        signal.signal(signal.SIGINT, signal.SIG_IGN if ignore_sigint else signal.SIG_DFL)

    full = {**os.environ, **(env or {}), "PYTHONPATH": os.pathsep.join([str(ROOT), *sys.path])}
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True,
                          env=full, timeout=60, preexec_fn=preexec)


def test_started_as_a_program_or_a_module(monkeypatch):
    monkeypatch.setattr(sys, "argv", ["/opt/ros/bin/tachometer", "--ros-args"])
    assert quiet_start.started_as({"tachometer"})
    assert not quiet_start.started_as({"battery_filter"})
    monkeypatch.setattr(sys, "argv", ["/x/tachometer_node.py"])
    monkeypatch.setattr(sys, "orig_argv", ["python3", "-m", "pkg.tachometer_node", "--ros-args"])
    assert quiet_start.started_as({"tachometer"}, {"pkg.tachometer_node"})
    assert not quiet_start.started_as({"tachometer"}, {"pkg.other"})
    monkeypatch.setattr(sys, "orig_argv", ["python3", "-c", "-m"])  # no module after -m
    assert not quiet_start.started_as({"tachometer"}, {"pkg.tachometer_node"})


@pytest.mark.parametrize("status,signame", [(130, "SIGINT"), (0, "SIGINT"), (0, "SIGTERM")])
def test_a_signal_at_start_up_leaves_at_once_with_the_status_and_nothing_printed(status, signame):
    proc = child(f"""
        import os, signal, time
        from bldc_propulsion import quiet_start
        quiet_start.install({status}, (signal.SIGINT, signal.SIGTERM))
        assert quiet_start.active(signal.{signame})
        os.kill(os.getpid(), signal.{signame})
        time.sleep(5)
        print("still running")
    """)
    assert (proc.returncode, proc.stdout, proc.stderr) == (status, "", "")


def test_an_ignored_sigint_stays_ignored():
    proc = child("""
        import os, signal
        from bldc_propulsion import quiet_start
        quiet_start.install(130)
        assert not quiet_start.active(signal.SIGINT)
        os.kill(os.getpid(), signal.SIGINT)
        print("still running")
    """, ignore_sigint=True)
    assert (proc.returncode, proc.stdout.strip()) == (0, "still running"), proc.stderr


def test_after_end_sigint_is_a_keyboard_interrupt_again():
    """The command line ends the start-up window before it stages outputs: they must see
    KeyboardInterrupt to remove their staging files."""
    proc = child("""
        import os, signal, time
        from bldc_propulsion import quiet_start
        quiet_start.install(130)
        quiet_start.end(signal.SIGINT)
        assert not quiet_start.active(signal.SIGINT)
        assert signal.getsignal(signal.SIGINT) is quiet_start.interrupt
        assert not quiet_start.interrupted()
        try:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(5)
        except KeyboardInterrupt:
            print("interrupted", quiet_start.interrupted())
    """)
    assert (proc.returncode, proc.stdout.strip()) == (0, "interrupted True"), proc.stderr


def test_an_interrupt_raised_in_a_finalizer_reaches_the_work_without_a_traceback():
    """A Ctrl-C landing in a finalizer (in CI: a weakref callback of a lazy import's module
    lock) cannot leave it; it is passed on to the work, and Python prints nothing. Any other
    exception a finalizer raises is still reported as Python does."""
    proc = child("""
        import gc, os, signal, time
        from bldc_propulsion import quiet_start
        quiet_start.install(130)
        quiet_start.end(signal.SIGINT)

        class Slow:
            def __del__(self):  # the signal lands here
                os.kill(os.getpid(), signal.SIGINT)
                time.sleep(0.5)

        class Broken:
            def __del__(self):
                raise ValueError("a finalizer's own fault")

        Broken()
        gc.collect()
        try:
            Slow()
            gc.collect()
            for _ in range(100):
                time.sleep(0.05)
            print("work finished")
        except KeyboardInterrupt:
            print("interrupted", quiet_start.interrupted())
    """)
    assert proc.stdout.strip() == "interrupted True", (proc.stdout, proc.stderr)
    assert "KeyboardInterrupt" not in proc.stderr and "Exception ignored" in proc.stderr, proc.stderr
    assert "a finalizer's own fault" in proc.stderr


def test_an_output_is_not_moved_into_place_after_a_swallowed_interrupt(tmp_path):
    """A KeyboardInterrupt swallowed where the unraisable hook does not see it (reported by the
    default hook, as a C call may swallow it) lets the work run on to its end: the staged output
    must still not replace the old one."""
    proc = child("""
        import gc, os, signal, sys, time
        from pathlib import Path
        from bldc_propulsion import quiet_start
        from bldc_propulsion.atomic import atomic_output
        quiet_start.install(130)
        quiet_start.end(signal.SIGINT)
        sys.unraisablehook = sys.__unraisablehook__  # only reported, never passed on
        out = Path(os.environ["OUT"])
        out.write_text("old")

        class Slow:
            def __del__(self):  # the signal lands here; Python reports it and goes on
                os.kill(os.getpid(), signal.SIGINT)
                time.sleep(0.5)

        try:
            with atomic_output(out, force=True) as tmp:
                tmp.write_text("new")
                Slow()
                gc.collect()
                print("work finished")
        except KeyboardInterrupt:
            print("interrupted")
        print(out.read_text(), sorted(p.name for p in out.parent.iterdir()))
    """, env={"OUT": str(tmp_path / "model.txt")})
    lines = proc.stdout.split("\n")
    # the interrupt never reached the block, but the output was not replaced nor left staged
    assert lines[:3] == ["work finished", "interrupted", "old ['model.txt']"], (proc.stdout, proc.stderr)
    assert "KeyboardInterrupt" in proc.stderr  # what Python reported and swallowed


def test_end_leaves_a_handler_someone_else_installed():
    proc = child("""
        import signal
        from bldc_propulsion import quiet_start
        quiet_start.install(0, (signal.SIGTERM,))
        mine = lambda *_: None
        signal.signal(signal.SIGTERM, mine)  # as nodes.common.stop_on_signals takes it over
        quiet_start.end(signal.SIGTERM)
        assert signal.getsignal(signal.SIGTERM) is mine
    """)
    assert proc.returncode == 0, proc.stderr


def test_importing_it_pulls_nothing_heavy():
    proc = child("""
        import sys
        import bldc_propulsion.quiet_start, bldc_propulsion.nodes
        heavy = sorted(m for m in ("numpy", "scipy", "rclpy", "rosbags") if m in sys.modules)
        assert not heavy, heavy
    """)
    assert proc.returncode == 0, proc.stderr


@pytest.mark.parametrize("hang", ["time.sleep(30)", "while True: pass"])  # the GIL free, held
def test_a_node_executable_whose_teardown_hangs_ends_itself_and_says_where(hang):
    """nodes.guard_teardown: past TEARDOWN_LIMIT_S the process prints its Python stack and
    exits 1, even while a busy loop holds the GIL."""
    done = child(f"""
        import sys, time
        sys.argv[0] = "/opt/ros/lib/bldc_propulsion/tachometer"
        import bldc_propulsion.nodes as nodes
        assert nodes.EXECUTABLE
        nodes.TEARDOWN_LIMIT_S = 0.5
        def stuck_in_teardown():
            {hang}
        started = time.monotonic()
        nodes.guard_teardown()
        stuck_in_teardown()
        """)
    assert done.returncode == 1, (done.returncode, done.stderr)
    assert "Timeout" in done.stderr and "stuck_in_teardown" in done.stderr, done.stderr


def test_a_teardown_that_ends_in_time_leaves_quietly_and_a_library_is_never_guarded():
    done = child("""
        import sys, time
        import rclpy.utilities  # a node has it imported before it stops: not timed by the guard
        sys.argv[0] = "/opt/ros/lib/bldc_propulsion/tachometer"
        import bldc_propulsion.nodes as nodes
        nodes.TEARDOWN_LIMIT_S = 1.0
        nodes.guard_teardown()
        nodes.guard_teardown()  # armed once: a second stop does not move the limit
        time.sleep(0.2)
        nodes.leave(0)
        """)
    assert (done.returncode, done.stderr) == (0, "")
    done = child("""
        import time
        import bldc_propulsion.nodes as nodes
        assert not nodes.EXECUTABLE
        nodes.TEARDOWN_LIMIT_S = 0.2
        nodes.guard_teardown()
        time.sleep(1.0)
        print(nodes.leave(3))
        """)
    assert (done.returncode, done.stdout.strip(), done.stderr) == (0, "3", "")
