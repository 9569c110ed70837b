"""The machine-local udp_multicast bus (drivers/local_multicast.py): its socket, interface and source check.

The network side (nothing from another machine arrives) is tests/integration/test_bus_stays_on_the_machine.py.
"""

from __future__ import annotations

import select
import socket
import struct
import time

import can
import pytest
from can.interfaces.udp_multicast.bus import GeneralPurposeUdpMulticastBus
from can.interfaces.udp_multicast.utils import pack_message, unpack_message

import drivers.local_multicast as lm
from controller.shell.demo import random_udp_port
from drivers.bus import LOCAL_MULTICAST_GROUP, open_bus, parse_bus_spec


def test_the_socket_is_ipv6_only_bound_to_the_group_and_never_sends_beyond_the_host() -> None:
    with open_bus(parse_bus_spec("udp_multicast", udp_port=random_udp_port())) as bus:
        sock = bus._multicast._socket
        _, index = lm.multicast_interface()
        assert sock.getsockname() == (LOCAL_MULTICAST_GROUP, bus._multicast.port, 0, index)
        assert sock.getsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY) == 1
        assert sock.getsockopt(socket.IPPROTO_IPV6, socket.IPV6_MULTICAST_HOPS) == 0
        assert sock.getsockopt(socket.IPPROTO_IPV6, socket.IPV6_MULTICAST_IF) == index


def test_frames_of_this_host_go_round_between_two_buses() -> None:
    spec = parse_bus_spec("udp_multicast", udp_port=random_udp_port())
    with open_bus(spec) as a, open_bus(spec) as b:
        a.send(can.Message(arbitration_id=0x123, data=b"\x01\x02", is_extended_id=False))
        got = b.recv(10.0)
        assert got is not None and (got.arbitration_id, bytes(got.data)) == (0x123, b"\x01\x02")
        assert b.foreign_datagrams == 0


def test_a_bus_never_receives_its_own_frames_and_its_sending_socket_receives_nothing() -> None:
    """As SocketCAN: the sender's echo is dropped in the kernel; every other bus gets the frame."""
    spec = parse_bus_spec("udp_multicast", udp_port=random_udp_port())
    with open_bus(spec) as a, open_bus(spec) as b, open_bus(spec) as c:
        a.send(can.Message(arbitration_id=0x080, data=b"", is_extended_id=False))
        b.send(can.Message(arbitration_id=0x181, data=b"\x01", is_extended_id=False))
        for bus, expected in ((a, {0x181}), (b, {0x080}), (c, {0x080, 0x181})):
            got = set()
            while len(got) < len(expected) and (msg := bus.recv(10.0)) is not None:
                got.add(msg.arbitration_id)
            assert got == expected
            assert bus.recv(0.05) is None  # and no echo after them
        sender = a._multicast._send_socket
        address, port = a._multicast.send_source
        assert sender.getsockname()[:2] == (address, port) == (address, a._multicast.send_port)
        assert sender.getsockopt(socket.IPPROTO_IPV6, socket.IPV6_MULTICAST_HOPS) == 0
        c._multicast._send_socket.sendto(b"x", sender.getsockname())
        sender.setblocking(False)
        with pytest.raises(BlockingIOError):
            sender.recv(64)


def test_only_the_bus_itself_can_send_from_its_source_and_the_same_port_elsewhere_is_received() -> None:
    """The echo filter drops one source, address and port; no other socket can bind that source
    (with or without SO_REUSEADDR/SO_REUSEPORT, nor the wildcard address), and a frame from the
    same port on another address of this host is someone else's: received (an outside tester's
    SDO writes from the controller's port went unseen, 44dbcbc)."""
    spec = parse_bus_spec("udp_multicast", udp_port=random_udp_port())
    _, index = lm.multicast_interface()
    with open_bus(spec) as a:
        address, port = a._multicast.send_source
        scope = a._multicast._send_socket.getsockname()[3]
        for where, reuse in ((address, False), (address, True), ("::", True)):
            with socket.socket(socket.AF_INET6, socket.SOCK_DGRAM) as s:
                if reuse:
                    s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                    s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
                with pytest.raises(OSError, match="in use"):
                    s.bind((where, port, 0, scope if where == address else 0))
        sent = False
        for other in sorted(lm.host_addresses() - {address, "::1"}):
            with socket.socket(socket.AF_INET6, socket.SOCK_DGRAM) as s:
                s.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_MULTICAST_HOPS, 0)
                s.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_MULTICAST_IF, index)
                try:
                    s.bind((other, port, 0, index if other.startswith("fe80") else 0))
                    frame = can.Message(arbitration_id=0x602, data=bytes(8), is_extended_id=False)
                    s.sendto(pack_message(frame), (LOCAL_MULTICAST_GROUP, spec.udp_port, 0, index))
                except OSError:
                    continue
                sent = True
                break
        if not sent:
            pytest.skip("this host has no second address to send from")
        got = a.recv(10.0)
        assert got is not None and got.arbitration_id == 0x602


