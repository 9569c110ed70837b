"""``bus.sync_producer = "kernel"`` off SocketCAN: refused before anything opens, naming the key.

Its behaviour on SocketCAN is tested in tests/vcan/test_kernel_sync_on_vcan.py.
"""

from __future__ import annotations

import can
import pytest

from controller.config import ConfigError, load_config
from controller.shell.service import run_controller
from drivers.bus import parse_bus_spec
from drivers.cyclic_exchange import CyclicExchange
from drivers.kernel_sync import KernelSyncError, KernelSyncExchange
from drivers.pdo_codec import PositionScale


def test_kernel_sync_on_a_bus_without_a_broadcast_manager_is_refused_before_the_bus_opens(monkeypatch):
    def no_bus(*args, **kwargs):
        raise AssertionError("the bus was opened")

    monkeypatch.setattr("controller.shell.service.open_bus", no_bus)
    cfg = load_config(overrides={"bus.sync_producer": "kernel", "recording.enabled": False,
                                 "monitoring.enabled": False})
    with pytest.raises(KernelSyncError, match=r"bus.sync_producer = 'kernel' needs a socketcan bus.*udp_multicast"):
        run_controller(cfg, parse_bus_spec("udp_multicast"))


def test_an_unknown_sync_producer_is_a_configuration_error():
    with pytest.raises(ConfigError, match=r"bus.sync_producer = 'bcm'"):
        load_config(overrides={"bus.sync_producer": "bcm"})


def test_the_kernel_exchange_needs_an_exchange_that_sends_no_sync():
    with can.Bus(interface="virtual", channel="kernel-sync-check") as bus:
        ex = CyclicExchange(bus, (1,), PositionScale(1e7), None, 100, heartbeat_every=1)
        with pytest.raises(ValueError, match="send_sync=False"):
            KernelSyncExchange(ex, 0.0025, 0.0005)
        quiet = CyclicExchange(bus, (1,), PositionScale(1e7), None, 100, heartbeat_every=1, send_sync=False)
        with pytest.raises(ValueError, match="lead 0.003 s must be within the period 0.0025 s"):
            KernelSyncExchange(quiet, 0.0025, 0.003)
