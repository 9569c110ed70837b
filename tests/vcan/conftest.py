"""Shared fixtures of the vcan tests (run them with ``tests/vcan/run``).

Every test collected from this folder gets the ``vcan`` marker, so the
default ``pytest`` run (``-m 'not vcan ...'`` in pyproject) leaves them out.

Fixtures:
- ``vcan_channel``: the name ``"vcan0"``; skips when there is no usable vcan0.
- ``no_leaks`` (autouse): fails a test that leaves a ``can.Bus`` open, a
  child process running, or a new thread alive; it shuts them down first.
"""

from __future__ import annotations

import contextlib
import os
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import can
import pytest

VCAN_CHANNEL = "vcan0"
ARPHRD_CAN = 280  # /sys/class/net/<dev>/type of CAN devices (linux/if_arp.h)
CANFD_MTU = 72  # MTU that lets a CAN device carry CAN FD frames (linux/can.h)
LEAK_GRACE_S = 1.0  # how long a thread may take to end after the test [s]

_THIS_DIR = Path(__file__).resolve().parent


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Mark every test of this folder ``vcan`` (before ``-m`` deselects)."""
    for item in items:
        if _THIS_DIR in Path(item.path).resolve().parents:
            item.add_marker(pytest.mark.vcan)


def vcan_unavailable_reason(channel: str = VCAN_CHANNEL) -> str:
    """Why ``channel`` cannot be used as a SocketCAN bus here, or "" if it can."""
    if not hasattr(socket, "AF_CAN"):
        return "this Python has no socket.AF_CAN"
    try:
        socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW).close()
    except OSError as err:
        return f"kernel has no SocketCAN ({err}); run tests/vcan/run"
    sys_dir = Path("/sys/class/net") / channel
    if not sys_dir.exists():
        return f"no {channel} interface; run tests/vcan/run (or: ip link add dev {channel} type vcan)"
    if int((sys_dir / "type").read_text()) != ARPHRD_CAN:
        return f"{channel} is not a CAN interface"
    if not int((sys_dir / "flags").read_text(), 16) & 0x1:  # IFF_UP
        return f"{channel} is down (ip link set up {channel})"
    return ""


@pytest.fixture(scope="session")
def vcan_channel() -> str:
    """Name of the vcan interface; skips the test when it is not usable."""
    reason = vcan_unavailable_reason(VCAN_CHANNEL)
    if reason:
        pytest.skip(reason)
    return VCAN_CHANNEL


@pytest.fixture(scope="session")
def vcan_fd_channel(vcan_channel: str) -> str:
    """Like ``vcan_channel``, and fails unless the interface carries CAN FD (MTU 72)."""
    mtu = int((Path("/sys/class/net") / vcan_channel / "mtu").read_text())
    if mtu != CANFD_MTU:
        pytest.fail(
            f"{vcan_channel} has mtu {mtu}, CAN FD needs {CANFD_MTU}: "
            f"ip link set {vcan_channel} down; ip link set {vcan_channel} mtu {CANFD_MTU}; "
            f"ip link set up {vcan_channel} (tests/vcan/run does this)"
        )
    return vcan_channel


# ---- leak checks ----------------------------------------------------------------


def _children(pid: int) -> set[int]:
    """Pids of the living (not zombie) descendants of ``pid``."""
    parent_of: dict[int, int] = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        # pid (comm) state ppid ...; comm may contain spaces and parentheses
        state, ppid = stat.rsplit(")", 1)[1].split()[:2]
        if state != "Z":
            parent_of[int(entry.name)] = int(ppid)
    found: set[int] = set()
    frontier = {pid}
    while frontier:
        frontier = {child for child, ppid in parent_of.items() if ppid in frontier} - found
        found |= frontier
    return found


@pytest.fixture(autouse=True)
def no_leaks(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """Fail the test if it leaves a can bus open, a child process or a new thread running."""
    # strong references: a bus dropped without shutdown() must still be seen here
    buses: list[can.BusABC] = []
    original_init = can.BusABC.__init__

    def tracking_init(self: can.BusABC, *args: object, **kwargs: object) -> None:
        buses.append(self)
        original_init(self, *args, **kwargs)

    monkeypatch.setattr(can.BusABC, "__init__", tracking_init)
    children_before = _children(os.getpid())
    threads_before = set(threading.enumerate())

    yield

    problems: list[str] = []
    open_buses = [bus for bus in buses if not getattr(bus, "_is_shutdown", True)]
    buses.clear()
    for bus in open_buses:
        problems.append(f"can bus left open: {bus.channel_info}")
        bus.shutdown()
    for pid in sorted(_children(os.getpid()) - children_before):
        problems.append(f"child process left running: pid {pid}")
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, 9)
    deadline = time.monotonic() + LEAK_GRACE_S
    for thread in set(threading.enumerate()) - threads_before:
        thread.join(max(0.0, deadline - time.monotonic()))
        if thread.is_alive():
            problems.append(f"thread left running: {thread.name}")
    if problems:
        pytest.fail("test leaked resources: " + "; ".join(problems), pytrace=False)
