"""Fixtures shared by the protocol layer's tests."""

from __future__ import annotations

import time
from collections.abc import Iterator

import can
import canopen
import pytest

from controller.config import load_config
from sim_backend.server import Simulator


@pytest.fixture
def sim_and_master() -> Iterator[tuple[Simulator, canopen.Network]]:
    """A simulator without the sensor and a canopen master on the same virtual bus."""
    cfg = load_config(overrides={"sensor.enabled": False})
    channel = f"sim-and-master-{time.monotonic_ns()}"
    sim_bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=True)
    master_bus = can.Bus(interface="virtual", channel=channel)
    network = canopen.Network(master_bus)
    sim = Simulator(cfg, sim_bus)
    sim.start()
    network.connect()
    try:
        yield sim, network
    finally:
        network.sync.stop()
        network.disconnect()
        sim.stop()
        sim_bus.shutdown()


@pytest.fixture
def buses() -> Iterator[tuple[can.BusABC, can.BusABC]]:
    """(simulator's bus, controller's bus) on one virtual channel, shut down after the test."""
    channel = f"buses-{time.monotonic_ns()}"
    pair = (
        can.Bus(interface="virtual", channel=channel, receive_own_messages=True),
        can.Bus(interface="virtual", channel=channel, receive_own_messages=True),
    )
    yield pair
    for bus in pair:
        bus.shutdown()
