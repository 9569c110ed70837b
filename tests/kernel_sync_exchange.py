"""The exchange the kernel-SYNC tests drive (tests/protocol/test_kernel_sync.py, tests/vcan/): one
drive (node 1), the controller node 100, no SYNC of its own, as ``KernelSyncExchange`` needs it (the
kernel's broadcast manager sends the SYNC)."""

from __future__ import annotations

import can

from drivers.cyclic_exchange import CyclicExchange
from drivers.pdo_codec import PositionScale


def quiet_exchange(
    bus: can.BusABC, sync_period_s: float = 0.0, heartbeat_every: int = 10**9
) -> CyclicExchange:
    return CyclicExchange(
        bus,
        (1,),
        PositionScale(1e7),
        None,
        100,
        heartbeat_every=heartbeat_every,
        send_sync=False,
        sync_period_s=sync_period_s,
    )
