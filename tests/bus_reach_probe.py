"""Who reaches a udp_multicast bus: the two sides of tests/integration/test_bus_stays_on_the_machine.py.

    python tests/bus_reach_probe.py listen PORT cheope|python-can   (in the "host" namespace)
    python tests/bus_reach_probe.py attack PORT HOST_V6 HOST_V4     (in the "lan" namespace)

``listen`` opens a receiving bus (the project's open_bus, or python-can's own UdpMulticastBus for
comparison), prints ``ready`` and then the id of every frame it receives, one JSON value a line, as
it arrives; on a line on stdin it opens a sending bus and sends a frame from this host (a SYNC) and
a marker (0x7FF), and ends after the marker (``null``: nothing for 60 s). ``attack`` sends, from another machine's address, what an attacker on the LAN can: an
NMT stop to node 2 (0x000, 02 02), packed as python-can packs a frame, as a unicast UDP datagram
to the host's IPv6 and IPv4 addresses, and as an interface-local multicast datagram written onto
the wire by hand (a raw Ethernet frame: Linux would not send it). It prints how many it sent.
"""

from __future__ import annotations

import json
import socket
import struct
import sys
import threading

import can
from can.interfaces.udp_multicast.utils import pack_message

GROUP = "ff11:7079:7468:6f6e:6465:6d6f:6d63:6173"
NMT_STOP_NODE_2 = can.Message(arbitration_id=0x000, data=b"\x02\x02", is_extended_id=False)
LOCAL_SYNC, MARKER = 0x080, 0x7FF


def listen(port: int, kind: str) -> None:
    from drivers.bus import open_bus, parse_bus_spec

    spec = parse_bus_spec("udp_multicast", udp_port=port)

    def bus() -> can.BusABC:
        if kind == "cheope":
            return open_bus(spec)
        return can.Bus(interface="udp_multicast", channel=GROUP, port=port)

    rx = bus()  # alone on the port until "go": unicast to a port shared (SO_REUSEPORT) goes to one socket

    def receive() -> None:
        while True:
            msg = rx.recv(60.0)
            print(json.dumps(None if msg is None else msg.arbitration_id), flush=True)
            if msg is None or msg.arbitration_id == MARKER:
                return

    receiving = threading.Thread(target=receive)
    receiving.start()
    print("ready", flush=True)
    sys.stdin.readline()
    with bus() as tx:
        tx.send(can.Message(arbitration_id=LOCAL_SYNC, data=b"", is_extended_id=False))
        tx.send(can.Message(arbitration_id=MARKER, data=b"", is_extended_id=False))
        receiving.join()
    rx.shutdown()


def _checksum(data: bytes) -> int:
    if len(data) % 2:
        data += b"\0"
    total: int = sum(struct.unpack(f"!{len(data) // 2}H", data))
    while total >> 16:
        total = (total & 0xFFFF) + (total >> 16)
    return ~total & 0xFFFF


def _raw_multicast_frame(interface: str, source_v6: str, port: int, payload: bytes) -> bytes:
    """An Ethernet frame carrying IPv6/UDP to the interface-local group, as only a raw socket sends it."""
    src, dst = socket.inet_pton(socket.AF_INET6, source_v6), socket.inet_pton(socket.AF_INET6, GROUP)
    udp_length = 8 + len(payload)
    pseudo = src + dst + struct.pack("!I3xB", udp_length, socket.IPPROTO_UDP)
    udp = struct.pack("!HHHH", port, port, udp_length, 0) + payload
    udp = udp[:6] + struct.pack("!H", _checksum(pseudo + udp) or 0xFFFF) + udp[8:]
    ipv6 = struct.pack("!IHBB", 6 << 28, udp_length, socket.IPPROTO_UDP, 1) + src + dst
    with open(f"/sys/class/net/{interface}/address") as f:
        mac = bytes.fromhex(f.read().strip().replace(":", ""))
    return b"\x33\x33" + dst[-4:] + mac + struct.pack("!H", 0x86DD) + ipv6 + udp


def attack(port: int, host_v6: str, host_v4: str) -> None:
    payload = pack_message(NMT_STOP_NODE_2)
    with socket.socket(socket.AF_INET6, socket.SOCK_DGRAM) as s6:
        s6.sendto(payload, (host_v6, port))
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s4:
        s4.sendto(payload, (host_v4, port))
    interface = next(name for _, name in socket.if_nameindex() if name != "lo")
    with open("/proc/net/if_inet6") as f:
        source_v6 = next(
            str(socket.inet_ntop(socket.AF_INET6, bytes.fromhex(line.split()[0])))
            for line in f
            if line.split()[5] == interface and not line.startswith("fe80")
        )
    with socket.socket(socket.AF_PACKET, socket.SOCK_RAW) as raw:
        raw.bind((interface, 0))
        raw.send(_raw_multicast_frame(interface, source_v6, port, payload))
    print(json.dumps({"unicast_v6": 1, "unicast_v4": 1, "raw_multicast": 1}), flush=True)


if __name__ == "__main__":
    if sys.argv[1] == "listen":
        listen(int(sys.argv[2]), sys.argv[3])
    else:
        attack(int(sys.argv[2]), sys.argv[3], sys.argv[4])
