"""The bus tap (drivers/frame_tap.py): every frame once with its direction, own echoes dropped exactly.

"Exactly" means by who sent the frame, not by its COB-ID or bytes: another node's frame identical
to one of ours (a foreign SYNC, the same heartbeat) is still received and recorded.
"""

from __future__ import annotations

import random
import time

import can
import canopen
import pytest

from drivers.bus import open_bus, parse_bus_spec
from drivers.frame_tap import FrameTap

SYNC = can.Message(arbitration_id=0x080, data=b"", is_extended_id=False)
END = can.Message(arbitration_id=0x181, data=b"\x01\x02", is_extended_id=False)


def _spec(interface: str):
    if interface == "udp_multicast":
        return parse_bus_spec("udp_multicast", udp_port=random.SystemRandom().randint(48000, 50999))
    return parse_bus_spec(f"virtual:tap-{random.SystemRandom().randint(0, 1 << 30)}")


@pytest.mark.parametrize("interface", ["udp_multicast", "virtual"])
def test_own_frames_are_seen_once_as_sent_and_an_identical_foreign_frame_once_as_received(interface):
    spec = _spec(interface)
    seen: list[tuple[bool, int, bytes]] = []
    with (
        FrameTap(
            open_bus(spec), lambda out, t, msg: seen.append((out, msg.arbitration_id, bytes(msg.data)))
        ) as tap,
        open_bus(spec) as other,
    ):
        for _ in range(3):
            tap.send(can.Message(arbitration_id=0x080, data=b"", is_extended_id=False))
        other.send(SYNC)  # the same COB-ID and bytes as ours, from another node
        other.send(END)
        got = []
        while (msg := tap.recv(timeout=30.0)) is not None:
            got.append(msg.arbitration_id)
            if msg.arbitration_id == END.arbitration_id:
                break
        # the other node, without a tap, sees our three SYNCs; on virtual its own two frames too
        # (it asked for own messages, as open_bus does), on udp_multicast not (the bus drops them)
        echoes = 2 if interface == "virtual" else 0
        other_saw = []
        while len(other_saw) < 3 + echoes and (msg := other.recv(timeout=30.0)) is not None:
            other_saw.append(msg.arbitration_id)
        assert other.recv(timeout=0.05) is None
    assert got == [0x080, 0x181]
    assert seen == [(True, 0x080, b"")] * 3 + [(False, 0x080, b""), (False, 0x181, b"\x01\x02")]
    assert (tap.sent, tap.received, tap.own_echoes) == (3, 2, 3 if interface == "virtual" else 0)
    assert sorted(other_saw) == [0x080] * (3 + echoes // 2) + [0x181] * (echoes // 2)


def test_recv_waits_past_dropped_echoes_for_the_rest_of_its_timeout():
    spec = _spec("virtual")
    with FrameTap(open_bus(spec)) as tap:
        tap.send(SYNC)
        assert tap.recv(timeout=0.05) is None  # the echo is not returned, and nothing else came
        assert tap.own_echoes == 1


def test_canopen_set_up_through_the_tap_is_recorded_both_ways():
    """SDO requests out, responses in, through canopen's notifier thread reading the tap."""
    spec = _spec("virtual")
    seen: list[tuple[bool, int]] = []
    network = canopen.Network(
        FrameTap(open_bus(spec), lambda out, t, msg: seen.append((out, msg.arbitration_id)))
    )
    server_net = canopen.Network(open_bus(spec))
    try:
        network.connect()
        server_net.connect()
        from drivers.node_setup import DRIVE_EDS

        server = canopen.LocalNode(5, str(DRIVE_EDS))
        server_net.add_node(server)
        client = canopen.RemoteNode(5, str(DRIVE_EDS))
        network.add_node(client)
        network.nmt.state = "PRE-OPERATIONAL"
        device_type = client.sdo.upload(0x1000, 0)
    finally:
        network.disconnect()
        server_net.disconnect()
    assert len(device_type) == 4
    assert (True, 0x000) in seen  # the NMT command
    requests = [x for x in seen if x == (True, 0x605)]
    responses = [x for x in seen if x == (False, 0x585)]
    assert len(requests) == len(responses) == 1
    assert not [x for x in seen if x[0] is False and x[1] in (0x000, 0x605)]  # no echo of ours as received


def test_on_the_machine_local_bus_the_tap_sends_frames_as_they_are_without_its_token():
    """The kernel drops the sender's own datagrams there: no token in ``channel`` (40 bytes more a
    datagram for every receiver to unpack); another node gets the frame with ``channel`` None."""
    spec = _spec("udp_multicast")
    with FrameTap(open_bus(spec)) as tap, open_bus(spec) as other:
        tap.send(can.Message(arbitration_id=0x080, data=b"", is_extended_id=False))
        msg = other.recv(timeout=30.0)
    assert msg is not None and msg.arbitration_id == 0x080
    assert msg.channel is None


class _Waiting(can.BusABC):
    """A bus with one frame waiting, received by the kernel at ``timestamp`` (wall clock)."""

    def __init__(self, timestamp: float) -> None:
        super().__init__(channel="waiting")
        self.frame: can.Message | None = can.Message(
            arbitration_id=0x181, data=b"\x01", is_extended_id=False, timestamp=timestamp
        )

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        raise AssertionError("nothing is sent here")

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        msg, self.frame = self.frame, None
        return msg, False


@pytest.mark.parametrize(("age_s", "stamp_age_s"), [(0.2, 0.2), (5.0, 0.0), (-1.0, 0.0)])
def test_a_received_frame_goes_to_the_sink_with_the_time_it_came_not_the_time_it_was_read(age_s, stamp_age_s):
    """A frame read 0.2 s after it came (a reader that slept through its answer window) is
    recorded 0.2 s before the read; a timestamp not believable as a receive time on this machine
    (5 s old, from the future) leaves the read's time."""
    seen: list[float] = []
    with FrameTap(
        _Waiting(time.time() - age_s), lambda out, t, msg: seen.append(t), clock=lambda: 100.0
    ) as tap:
        assert tap.recv(timeout=0.0) is not None
    assert seen == [pytest.approx(100.0 - stamp_age_s, abs=0.05)]
