"""The cyclic PDO path: this project's ``CyclicExchange`` against the ``canopen`` package's PDO objects, and a frame's cost on each bus."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Protocol, cast

import numpy as np

from controller.tools.bench.statistics import percentiles_us
from drivers import cob_ids

if TYPE_CHECKING:
    from queue import SimpleQueue

    import can

    class StubBus(can.BusABC):
        """The bus ``stub_bus`` returns, declared for the type checker: the class itself is made
        there, so that python-can is imported only when the PDO comparison runs."""

        queue: SimpleQueue[can.Message]
        sent: int


def stub_bus() -> StubBus:
    """A python-can bus that costs (almost) nothing: sends are counted, frames to receive are
    queued by the caller. Lets the PDO comparison measure the PDO path, not a transport
    (python-can's virtual bus deep-copies every frame for every receiver, ~10 us each)."""
    import queue

    import can

    class _StubBus(can.BusABC):
        def __init__(self) -> None:
            self.queue: queue.SimpleQueue[can.Message] = queue.SimpleQueue()
            self.sent = 0
            super().__init__(channel="stub")

        def send(self, msg: can.Message, timeout: float | None = None) -> None:
            self.sent += 1

        def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
            try:
                return self.queue.get(timeout=timeout) if timeout else self.queue.get_nowait(), False
            except queue.Empty:
                return None, False

    return cast("StubBus", _StubBus())  # the same attributes as StubBus, declared above


def compare_pdo_paths(
    cycles: int, config_path: str | None = None, overrides: list[str] | None = None
) -> dict[str, object]:
    """CPU time per cycle of the cyclic PDO path: this project's exchange vs canopen's PDO objects.

    Both run the same cycle on a stub bus (``stub_bus``): 3 RPDOs and SYNC out, then the 3 drive
    TPDOs and 2 sensor TPDOs (prebuilt frames, queued by the "device") received, decoded and
    turned into SI values. canopen's arm uses ``RemoteNode`` PDO maps read from the shipped EDS
    files: it sets the mapped variables and calls ``transmit`` per RPDO and ``sync.transmit``,
    then waits until its notifier thread has dispatched all five TPDOs (a semaphore released
    by PDO callbacks) and reads the mapped values. CPU time is the process's (both threads).
    """
    import can
    import canopen

    from controller.config import load_config, parse_override
    from controller.core.cycle_data import CycleOutputs
    from drivers.cyclic_exchange import CyclicExchange
    from drivers.pdo_codec import FORCE_N_PER_COUNT, TORQUE_NM_PER_COUNT, PositionScale, encode_drive_tpdo
    from sim_backend.server import DRIVE_EDS, SENSOR_EDS

    cfg = load_config(config_path, dict(parse_override(s) for s in (overrides or [])))
    ids = tuple(cfg.actuators.node_ids)
    sid = cfg.sensor.node_id
    scale = PositionScale(cfg.actuators.counts_per_m)
    tpdos = [
        can.Message(
            arbitration_id=cob_ids.tpdo1(i),
            data=encode_drive_tpdo(0x1237, 5_000_000 + i),
            is_extended_id=False,
        )
        for i in ids
    ]
    tpdos += [
        can.Message(
            arbitration_id=cob_ids.tpdo1(sid), data=bytes([1, 0, 2, 0, 3, 0, 0, 7]), is_extended_id=False
        ),
        can.Message(
            arbitration_id=cob_ids.tpdo2(sid), data=bytes([4, 0, 5, 0, 6, 0, 0, 7]), is_extended_id=False
        ),
    ]
    outputs = CycleOutputs(controlwords=(0x0F,) * len(ids), targets=(0.5,) * len(ids))

    def measure(cycle: Callable[[], None]) -> tuple[float, float]:
        for _ in range(min(500, cycles)):
            cycle()
        c0, w0 = time.process_time(), time.perf_counter()
        for _ in range(cycles):
            cycle()
        return (time.process_time() - c0) / cycles * 1e6, (time.perf_counter() - w0) / cycles * 1e6

    results: dict[str, object] = {
        "cycles": cycles,
        "frames_per_cycle": {"out": len(ids) + 1, "in": len(tpdos)},
    }
    bus = stub_bus()
    # the cost of decoding a cycle, not of waiting out its answer window
    ex = CyclicExchange(
        bus, ids, scale, sid, cfg.loop.controller_node_id, heartbeat_every=10**9, answer_window_s=0.0
    )

    def project_cycle() -> None:
        ex.send(outputs)
        for m in tpdos:
            bus.queue.put(m)
        inputs = ex.collect(time.monotonic() + 0.01)
        if inputs.sensor is None or not inputs.sensor.fresh:
            raise RuntimeError("project arm: sensor frames missing")

    project_cpu_us, project_wall_us = (round(x, 2) for x in measure(project_cycle))
    results["project_cpu_us"], results["project_wall_us"] = project_cpu_us, project_wall_us
    bus.shutdown()
    bus = stub_bus()
    net = canopen.Network(bus)
    net.connect()
    try:
        nodes = [net.add_node(i, str(DRIVE_EDS)) for i in ids]
        sensor = net.add_node(sid, str(SENSOR_EDS))
        arrived = threading.Semaphore(0)
        for node in nodes:
            _read_from_od(node.rpdo)
            _read_from_od(node.tpdo)
            node.tpdo[1].add_callback(lambda _m: arrived.release())
        _read_from_od(sensor.tpdo)
        sensor.tpdo[1].add_callback(lambda _m: arrived.release())
        sensor.tpdo[2].add_callback(lambda _m: arrived.release())
        rpdos = [n.rpdo[1] for n in nodes]
        rvars = [(m["Controlword"], m["Target position"]) for m in rpdos]
        tvars = [(n.tpdo[1]["Statusword"], n.tpdo[1]["Position actual value"]) for n in nodes]
        fvars, tqvars = list(sensor.tpdo[1])[:3], list(sensor.tpdo[2])[:3]

        def canopen_cycle() -> None:
            for m, (cw, tp), c, x in zip(rpdos, rvars, outputs.controlwords, outputs.targets, strict=True):
                cw.raw = c
                tp.raw = scale.to_counts(x)
                m.transmit()
            net.sync.transmit()
            for m in tpdos:
                bus.queue.put(m)
            for _ in range(len(tpdos)):
                if not arrived.acquire(timeout=1.0):
                    raise RuntimeError("canopen arm: a TPDO did not arrive")
            _ = [(sw.raw, scale.to_unit(pos.raw)) for sw, pos in tvars]
            _ = [v.raw * FORCE_N_PER_COUNT for v in fvars] + [v.raw * TORQUE_NM_PER_COUNT for v in tqvars]

        canopen_cpu_us, canopen_wall_us = (round(x, 2) for x in measure(canopen_cycle))
        results["canopen_cpu_us"], results["canopen_wall_us"] = canopen_cpu_us, canopen_wall_us
    finally:
        net.disconnect()
    results["canopen_over_project"] = round(canopen_cpu_us / project_cpu_us, 2)
    return results


class _PdoMaps(Protocol):
    """canopen's ``RPDO``/``TPDO`` map collections (``PdoBase``), whose ``read`` is unannotated."""

    def read(self, from_od: bool = False) -> None: ...


def _read_from_od(maps: _PdoMaps) -> None:
    """Set up the PDO maps from the object dictionary (the EDS), not over SDO."""
    maps.read(from_od=True)


def bus_frame_cost(spec_text: str, fd: bool, frames: int = 2000) -> dict[str, object]:
    """Wall time of python-can's ``send`` and ``recv`` per frame on the configured bus.

    Two buses on the same channel, one frame at a time (send, a 200 µs pause, receive), so
    each ``recv`` finds its frame waiting: the cost of the interface itself (on udp_multicast:
    msgpack and a datagram per frame), not of waiting. Also counts how many of the sender's
    own frames come back to it: every one is a receive the loop pays for and discards.
    """
    import can

    from controller.shell.demo import random_udp_port
    from drivers.bus import open_bus, parse_bus_spec

    spec = parse_bus_spec(spec_text, fd=fd, udp_port=random_udp_port())
    tx, rx = open_bus(spec), open_bus(spec)
    msg = can.Message(arbitration_id=0x201, data=bytes(8), is_extended_id=False, is_fd=fd, bitrate_switch=fd)
    send_us, recv_us = np.empty(frames), np.empty(frames)
    own = 0
    try:
        for k in range(frames):
            t0 = time.perf_counter()
            tx.send(msg)
            t1 = time.perf_counter()
            time.sleep(2e-4)
            t2 = time.perf_counter()
            got = rx.recv(timeout=0.1)
            t3 = time.perf_counter()
            if got is None:
                raise RuntimeError(f"bus_frame_cost: frame {k} did not arrive on {spec}")
            send_us[k], recv_us[k] = (t1 - t0) * 1e6, (t3 - t2) * 1e6
            own += tx.recv(timeout=0.0) is not None
    finally:
        tx.shutdown()
        rx.shutdown()
    return {
        "bus": str(spec),
        "frames": frames,
        "send_us": percentiles_us(send_us),
        "recv_us": percentiles_us(recv_us),
        "own_frames_received_back": own,
    }
