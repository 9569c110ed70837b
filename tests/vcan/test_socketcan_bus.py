"""python-can ``socketcan`` buses on vcan0: what the controller and simulator rely on.

Run with ``tests/vcan/run`` (natively or in a VM). Findings these tests pin
down (Linux 6.1, python-can 4.6):
- classical and CAN FD frames arrive with exact IDs, flags and bytes, in
  order; a bus does not receive its own frames unless
  ``receive_own_messages=True``; ``msg.is_rx`` is False for every frame sent
  by any process of this host (MSG_DONTROUTE), so it cannot tell the
  controller's frames from the simulator's: filter by COB-ID;
  a bus opened without ``fd=True`` never sees FD frames;
- vcan never fills its transmit queue: it has no qdisc (``noqueue``, so
  ``txqueuelen`` changes nothing) and loops frames back synchronously.
  A reader that does not read loses the newest frames silently (tail drop at
  its socket receive buffer: 278 classical frames fit the default 208 KiB
  SO_RCVBUF); the sender gets no error;
- a full transmit queue (a rate-limiting ``tbf`` qdisc stands in for a busy
  controller) makes ``send`` raise ``can.CanOperationError`` with
  ``error_code == errno.ENOBUFS`` (105), message "Failed to transmit: No
  buffer space available"; sending works again once the queue drains;
- vcan never generates error frames, but delivers the ones a socket sends
  (CAN_ERR_FLAG set): python-can reports ``is_error_frame=True`` with the
  error class bits as ``arbitration_id``. Error frames whose class bits are 0
  are delivered to nobody, and ``ignore_rx_error_frames=True`` filters them.
"""

from __future__ import annotations

import errno
import os
import shutil
import socket
import struct
import subprocess
import time
from collections.abc import Iterator

import can
import pytest

RECV_TIMEOUT_S = 2.0  # generous: the tests may run in an emulated (TCG) VM
CAN_ERR_FLAG = 0x20000000  # linux/can.h
CAN_ERR_BUSOFF = 0x00000040  # linux/can/error.h, error class "bus off"
CAN_ERR_CRTL = 0x00000004  # linux/can/error.h, error class "controller problems"
CAN_FRAME_FMT = "=IB3x8s"  # struct can_frame: can_id, len, pad, res0, len8_dlc, data[8]
CANFD_DATA_LENGTHS = (0, 1, 7, 8, 12, 16, 20, 24, 32, 48, 64)


def _bus(channel: str, **kwargs: object) -> can.BusABC:
    return can.Bus(interface="socketcan", channel=channel, **kwargs)


def _recv_all(bus: can.BusABC, count: int) -> list[can.Message]:
    received = []
    for _ in range(count):
        msg = bus.recv(timeout=RECV_TIMEOUT_S)
        assert msg is not None, f"only {len(received)} of {count} frames arrived"
        received.append(msg)
    return received


def _marker(bus: can.BusABC, arbitration_id: int = 0x7EF) -> can.Message:
    """Send a classical frame used to prove that nothing arrived before it."""
    msg = can.Message(arbitration_id=arbitration_id, data=b"\xaa\x55", is_extended_id=False)
    bus.send(msg)
    return msg


# ---- 1. classical frames --------------------------------------------------------

CLASSICAL_FRAMES = [
    can.Message(arbitration_id=0x000, data=b"", is_extended_id=False),
    can.Message(arbitration_id=0x7FF, data=bytes(range(8)), is_extended_id=False),
    can.Message(arbitration_id=0x181, data=b"\x00\xff\x10\x80", is_extended_id=False),
    can.Message(arbitration_id=0x1FFFFFFF, data=b"\xde\xad\xbe\xef\x01", is_extended_id=True),
    can.Message(arbitration_id=0x00000001, data=b"\x7f", is_extended_id=True),
    can.Message(arbitration_id=0x601, is_remote_frame=True, dlc=4, is_extended_id=False),
]


