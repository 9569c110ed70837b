"""Stop signals take no lock in their handler (controller/signal_relay.py).

A handler runs in the main thread wherever it was interrupted. Here the main thread holds the
stop event's own lock (as inside ``Event.set`` or ``Event.wait``) when the signals come: a handler
that set the event itself would wait for that lock for ever. Each case runs in a process of its
own, ended by the test if it hangs.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import textwrap

import pytest

from controller.signal_relay import stop_event_while

_HELD_LOCK = {
    "install_stop_signals": """
        from controller.shell.stop_signals import install_stop_signals
        s = install_stop_signals()
        event = s.stop
        with event._cond:  # the lock Event.set takes: held by the interrupted code
            signal.raise_signal(signal.SIGTERM)
            signal.raise_signal(signal.SIGTERM)  # a second one at once, as `timeout` sends
            print("handlers returned", flush=True)
        assert s.stop.wait(30) and s.quick_stop.wait(30)
        print("stop, then quick stop")
    """,
    "stop_event_on_signals": """
        from controller.signal_relay import stop_event_on_signals
        event = stop_event_on_signals()
        with event._cond:
            signal.raise_signal(signal.SIGINT)
            print("handlers returned", flush=True)
        assert event.wait(30)
        print("stop")
    """,
}


@pytest.mark.parametrize("case", sorted(_HELD_LOCK))
def test_a_signal_while_the_main_thread_holds_the_events_lock_stops_without_a_deadlock(case: str) -> None:
    script = "import signal\n" + textwrap.dedent(_HELD_LOCK[case])
    try:
        r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    except subprocess.TimeoutExpired as hung:
        pytest.fail(f"{case}: the process hung in its signal handler ({hung.stdout!r})")
    assert r.returncode == 0, r.stderr
    assert r.stdout.splitlines()[0] == "handlers returned"
    assert r.stdout.splitlines()[-1] in ("stop, then quick stop", "stop")


def test_a_hang_up_stops_as_sigterm_does_unless_it_was_ignored_at_start() -> None:
    """A closed terminal or a dropped SSH session (SIGHUP) ended `cheope run` mid-motion with no
    stop of its own (an outside tester's finding); under `nohup` it stays ignored."""
    script = textwrap.dedent("""
        import signal
        from controller.shell.stop_signals import install_stop_signals
        s = install_stop_signals()
        signal.raise_signal(signal.SIGHUP)
        print("stopped" if s.stop.wait(30) else "not stopped")
    """)
    started = "import signal; signal.signal(signal.SIGHUP, signal.SIG_{}); exec(open(0).read())"
    # from a terminal (SIGHUP at its default; the test run itself may be under nohup), then under nohup
    r = subprocess.run(
        [sys.executable, "-c", started.format("DFL")],
        input=script,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 0 and r.stdout.strip() == "stopped", r.stderr
    ignored = subprocess.run(
        [sys.executable, "-c", started.format("IGN")],
        input=script.replace("s.stop.wait(30)", "s.stop.wait(1)"),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert ignored.returncode == 0 and ignored.stdout.strip() == "not stopped", ignored.stderr


def test_a_second_hang_up_does_not_quick_stop_a_second_sigterm_does() -> None:
    """A closed terminal often sends two SIGHUPs (the shell's, the kernel's): they ask one stop."""
    import signal

    from controller.shell.stop_signals import StopSignals

    s = StopSignals()
    s.on_signal(signal.SIGHUP)
    s.on_signal(signal.SIGHUP)
    assert s.stop.is_set() and not s.quick_stop.is_set()
    s.on_signal(signal.SIGTERM)
    assert s.quick_stop.is_set()


def test_stop_event_while_hands_each_signal_back_as_it_found_it() -> None:
    """``cheope demo --simulated-time`` routes the stop signals for its run only: a caller of ``main``
    in its own process (the tests) keeps its Ctrl-C, not one routed to an event no one reads."""
    before = signal.getsignal(signal.SIGINT)
    with stop_event_while((signal.SIGINT,)) as stop:
        assert signal.getsignal(signal.SIGINT) != before
        signal.raise_signal(signal.SIGINT)
        assert stop.wait(30)
    assert signal.getsignal(signal.SIGINT) == before
