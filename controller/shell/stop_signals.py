"""SIGTERM, SIGINT and SIGHUP as stop requests: the first stops under control, the second quick-stops.

A service manager (systemd: ``KillSignal=SIGTERM``, then SIGKILL after ``TimeoutStopSec``)
and a user at the terminal (Ctrl-C) both send one signal and expect an orderly end: the loop
brakes within the limits, disables the drives and exits 0. A second signal means "now": the
drives get a quick stop through the controlword (CiA 402) and the process ends in FAULT. The
events are set from the signal relay's thread, not in a handler (controller/signal_relay.py).
"""

from __future__ import annotations

import signal
import threading
from dataclasses import dataclass, field

from controller.signal_relay import route_signals, stop_signals


@dataclass
class StopSignals:
    stop: threading.Event = field(default_factory=threading.Event)
    quick_stop: threading.Event = field(default_factory=threading.Event)

    def on_signal(self, signum: int) -> None:
        # a hang-up never escalates: a closed terminal often sends two (the shell's to its jobs,
        # the kernel's when the session leader exits), which must not quick-stop the drives
        if self.stop.is_set() and signum != signal.SIGHUP:
            self.quick_stop.set()
        self.stop.set()


def install_stop_signals(signals: tuple[signal.Signals, ...] | None = None) -> StopSignals:
    """Route ``signals`` (default: ``signal_relay.stop_signals()``, SIGHUP with them) to a new
    ``StopSignals`` (call from the main thread)."""
    handler = StopSignals()
    route_signals(stop_signals() if signals is None else signals, handler.on_signal)
    return handler
