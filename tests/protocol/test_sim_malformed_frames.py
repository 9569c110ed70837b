"""Frames the simulated devices cannot parse, and a failure of their thread (sim_backend/server.py).

A 1-byte NMT command or an empty SDO request raised ``struct.error`` inside canopen's NMT or SDO
server and ended the simulator's devices' thread: the process ran on deaf, its heartbeats still
saying OPERATIONAL, the drives enabled whatever their master sent (an outside tester's find).
"""

from __future__ import annotations

import threading

import can
import canopen
from waiting import wait_until

from drivers.node_setup import DRIVE_EDS
from sim_backend.server import Simulator


def _frame(cob_id: int, data: bytes, extended: bool = False) -> can.Message:
    return can.Message(arbitration_id=cob_id, data=data, is_extended_id=extended)


def test_frames_canopen_cannot_parse_are_rejected_and_the_devices_answer_on(
    sim_and_master: tuple[Simulator, canopen.Network],
) -> None:
    sim, network = sim_and_master
    for msg in (
        _frame(0x000, b"\x01"),  # NMT: 1 byte
        _frame(0x601, b""),  # SDO request: empty
        _frame(0x601, b"\x40\x00\x10"),  # SDO request: 3 bytes
    ):
        network.bus.send(msg)
    wait_until(lambda: sim.rejected_frames >= 3, "the three frames rejected", poll_s=0.01)
    node = canopen.RemoteNode(1, str(DRIVE_EDS))
    network.add_node(node)
    assert len(node.sdo.upload(0x1000, 0)) == 4  # node 1's SDO server answers on
    assert sim.failure is None and sim._thread is not None and sim._thread.is_alive()


def test_a_29_bit_frame_reaches_no_device(sim_and_master: tuple[Simulator, canopen.Network]) -> None:
    """Its identifier only looks like a COB-ID: an SDO read on the extended id 0x601 is not answered."""
    sim, network = sim_and_master
    answers: list[can.Message] = []
    network.subscribe(0x581, lambda cob, data, t: answers.append(data))
    read_device_type = bytes((0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0))
    network.bus.send(_frame(0x601, read_device_type, extended=True))
    network.bus.send(_frame(0x601, read_device_type))  # the same read on the 11-bit id, after it
    wait_until(lambda: answers, "the 11-bit read answered", poll_s=0.01)
    # the devices take frames in order: an answer to the 29-bit read would have come first
    assert len(answers) == 1 and sim.rejected_frames >= 1


def test_a_failure_of_the_devices_thread_silences_them_and_ends_the_process(
    sim_and_master: tuple[Simulator, canopen.Network],
) -> None:
    sim, network = sim_and_master
    ended = threading.Event()
    sim.on_failure = ended.set

    def broken(data: bytearray, now: float) -> None:
        raise RuntimeError("a bug in the SYNC handler")

    sim._fast[0x080] = broken
    network.bus.send(_frame(0x080, b""))
    assert ended.wait(10.0)
    assert isinstance(sim.failure, RuntimeError)
    assert all(node.nmt._send_task is None for node in sim.nodes.values())  # no heartbeat producer left
    assert sim._thread is not None
    sim._thread.join(10.0)
    assert not sim._thread.is_alive()