def test_a_datagram_from_a_source_not_of_this_host_is_dropped_and_counted(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Behind the binding (which no such datagram passes on Linux), the source check: on a datagram
    read at once and on one waited for alike."""
    # recv(0): the foreign one, then nothing more waiting; recv(1): nothing waiting, one waited for
    waiting = [(b"x", ("2001:db8::66", 1, 0, 0), 1.0), None, None, (b"z", ("::1", 1, 0, 0), 3.0)]
    waited = [(b"y", ("::1", 1, 0, 0), 2.0)]
    monkeypatch.setattr(lm.LocalGroupSocket, "_recv_waiting", lambda self: waiting.pop(0))
    monkeypatch.setattr(GeneralPurposeUdpMulticastBus, "recv", lambda self, timeout=None: waited.pop(0))
    with open_bus(parse_bus_spec("udp_multicast", udp_port=random_udp_port())) as bus:
        handler = bus._multicast
        assert handler.recv(0.0) is None  # the foreign one
        assert handler.foreign_datagrams == 1
        assert handler.recv(1.0) == (b"y", ("::1", 1, 0, 0), 2.0)  # none waiting: waited for
        assert handler.recv(0.0) == (b"z", ("::1", 1, 0, 0), 3.0)


def test_datagrams_already_waiting_are_read_without_a_select_and_in_order(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A burst (a SYNC's answers) drains with one ``recvmsg`` a frame; only an empty socket is waited on."""
    spec = parse_bus_spec("udp_multicast", udp_port=random_udp_port())
    with open_bus(spec) as a, open_bus(spec) as b:
        for cob in (0x181, 0x182, 0x183):
            a.send(can.Message(arbitration_id=cob, data=b"\x01", is_extended_id=False))
        first = b.recv(10.0)  # waits (select) until the burst is there
        selects = []
        monkeypatch.setattr(
            "can.interfaces.udp_multicast.bus.select.select",
            lambda *args: selects.append(args) or ([], [], []),
        )
        rest = [b.recv(0.0), b.recv(0.0)]
        assert [m.arbitration_id for m in (first, *rest) if m is not None] == [0x181, 0x182, 0x183]
        assert all(m is not None and m.timestamp > 0.0 for m in rest)  # the kernel's receive times
        assert b.recv(0.0) is None
        assert selects == []  # never asked: each read found its datagram, the last found none
        assert b.recv(0.01) is None and selects  # an empty socket with a timeout: waited on


def _rings(bus: can.BusABC) -> list[int]:
    """The identifiers of the frames that rang ``bus``'s doorbell since it was last emptied."""
    bell = bus._multicast._doorbell
    out = []
    while select.select([bell], [], [], 0.0)[0]:
        out.append(unpack_message(bell.recv(4096)).arbitration_id)
    return out


@pytest.mark.parametrize("fd", [False, True])
@pytest.mark.parametrize("cob", [0x100, 0x1FF, 0x200, 0x201, 0x57F, 0x580, 0x7FF, 0xFFFF])
def test_the_doorbell_reads_the_identifier_where_python_can_packs_it(cob: int, fd: bool) -> None:
    """The filter checks the type bytes of python-can's msgpack layout and reads the identifier at a
    fixed offset: a python-can that packs otherwise fails here (and its frames would all ring)."""
    packed = pack_message(
        can.Message(timestamp=time.time(), arbitration_id=cob, data=bytes(8), is_extended_id=False, is_fd=fd)
    )
    for offset, value in lm._PACKED_LAYOUT:
        assert packed[offset] == value
    assert struct.unpack_from(">H", packed, lm._PACKED_ID_OFFSET)[0] == cob


def test_deferred_frames_wake_no_receiver_and_come_in_order_before_the_frame_that_does() -> None:
    """The simulator's RPDOs: the SYNC after them rings alone, and the receiver reads them first."""
    spec = parse_bus_spec("udp_multicast", udp_port=random_udp_port())
    with open_bus(spec) as a, open_bus(spec) as b:
        b.defer_wakeups(range(0x200, 0x580))
        for cob in (0x201, 0x302, 0x57F, 0x080):
            a.send(can.Message(arbitration_id=cob, data=b"\x01", is_extended_id=False))
        got = [b.recv(10.0) for _ in range(4)]
        assert [m.arbitration_id for m in got if m is not None] == [0x201, 0x302, 0x57F, 0x080]
        assert _rings(b) == [0x080]  # of the four, only the SYNC reached the doorbell
        b.send(can.Message(arbitration_id=0x181, data=b"", is_extended_id=False))  # its own: no ring
        a.send(can.Message(arbitration_id=0x580, data=b"", is_extended_id=False))  # outside the range
        assert b.recv(10.0).arbitration_id == 0x580
        assert _rings(b) == [0x580]


def test_a_deferred_frame_alone_is_read_when_the_wait_ends() -> None:
    spec = parse_bus_spec("udp_multicast", udp_port=random_udp_port())
    with open_bus(spec) as a, open_bus(spec) as b:
        b.defer_wakeups(range(0x200, 0x580))
        a.send(can.Message(arbitration_id=0x203, data=b"\x02", is_extended_id=False))
        got = None
        while got is None:  # each wait of 0.05 s ends with what is waiting, rung or not
            got = b.recv(0.05)
        assert (got.arbitration_id, bytes(got.data)) == (0x203, b"\x02")
        assert _rings(b) == []
        assert b.recv(0.0) is None


def test_a_datagram_the_doorbell_cannot_read_rings_it() -> None:
    """Not laid out as a packed frame (another program, a fuzzer): kept, so it wakes the receiver,
    which then drops it as before (python-can cannot unpack it)."""
    spec = parse_bus_spec("udp_multicast", udp_port=random_udp_port())
    with open_bus(spec) as a, open_bus(spec) as b:
        b.defer_wakeups(range(0x200, 0x580))
        _, index = lm.multicast_interface()
        bell = b._multicast._doorbell
        for datagram in (b"\x8b" + bytes(60), b"x"):
            a._multicast._send_socket.sendto(datagram, (LOCAL_MULTICAST_GROUP, b._multicast.port, 0, index))
            assert select.select([bell], [], [], 10.0)[0]
            assert bell.recv(4096) == datagram


def test_the_doorbell_takes_one_run_of_identifiers_a_uint16_holds() -> None:
    for bad in (range(0x80, 0x200), range(0x200, 0x580, 2), range(0x300, 0x300), range(0x200, 0x10001)):
        with pytest.raises(ValueError, match="quiet identifiers"):
            lm.doorbell_filter(("::1", 1234), bad)


def test_the_interface_is_the_loopback_when_it_carries_multicast_else_the_lowest_index_up(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    usable = {"lo": (False, True), "eth1": (True, False), "eth0": (True, False), "ifb0": (False, False)}
    monkeypatch.setattr(socket, "if_nameindex", lambda: [(1, "lo"), (2, "ifb0"), (3, "eth0"), (4, "eth1")])
    monkeypatch.setattr(lm, "_interface_usable", lambda name: usable[name])
    assert lm.multicast_interface() == ("eth0", 3)
    usable["lo"] = (True, True)
    assert lm.multicast_interface() == ("lo", 1)
    usable.update({k: (False, v[1]) for k, v in usable.items()})
    with pytest.raises(lm.NoMulticastInterfaceError, match="ip link set lo multicast on"):
        lm.multicast_interface()


def test_this_hosts_addresses_include_the_loopback() -> None:
    assert "::1" in lm.host_addresses()


NOT_FRAMES = (
    b"hello",  # not msgpack
    pack_message(can.Message(arbitration_id=0x181, data=b"\x01", is_extended_id=False))
    + b"!",  # trailing bytes
    struct.pack(">BBB", 0x93, 1, 2) + b"\x03",  # a msgpack list [1, 2, 3]
    b"\x83\xa9timestamp\xcb"
    + bytes(8)
    + b"\xaearbitration_id\xce\xff\xff\xff\xff\xaeis_extended_id\xc2",  # id out of range
    b"\x81\xa7mystery\x01",  # a field a frame does not have
    b"\x82\xaearbitration_id\xcb" + struct.pack(">d", 384.5) + b"\xa4data\xc4\x00",  # a float identifier
    b"\x82\xaearbitration_id\x01\xa4data\xce\xff\xff\xff\xff",  # an integer as data (4 GiB to python-can)
    b"\x81\xaearbitration_id\xcf\x80" + bytes(7),  # 2**63
)


def test_a_datagram_that_is_no_frame_is_dropped_counted_and_named_and_the_frames_around_it_arrive(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """python-can's own bus raised CanOperationError out of ``recv`` for each of these: one datagram
    from any process of this host ended the controller and the simulator. Here each is dropped, the
    receiver waits on for the rest of its timeout, and the frames before and after come in order."""
    spec = parse_bus_spec("udp_multicast", udp_port=random_udp_port())
    with open_bus(spec) as a, open_bus(spec) as b:
        a.send(can.Message(arbitration_id=0x101, data=b"\x01", is_extended_id=False))
        for datagram in NOT_FRAMES:
            a._multicast.send(datagram)
        a.send(can.Message(arbitration_id=0x102, data=b"\x02", is_extended_id=False))
        got = [b.recv(10.0), b.recv(10.0)]
        assert [(m.arbitration_id, bytes(m.data)) for m in got if m is not None] == [
            (0x101, b"\x01"),
            (0x102, b"\x02"),
        ]
        assert b.unreadable_datagrams == len(NOT_FRAMES)
        assert b.recv(0.05) is None
        assert "datagram(s) that are no CAN frame dropped" in caplog.text


def test_only_datagrams_that_are_no_frame_end_a_receive_at_its_timeout_not_in_an_error() -> None:
    spec = parse_bus_spec("udp_multicast", udp_port=random_udp_port())
    with open_bus(spec) as a, open_bus(spec) as b:
        a._multicast.send(b"hello")
        assert b.recv(0.2) is None
        assert b.unreadable_datagrams == 1


@pytest.mark.parametrize("datagram", NOT_FRAMES)
def test_unpack_frame_names_what_is_wrong(datagram: bytes) -> None:
    with pytest.raises(ValueError, match=r"^(not msgpack|a msgpack list|not a CAN frame)"):
        lm.unpack_frame(datagram, 1.0)


def test_unpack_frame_reads_what_python_can_packs() -> None:
    sent = can.Message(arbitration_id=0x1ABCDEF, data=bytes(range(12)), is_extended_id=True, is_fd=True)
    got = lm.unpack_frame(pack_message(sent), 5.0)
    assert got.timestamp == 5.0
    assert got.equals(unpack_message(pack_message(sent), replace={"timestamp": 5.0}))


def test_a_receive_that_does_not_wait_reads_past_a_foreign_datagram(monkeypatch: pytest.MonkeyPatch) -> None:
    waiting = [(b"x", ("2001:db8::66", 1, 0, 0), 1.0), (b"y", ("::1", 1, 0, 0), 2.0), None]
    monkeypatch.setattr(lm.LocalGroupSocket, "_recv_waiting", lambda self: waiting.pop(0))
    with open_bus(parse_bus_spec("udp_multicast", udp_port=random_udp_port())) as bus:
        handler = bus._multicast
        assert handler.recv(0.0) == (b"y", ("::1", 1, 0, 0), 2.0)
        assert handler.foreign_datagrams == 1


def test_a_receive_that_does_not_wait_reads_past_a_datagram_that_is_no_frame(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The cyclic exchange drains with ``recv(0)`` past its deadline: a dropped datagram must not
    end the drain while an answer waits behind it (through ``BusABC.recv`` it did)."""
    frame = pack_message(can.Message(arbitration_id=0x181, data=b"\x01", is_extended_id=False))
    waiting = [(b"hello", ("::1", 1, 0, 0), 1.0), (frame, ("::1", 1, 0, 0), 2.0), None]
    monkeypatch.setattr(lm.LocalGroupSocket, "recv", lambda self, timeout=None: waiting.pop(0))
    with open_bus(parse_bus_spec("udp_multicast", udp_port=random_udp_port())) as bus:
        got = bus.recv(0.0)
        assert got is not None and (got.arbitration_id, got.timestamp) == (0x181, 2.0)
        assert bus.recv(0.0) is None and bus.unreadable_datagrams == 1
