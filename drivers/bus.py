"""Opening the CAN bus through python-can from an ``INTERFACE:CHANNEL`` specification."""

from __future__ import annotations

import socket
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import can

from controller.errors import InputError
from drivers.local_multicast import LocalUdpMulticastBus

# Interface-local IPv6 multicast group (DESIGN.md): never leaves this machine.
LOCAL_MULTICAST_GROUP = "ff11:7079:7468:6f6e:6465:6d6f:6d63:6173"
DEFAULT_UDP_PORT = 43113
SUPPORTED_INTERFACES = ("socketcan", "udp_multicast", "virtual")
CANFD_MTU = 72  # a SocketCAN interface carries FD frames only with this MTU (linux/can.h)


class BusSpecError(InputError):
    """A ``--bus`` specification is malformed or names something we refuse to use."""


@dataclass(frozen=True)
class BusSpec:
    interface: str
    channel: str
    fd: bool = False
    udp_port: int = DEFAULT_UDP_PORT

    def __str__(self) -> str:
        return f"{self.interface}:{self.channel}" + (" (CAN FD)" if self.fd else "")

    @property
    def place(self) -> str:
        """The bus as a message names it: with its UDP port for udp_multicast."""
        return str(self) + (f" port {self.udp_port}" if self.interface == "udp_multicast" else "")


def parse_bus_spec(text: str, fd: bool = False, udp_port: int = DEFAULT_UDP_PORT) -> BusSpec:
    """Parse ``socketcan:vcan0``, ``udp_multicast`` (the local group), ``virtual:name``."""
    interface, _, channel = text.partition(":")
    if interface not in SUPPORTED_INTERFACES:
        raise BusSpecError(
            f"--bus {text!r}: interface {interface!r} is not one of {', '.join(SUPPORTED_INTERFACES)}"
        )
    if interface == "udp_multicast":
        channel = channel or LOCAL_MULTICAST_GROUP
        if channel != LOCAL_MULTICAST_GROUP:
            # ff15:/239. groups reach the network; this product only uses the local group.
            raise BusSpecError(
                f"--bus {text!r}: udp_multicast is only allowed on the interface-local group "
                f"{LOCAL_MULTICAST_GROUP}"
            )
    elif not channel:
        raise BusSpecError(f"--bus {text!r}: missing channel, expected {interface}:CHANNEL")
    if not 1 <= udp_port <= 65535:
        raise BusSpecError(f"UDP port {udp_port} (--udp-port, bus.udp_port): must be in 1..65535")
    return BusSpec(interface=interface, channel=channel, fd=fd, udp_port=udp_port)


def socketcan_available() -> bool:
    """Whether this kernel has SocketCAN at all (CONFIG_CAN)."""
    try:
        socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW).close()
    except (OSError, AttributeError):
        return False
    return True


def open_bus(spec: BusSpec) -> can.BusABC:
    """Open the bus; raises can.CanInitializationError with the spec in the message."""
    # python-can passes the interface's own options through ``**kwargs: Any``.
    kwargs: dict[str, Any] = {"interface": spec.interface, "channel": spec.channel, "fd": spec.fd}
    if spec.interface == "virtual":
        kwargs["receive_own_messages"] = True  # like the other two: every bus sees its own frames
    if spec.fd and spec.interface == "socketcan":
        mtu_file = Path("/sys/class/net") / spec.channel / "mtu"
        if mtu_file.exists() and int(mtu_file.read_text()) < CANFD_MTU:
            raise can.CanInitializationError(
                f"cannot open {spec}: {spec.channel} cannot carry CAN FD frames (MTU {mtu_file.read_text().strip()}; "
                f"ip link set {spec.channel} down && ip link set {spec.channel} mtu {CANFD_MTU} up)"
            )
    try:
        if spec.interface == "udp_multicast":
            # not python-can's own: its socket listens on every address (drivers/local_multicast.py)
            return LocalUdpMulticastBus(spec.channel, spec.udp_port, fd=spec.fd)
        return can.Bus(**kwargs)
    except (OSError, can.CanError) as err:
        hint = ""
        if spec.interface == "socketcan" and not socketcan_available():
            hint = " (this kernel has no SocketCAN; use udp_multicast or tests/vcan/run)"
        raise can.CanInitializationError(f"cannot open {spec}: {err}{hint}") from err