def test_classical_frames_arrive_with_exact_ids_flags_and_bytes(vcan_channel: str) -> None:
    with _bus(vcan_channel) as tx, _bus(vcan_channel) as rx:
        for sent in CLASSICAL_FRAMES:
            tx.send(sent)
        for sent, got in zip(CLASSICAL_FRAMES, _recv_all(rx, len(CLASSICAL_FRAMES)), strict=True):
            assert got.arbitration_id == sent.arbitration_id
            assert got.is_extended_id == sent.is_extended_id
            assert got.is_remote_frame == sent.is_remote_frame
            assert got.dlc == sent.dlc
            assert bytes(got.data) == (b"" if sent.is_remote_frame else bytes(sent.data))
            # python-can sets is_rx=False for every frame created on this host (MSG_DONTROUTE),
            # so on vcan is_rx cannot tell our frames from the simulator's: filter by COB-ID.
            assert not got.is_rx and not got.is_fd and not got.is_error_frame
            assert got.channel == vcan_channel


def test_many_frames_keep_order_and_timestamps_increase(vcan_channel: str) -> None:
    # below the 278 frames that fit an unread socket with the default 208 KiB SO_RCVBUF
    count = 250
    with _bus(vcan_channel) as tx, _bus(vcan_channel) as rx:
        for i in range(count):
            tx.send(can.Message(arbitration_id=0x200, data=struct.pack("<I", i), is_extended_id=False))
        received = _recv_all(rx, count)
    assert [struct.unpack("<I", m.data)[0] for m in received] == list(range(count))
    stamps = [m.timestamp for m in received]
    assert stamps == sorted(stamps)
    assert abs(stamps[-1] - time.time()) < 60.0  # wall-clock (SO_TIMESTAMPNS) seconds


def test_sender_receives_its_own_frames_only_when_asked(vcan_channel: str) -> None:
    frame = can.Message(arbitration_id=0x123, data=b"\x01\x02\x03", is_extended_id=False)
    with _bus(vcan_channel) as plain, _bus(vcan_channel, receive_own_messages=True) as echoing:
        plain.send(frame)
        echoing.send(frame)
        # plain sees only echoing's frame; echoing sees plain's and then its own
        assert plain.recv(timeout=RECV_TIMEOUT_S).arbitration_id == 0x123
        _marker(echoing)
        assert plain.recv(timeout=RECV_TIMEOUT_S).arbitration_id == 0x7EF
        first, own = _recv_all(echoing, 2)
        assert bytes(first.data) == bytes(own.data) == b"\x01\x02\x03"
        assert not first.is_rx and not own.is_rx  # both were created on this host
        # the marker echoing sent itself comes back to it as well
        assert echoing.recv(timeout=RECV_TIMEOUT_S).arbitration_id == 0x7EF


# ---- 2. CAN FD --------------------------------------------------------------------


def test_fd_frames_round_trip_with_brs(vcan_fd_channel: str) -> None:
    frames = [
        can.Message(
            arbitration_id=0x300 + n,
            data=bytes((n + i) % 256 for i in range(n)),
            is_fd=True,
            bitrate_switch=bool(n % 2) or n == 64,
            is_extended_id=False,
        )
        for n in CANFD_DATA_LENGTHS
    ]
    frames.append(
        can.Message(
            arbitration_id=0x1ABCDE01,
            data=bytes(range(64)),
            is_fd=True,
            bitrate_switch=True,
            error_state_indicator=True,
            is_extended_id=True,
        )
    )
    with _bus(vcan_fd_channel, fd=True) as tx, _bus(vcan_fd_channel, fd=True) as rx:
        for sent in frames:
            tx.send(sent)
        for sent, got in zip(frames, _recv_all(rx, len(frames)), strict=True):
            assert got.is_fd
            assert got.arbitration_id == sent.arbitration_id
            assert got.is_extended_id == sent.is_extended_id
            assert got.bitrate_switch == sent.bitrate_switch
            assert got.error_state_indicator == sent.error_state_indicator
            assert bytes(got.data) == bytes(sent.data)
            assert got.dlc == len(sent.data)


def test_classical_bus_does_not_receive_fd_frames(vcan_fd_channel: str) -> None:
    with _bus(vcan_fd_channel, fd=True) as tx, _bus(vcan_fd_channel) as classical:
        tx.send(can.Message(arbitration_id=0x310, data=bytes(64), is_fd=True, bitrate_switch=True))
        marker = _marker(tx)
        got = classical.recv(timeout=RECV_TIMEOUT_S)
    assert got is not None and got.arbitration_id == marker.arbitration_id and not got.is_fd


# ---- 3. full queues ---------------------------------------------------------------


