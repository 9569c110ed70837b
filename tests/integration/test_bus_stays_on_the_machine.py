"""The udp_multicast bus hears this machine only (issue 38, item 1; DESIGN.md "Buses").

In two network namespaces made by the test (tests/network_namespace.py: ``host`` runs the bus,
``lan`` is another machine on its network, joined by a veth pair), the ``lan`` side sends what
an attacker on the network can (tests/bus_reach_probe.py attack): an NMT stop to node 2 as a
unicast UDP datagram to the host's IPv6 and IPv4 address and the bus's port, and the same frame
as an interface-local multicast datagram written onto the wire by hand. The test waits until the
host's kernel has counted every one of them (delivered to a socket, or dropped for want of one,
or as an invalid header), then has the host send a frame of its own and a marker: the project's
bus receives the host's frames and nothing else; python-can's own UdpMulticastBus, on the same
test, receives the attacker's unicast frames (what the project's bus did before).
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest
from network_namespace import HOST_V4, HOST_V6, NamespacePair, available, namespace_pair

from controller.shell.demo import random_udp_port

pytestmark = [pytest.mark.integration, pytest.mark.skipif(bool(available()), reason=available() or "-")]

PROBE = str(Path(__file__).resolve().parent.parent / "bus_reach_probe.py")
ROOT = Path(__file__).resolve().parents[2]
NMT, LOCAL_SYNC, MARKER = 0x000, 0x080, 0x7FF


def _dropped(counters: dict[str, int]) -> tuple[int, int]:
    """(UDP datagrams the kernel dropped for want of a socket, IPv6 datagrams dropped for their header)."""
    return counters["Udp6NoPorts"] + counters["UdpNoPorts"], counters["Ip6InHdrErrors"]


def _wait_dropped(pair: NamespacePair, before: tuple[int, int], udp: int, headers: int) -> None:
    deadline, now = time.monotonic() + 30.0, before
    while time.monotonic() < deadline:
        now = _dropped(pair.counters(pair.host))
        if now[0] - before[0] >= udp and now[1] - before[1] >= headers:
            return
        time.sleep(0.05)  # polling the kernel's counters: the event is theirs to count
    raise AssertionError(
        f"the host's kernel did not drop the attacker's datagrams within 30 s: {now} vs {before}"
    )


def _received_by(pair: NamespacePair, kind: str) -> list[int | None]:
    """The ids the host's bus received: the attacker's (if any), then the host's own SYNC and marker."""
    port = random_udp_port()
    listener = subprocess.Popen(
        [*pair.exec_prefix(pair.host), sys.executable, PROBE, "listen", str(port), kind],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=ROOT,
    )
    try:
        assert listener.stdout is not None and listener.stdin is not None
        ready = listener.stdout.readline().strip()
        assert ready == "ready", listener.stderr.read() if listener.stderr else ready
        before = _dropped(pair.counters(pair.host))
        sent = subprocess.run(
            [*pair.exec_prefix(pair.lan), sys.executable, PROBE, "attack", str(port), HOST_V6, HOST_V4],
            capture_output=True,
            text=True,
            check=True,
            cwd=ROOT,
        )
        assert json.loads(sent.stdout) == {"unicast_v6": 1, "unicast_v4": 1, "raw_multicast": 1}
        received: list[int | None] = []
        if kind == "cheope":  # every attack was dropped by the host's kernel before the host sends
            _wait_dropped(pair, before, udp=2, headers=1)
        else:  # python-can's bus: the two unicast frames arrive (the wire multicast is dropped)
            while len(received) < 2:
                received.append(json.loads(listener.stdout.readline()))
            _wait_dropped(pair, before, udp=0, headers=1)
        listener.stdin.write("go\n")
        listener.stdin.flush()
        out, err = listener.communicate(timeout=90)
        assert listener.returncode == 0, err
        return received + [json.loads(line) for line in out.split()]
    finally:
        if listener.poll() is None:
            listener.kill()
            listener.wait()


def test_nothing_from_another_machine_reaches_the_bus_but_this_hosts_frames_do() -> None:
    with namespace_pair() as pair:
        assert _received_by(pair, "cheope") == [LOCAL_SYNC, MARKER]
        # the same test against python-can's own bus, bound to [::]:PORT: the unicast NMT stops arrive
        # (IPv6 and IPv4); the hand-written multicast is dropped by the kernel for both
        assert _received_by(pair, "python-can") == [NMT, NMT, LOCAL_SYNC, MARKER]
