"""systemd's readiness protocol (sd_notify(3)) in a few lines of the standard library.

With ``Type=notify`` systemd waits for ``READY=1`` before it counts the unit as started, so
units ordered ``After=`` the controller start once the drives are configured and the loop is
about to run, not when the interpreter has merely started. ``STOPPING=1`` tells it the stop is
under way (braking, disabling the drives). The protocol is one datagram on the AF_UNIX socket
named in ``$NOTIFY_SOCKET``; the ``systemd-python`` or ``sdnotify`` packages would add a
dependency (and, for the first, a C build) for these lines.

No ``WATCHDOG=1``: a stalled loop is caught where it matters, by the drives' SYNC watchdog
(tens of milliseconds, in the drive), and a restart of a controller mid-motion by the service
manager is not a recovery we want automatic.
"""

from __future__ import annotations

import os
import socket


def notify(state: str) -> bool:
    """Send ``state`` (e.g. ``"READY=1"``) to the service manager; False when not run by one."""
    path = os.environ.get("NOTIFY_SOCKET", "")
    if not path:
        return False
    address = "\0" + path[1:] if path.startswith("@") else path  # "@": the abstract namespace
    try:
        with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC) as s:
            s.sendto(state.encode(), address)
    except OSError:
        return False  # the manager went away: nothing to tell
    return True
