"""The simulated drive is a CiA 402 device to outside tools: canopen's BaseNode402 drives it.

The simulator runs in-process on a python-can ``virtual`` bus; the master side is the
canopen package's own Network, BaseNode402, PDO and SYNC classes, not this project's driver.
"""

from __future__ import annotations

import time

from canopen.profiles.p402 import BaseNode402

from drivers.node_setup import DRIVE_EDS


def _wait(predicate, timeout_s=3.0):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.01)
    return False


def test_base_node_402_enables_the_drive_and_moves_it(sim_and_master):
    sim, network = sim_and_master
    node = BaseNode402(1, str(DRIVE_EDS))
    network.add_node(node)
    node.nmt.state = "PRE-OPERATIONAL"
    node.setup_402_state_machine()  # uploads the PDO configuration over SDO
    assert node.sdo[0x1018][1].raw == 0x00000CE0
    node.op_mode = "CYCLIC SYNCHRONOUS POSITION"
    assert node.op_mode == "CYCLIC SYNCHRONOUS POSITION"
    node.nmt.state = "OPERATIONAL"
    network.sync.start(0.01)

    start_counts = node.sdo[0x6064].raw
    rpdo = node.rpdo[1]
    rpdo["Target position"].raw = start_counts
    rpdo["Controlword"].raw = 0x0006
    rpdo.start(0.01)
    assert _wait(lambda: node.state == "SWITCH ON DISABLED")

    node.state = "OPERATION ENABLED"  # BaseNode402 walks 2 -> 3 -> 4 through the controlword
    assert node.state == "OPERATION ENABLED"
    assert sim.drives[0].power.name == "OPERATION_ENABLED"

    for target_m in (0.56, 0.58, 0.57):
        rpdo["Target position"].raw = round(target_m * 1e7)
        assert _wait(lambda target_m=target_m: abs(node.tpdo_values[0x6064] - target_m * 1e7) < 50), (
            f"drive did not reach {target_m} m: at {node.tpdo_values[0x6064] / 1e7} m"
        )

    node.state = "SWITCH ON DISABLED"
    assert node.state == "SWITCH ON DISABLED"
    rpdo.stop()