def test_vcan_send_never_fails_and_an_idle_reader_loses_the_newest_frames(vcan_channel: str) -> None:
    """vcan has no qdisc to fill; overflow happens at the receiver, silently."""
    sent_count = 3000
    with _bus(vcan_channel) as tx, _bus(vcan_channel) as idle_reader:
        tx.socket.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 1)  # kernel minimum (4608 B)
        idle_reader.socket.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1)  # minimum too
        for i in range(sent_count):
            tx.send(can.Message(arbitration_id=0x400, data=struct.pack("<I", i), is_extended_id=False))
        kept = []
        while (msg := idle_reader.recv(timeout=0.5)) is not None:
            kept.append(struct.unpack("<I", msg.data)[0])
    assert 0 < len(kept) < sent_count
    assert kept == list(range(len(kept)))  # tail drop: the first frames stay, the newest are lost


@pytest.fixture
def throttled_vcan(vcan_channel: str) -> Iterator[str]:
    """vcan0 behind a tiny token-bucket qdisc: a transmit queue that really fills."""
    if os.geteuid() != 0 or shutil.which("tc") is None:
        pytest.skip("needs root and tc (iproute2) to attach a qdisc to vcan0")
    # 10 kbit/s drains ~78 classical frames/s; limit 64 B holds 4 frames (skb len 16 B)
    cmd = [
        "tc",
        "qdisc",
        "replace",
        "dev",
        vcan_channel,
        "root",
        "tbf",
        "rate",
        "10kbit",
        "burst",
        "160",
        "limit",
        "64",
    ]
    subprocess.run(cmd, check=True, capture_output=True, timeout=30)
    try:
        yield vcan_channel
    finally:
        subprocess.run(
            ["tc", "qdisc", "del", "dev", vcan_channel, "root"], check=True, capture_output=True, timeout=30
        )


def test_full_transmit_queue_raises_enobufs_and_recovers(throttled_vcan: str) -> None:
    frame = can.Message(arbitration_id=0x500, data=bytes(8), is_extended_id=False)
    with _bus(throttled_vcan) as tx:
        accepted = 0
        with pytest.raises(can.CanOperationError) as caught:
            for _ in range(10_000):
                tx.send(frame)
                accepted += 1
        assert caught.value.error_code == errno.ENOBUFS
        assert "No buffer space available" in str(caught.value)
        assert isinstance(caught.value.__cause__, OSError)
        assert 4 <= accepted < 10_000
        time.sleep(0.5)  # the bucket drains ~39 frames in 0.5 s
        tx.send(frame)  # works again


# ---- 4. error frames ----------------------------------------------------------------


@pytest.mark.parametrize("sender", ["python-can", "raw socket"])
def test_error_frames_are_delivered_and_flagged(vcan_channel: str, sender: str) -> None:
    can_id = CAN_ERR_BUSOFF | CAN_ERR_CRTL
    payload = bytes([0, 0x04, 0, 0, 0, 0, 0, 0])  # data[1] = CAN_ERR_CRTL_RX_WARNING
    with (
        _bus(vcan_channel) as rx,
        _bus(vcan_channel, ignore_rx_error_frames=True) as no_err,
        _bus(vcan_channel) as tx,
    ):
        if sender == "python-can":
            tx.send(
                can.Message(arbitration_id=can_id, data=payload, is_error_frame=True, is_extended_id=False)
            )
        else:
            with socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW) as raw:
                raw.bind((vcan_channel,))
                raw.send(struct.pack(CAN_FRAME_FMT, CAN_ERR_FLAG | can_id, len(payload), payload))
        marker = _marker(tx)
        got = rx.recv(timeout=RECV_TIMEOUT_S)
        assert got is not None and got.is_error_frame
        assert got.arbitration_id == can_id
        assert not got.is_extended_id and bytes(got.data) == payload
        assert rx.recv(timeout=RECV_TIMEOUT_S).arbitration_id == marker.arbitration_id
        first = no_err.recv(timeout=RECV_TIMEOUT_S)
        assert first.arbitration_id == marker.arbitration_id and not first.is_error_frame


def test_error_frame_without_class_bits_reaches_nobody(vcan_channel: str) -> None:
    with _bus(vcan_channel) as rx, _bus(vcan_channel) as tx:
        tx.send(can.Message(arbitration_id=0, data=bytes(8), is_error_frame=True, is_extended_id=False))
        marker = _marker(tx)
        first = rx.recv(timeout=RECV_TIMEOUT_S)
    assert first.arbitration_id == marker.arbitration_id and not first.is_error_frame
