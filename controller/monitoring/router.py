"""``cheope router``: a Zenoh router in a Python process, for many controllers monitored from one place.

Zenoh's own router is ``zenohd`` (a Rust binary, not on PyPI); eclipse-zenoh's Python API
opens the same router with ``mode: "router"`` in a session's configuration, which is what
this does, so that no second install is needed. Controllers connect to it
(``cheope run --zenoh-connect tcp/127.0.0.1:7447``), and so do the tools
(``cheope list --zenoh-connect tcp/127.0.0.1:7447``): the router forwards samples, queries
and liveliness between all of them. A ``zenohd`` listening on the same endpoint serves
the same purpose. Listens on loopback unless told otherwise; multicast and gossip scouting
off, as every session of the project (zenoh_session.py).
"""

from __future__ import annotations

import threading
from collections.abc import Callable

from controller.monitoring.zenoh_session import SessionSettings, open_session
from controller.signal_relay import stop_event_on_signals

READY = "READY"


def run_router(
    listen: tuple[str, ...],
    config_file: str = "",
    say: Callable[[str], None] = print,
    stop: threading.Event | None = None,
) -> int:
    """Run until SIGINT or SIGTERM (or ``stop``); prints ``READY <endpoints>`` once it listens."""
    if stop is None:
        stop = stop_event_on_signals()  # no lock in a handler (controller/signal_relay.py)
    session, endpoints = open_session(SessionSettings(mode="router", listen=listen, config_file=config_file))
    try:
        say(f"{READY} {' '.join(endpoints)}")
        stop.wait()
    finally:
        session.close()
    return 0
