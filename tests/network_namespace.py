"""Two network namespaces joined by a veth pair, made by a test and removed by it.

``host`` stands for this machine (it runs the bus), ``lan`` for another machine on its network:
everything a test sends between them stays in the two namespaces, never on the machine's own
network. Needs root (CAP_SYS_ADMIN, CAP_NET_ADMIN) and the ``ip`` command; ``available()`` says
why not when the test has to be skipped.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

HOST_V6, LAN_V6 = "fd38::1", "fd38::2"
HOST_V4, LAN_V4 = "10.238.0.1", "10.238.0.2"


@dataclass(frozen=True)
class NamespacePair:
    host: str  # namespace names
    lan: str
    host_link: str  # the veth end in each
    lan_link: str

    def exec_prefix(self, namespace: str) -> list[str]:
        return ["ip", "netns", "exec", namespace]

    def counters(self, namespace: str) -> dict[str, int]:
        """The namespace's IP and UDP counters (/proc/net/snmp6 and the Udp lines of /proc/net/snmp)."""
        snmp6 = _run([*self.exec_prefix(namespace), "cat", "/proc/net/snmp6"])
        out = {k: int(v) for k, v in (line.split() for line in snmp6.splitlines() if line.strip())}
        udp = [
            line.split()[1:]
            for line in _run([*self.exec_prefix(namespace), "cat", "/proc/net/snmp"]).splitlines()
            if line.startswith("Udp:")
        ]
        names, values = udp[0], udp[1]  # a line of names, then one of values
        out.update({f"Udp{n}": int(v) for n, v in zip(names, values, strict=True)})
        return out


def _run(cmd: list[str]) -> str:
    return subprocess.run(cmd, check=True, capture_output=True, text=True).stdout


def available() -> str:
    """'' when namespaces can be made here, else why not."""
    if os.geteuid() != 0:
        return "network namespaces need root"
    if shutil.which("ip") is None:
        return "no ip command (iproute2)"
    return ""


@contextmanager
def namespace_pair() -> Iterator[NamespacePair]:
    """The two namespaces, up, with IPv6 and IPv4 addresses on the veth ends; removed on leaving."""
    tag = f"c38{os.getpid() % 100000}"
    pair = NamespacePair(f"{tag}h", f"{tag}a", f"{tag}h", f"{tag}a")
    made: list[str] = []
    try:
        for ns in (pair.host, pair.lan):
            _run(["ip", "netns", "add", ns])
            made.append(ns)
        _run(["ip", "link", "add", pair.host_link, "type", "veth", "peer", "name", pair.lan_link])
        for ns, link, v6, v4 in (
            (pair.host, pair.host_link, HOST_V6, HOST_V4),
            (pair.lan, pair.lan_link, LAN_V6, LAN_V4),
        ):
            _run(["ip", "link", "set", link, "netns", ns])
            _run(["ip", "-n", ns, "link", "set", "lo", "up"])
            _run(["ip", "-n", ns, "addr", "add", f"{v6}/64", "dev", link, "nodad"])
            _run(["ip", "-n", ns, "addr", "add", f"{v4}/24", "dev", link])
            _run(["ip", "-n", ns, "link", "set", link, "up"])
        yield pair
    finally:
        for ns in made:  # deleting a namespace deletes the veth end in it, and so the pair
            subprocess.run(["ip", "netns", "del", ns], check=False, capture_output=True)
