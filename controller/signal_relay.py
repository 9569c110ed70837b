"""Signals routed out of their handlers: a handler takes no lock.

Python runs a signal handler in the main thread between two bytecodes, wherever that thread is:
a handler that sets a ``threading.Event`` waits for the Event's lock, and if the interrupted code
holds it, it waits for ever. Two SIGTERMs in a row did that (``timeout`` sends one to the process
and one to its process group): the second handler ran inside the first one's ``Event.set``, and
the demo hung in its loop with its CPU shield kept and its ports held. So a handler only writes
the signal's number to a pipe, and a thread of its own (``cheope-signals``) reads it and calls
what was routed there, taking what locks it needs like any other thread.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
from collections.abc import Callable, Iterable, Iterator
from types import FrameType

SignalCallback = Callable[[int], None]  # the signal's number

# The signals that ask for an orderly stop: Ctrl-C, a service manager's stop, and a hang-up (the
# terminal closed, an SSH session dropped), which ended `cheope run` mid-motion with no stop of its
# own (the drives quick-stopped on their SYNC watchdog; an outside tester's finding). A hang-up
# that was ignored when the process started (``nohup``) stays ignored (``stop_signals``).
_STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


def stop_signals() -> tuple[signal.Signals, ...]:
    """``_STOP_SIGNALS``, less SIGHUP when it was ignored since the process started (``nohup``)."""
    return tuple(s for s in _STOP_SIGNALS if s != signal.SIGHUP or signal.getsignal(s) is not signal.SIG_IGN)


class _SignalRelay:
    """The pipe from the handlers to the relay thread (one a process)."""

    def __init__(self) -> None:
        self._pid = os.getpid()
        self._read, self._write = os.pipe()
        os.set_blocking(self._write, False)  # a full pipe loses a repeated signal, never blocks a handler
        self.callbacks: dict[int, SignalCallback] = {}
        threading.Thread(target=self._relay, name="cheope-signals", daemon=True).start()

    def handler(self, signum: int, frame: FrameType | None) -> None:
        if os.getpid() != self._pid:  # a forked child before it set its own handlers: not ours
            return
        with contextlib.suppress(BlockingIOError):  # 64 KiB of signals not read yet: one more adds nothing
            os.write(self._write, bytes((signum,)))

    def _relay(self) -> None:
        while True:
            for signum in os.read(self._read, 256):
                callback = self.callbacks.get(signum)
                if callback is not None:
                    callback(signum)


_relay: _SignalRelay | None = None


def route_signals(signals: Iterable[int], callback: SignalCallback) -> None:
    """From now on each of ``signals`` calls ``callback(signum)`` on the relay thread, not in a
    handler (module text). Call from the main thread, as ``signal.signal``."""
    global _relay
    if _relay is None:
        _relay = _SignalRelay()
    for sig in signals:
        _relay.callbacks[int(sig)] = callback
        signal.signal(sig, _relay.handler)


def stop_event_on_signals(signals: Iterable[int] | None = None) -> threading.Event:
    """An event that ``signals`` (default: ``stop_signals()``) set (sim, replay, router, demo)."""
    stop = threading.Event()
    route_signals(stop_signals() if signals is None else signals, lambda _: stop.set())
    return stop


@contextlib.contextmanager
def stop_event_while(signals: Iterable[int] | None = None) -> Iterator[threading.Event]:
    """``stop_event_on_signals`` for the block: after it, each signal is handled as before it. A
    command run in the process of its caller (the tests' ``main([...])``) leaves that process's
    Ctrl-C as it found it, not routed to an event no one reads any more."""
    chosen = tuple(int(sig) for sig in (stop_signals() if signals is None else signals))
    handlers = {sig: signal.getsignal(sig) for sig in chosen}
    callbacks = {sig: _relay.callbacks.get(sig) if _relay is not None else None for sig in chosen}
    stop = stop_event_on_signals(chosen)
    try:
        yield stop
    finally:
        assert _relay is not None  # started by stop_event_on_signals
        for sig in chosen:
            if handlers[sig] is not None:  # None: a handler set outside Python, which getsignal cannot give
                signal.signal(sig, handlers[sig])
            callback = callbacks[sig]
            if callback is None:
                _relay.callbacks.pop(sig, None)
            else:
                _relay.callbacks[sig] = callback
