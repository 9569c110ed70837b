"""A controller process (``controller run``) beside the simulator process on a ``udp_multicast`` bus
of their own, as the integration tests start them, and what those tests watch of the robot: drive
1 moving under the controller, the drives read back over SDO."""

from __future__ import annotations

import random
import struct
import subprocess
import sys
import threading
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import can
import canopen
from busy_machine import TOLERANT
from waiting import wait_until

from controller.core.cia402 import PowerState, decode_statusword
from controller.shell.demo import simulator_process, stop_process
from drivers.bus import BusSpec, open_bus, parse_bus_spec
from drivers.node_setup import DRIVE_EDS

LAPS = 3  # far longer than any of these tests watches the robot


def child_running(parent_pid: int, module: str) -> int | None:
    """The pid of ``parent_pid``'s child process running ``python -m module`` (the recording's
    writer, the CPU shield's guardian), None while there is none."""
    try:
        children = Path(f"/proc/{parent_pid}/task/{parent_pid}/children").read_text().split()
    except OSError:
        return None
    for pid in children:
        try:
            if module.encode() in Path(f"/proc/{pid}/cmdline").read_bytes():
                return int(pid)
        except OSError:
            continue
    return None


def run_sets(tmp_path: Path, *more: str) -> list[str]:
    """``--set`` options of a path run of LAPS laps recorded into ``tmp_path``, without monitoring,
    tolerant of a busy machine (TOLERANT), then ``more``."""
    return [
        "--set",
        f"task.path.laps={LAPS}",
        "--set",
        f'recording.directory="{tmp_path}"',
        "--set",
        "monitoring.enabled=false",
        *TOLERANT,
        *more,
    ]


@dataclass
class ControllerOnTheBus:
    spec: BusSpec
    bus: can.BusABC  # a socket of the test's on the same bus
    process: subprocess.Popen[str]
    simulator: subprocess.Popen[str]  # its process (a test stops it with SIGSTOP: the host's pause)


@contextmanager
def controller_beside_simulator(
    options: list[str], stderr: int = subprocess.PIPE
) -> Iterator[ControllerOnTheBus]:
    """The simulator, a bus socket of the test's and ``controller run --json --no-realtime`` with
    ``options`` on a bus of their own; the controller is stopped (by process id) when the block ends."""
    spec = parse_bus_spec("udp_multicast", udp_port=random.SystemRandom().randint(48000, 49999))
    command = [sys.executable, "-m", "controller", "run", "--json", "--no-realtime"]
    with simulator_process(spec, None, [f"task.path.laps={LAPS}"]) as simulator, open_bus(spec) as bus:
        process = subprocess.Popen(
            [*command, "--udp-port", str(spec.udp_port), *options],
            stdout=subprocess.PIPE,
            stderr=stderr,
            text=True,
        )
        try:
            yield ControllerOnTheBus(spec, bus, process, simulator)
        finally:
            stop_process(process)


def wait_until_drive_1_moves(bus: can.BusABC, ctrl: subprocess.Popen[str]) -> None:
    """Drive 1's TPDOs: OPERATION ENABLED, 2 mm from where this began to watch, and still moving."""
    start: int | None = None
    last: int | None = None

    def moving() -> bool:
        nonlocal start, last
        assert ctrl.poll() is None, ctrl.communicate()
        msg = bus.recv(timeout=0.1)
        if msg is None or msg.arbitration_id != 0x181 or len(msg.data) < 6:
            return False
        statusword, counts = struct.unpack_from("<Hi", msg.data)  # then its effort (cheope.toml's mapping)
        if decode_statusword(statusword) != PowerState.OPERATION_ENABLED:
            return False
        start = counts if start is None else start
        step, last = (abs(counts - last) if last is not None else 0), counts
        return abs(counts - start) > 20_000 and step > 10  # 2 mm travelled (1e7 counts/m), > 1 um per cycle

    wait_until(moving, "drive 1 moving under the controller", poll_s=0.0)


@contextmanager
def another_master(spec: BusSpec, frames: Sequence[can.Message]) -> Iterator[None]:
    """A master on ``spec`` while the block runs: ``frames`` (its SYNC, its heartbeat) every 10 ms,
    from a thread of this test, stopped and joined at the block's end."""
    stop = threading.Event()
    with open_bus(spec) as master:

        def send() -> None:
            while not stop.wait(0.01):
                for frame in frames:
                    master.send(frame)

        thread = threading.Thread(target=send, name="another master")
        thread.start()
        try:
            yield
        finally:
            stop.set()
            thread.join()


SYNC = can.Message(arbitration_id=0x080, data=b"", is_extended_id=False)


@contextmanager
def drives_over_sdo(spec: BusSpec, node_ids: tuple[int, ...]) -> Iterator[canopen.Network]:
    """A CANopen network of the drives on a socket of its own: the test's ``bus`` socket stops being
    read once the robot moves, and its buffer, full of the run's frames, dropped an SDO answer once
    (CI) before canopen's notifier drained it."""
    network = canopen.Network(open_bus(spec))
    network.connect()
    try:
        for node_id in node_ids:
            node = canopen.RemoteNode(node_id, str(DRIVE_EDS))
            node.sdo.RESPONSE_TIMEOUT = 2.0
            network.add_node(node)
        yield network
    finally:
        network.disconnect()
