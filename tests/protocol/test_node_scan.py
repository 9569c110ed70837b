"""``cheope nodes``: the bus as a commissioning tool sees it, and LSS for nodes without a node id,
against the simulator in-process on a ``virtual`` bus."""

from __future__ import annotations

import pytest

from controller.config import load_config
from controller.node_plan import node_setup_plan
from drivers.node_scan import NodeScanError, lss_fast_scan, nodes_table, scan_nodes
from drivers.node_setup import DRIVE_EDS, SENSOR_EDS, configure_nodes
from sim_backend.lss_slave import LssSlave
from sim_backend.server import SIM_SERIAL_BASE, Simulator

EDS = (DRIVE_EDS, SENSOR_EDS)


def test_the_scan_names_each_node_its_identity_state_error_code_and_mapping(buses):
    cfg = load_config(overrides={"sim.drive.quirks": ["boots_in_fault:2", "guarding_only:3"]})
    sim_bus, bus = buses
    with Simulator(cfg, sim_bus):
        nodes = scan_nodes(bus, EDS, listen_s=0.3)
    assert [n.node_id for n in nodes] == [1, 2, 3, 16]
    one, two, three, sensor = nodes
    assert (one.vendor_id, one.product_code, one.serial) == (0xCE0, 0x402, SIM_SERIAL_BASE | 1)
    # fresh from boot: no heartbeat yet (0x1017 is 0 until a master writes it), its state by guarding
    assert one.nmt_state == "PRE-OPERATIONAL" and one.supervision == "guarding"
    assert one.power_state == "SWITCH_ON_DISABLED" and one.error_code == 0
    assert two.power_state == "FAULT" and two.error_code == 0x3220  # its power stage is not up yet
    assert three.supervision == "guarding" and three.nmt_state == "PRE-OPERATIONAL"
    assert one.mapping["RPDO1"] == ["0x6040sub0 Controlword", "0x607Asub0 Target position"]
    assert one.mapping["TPDO1"][:2] == ["0x6041sub0 Statusword", "0x6064sub0 Position actual value"]
    assert sensor.statusword is None and "TPDO2" in sensor.mapping  # not a CiA 402 device
    text = nodes_table(nodes)
    assert (
        "node 2: vendor 0x00000CE0" in text
        and "power FAULT (statusword 0x0208), error code 0x603F 0x3220" in text
    )


def test_after_set_up_the_scan_shows_what_the_controller_configured(buses):
    cfg = load_config(
        overrides={
            "sensor.enabled": False,
            "sim.drive.quirks": ["fixed_mapping:1"],
            "node": [{"node_id": 1, "pdo_mapping": "read"}],
        }
    )
    sim_bus, bus = buses
    with Simulator(cfg, sim_bus):
        configure_nodes(bus, node_setup_plan(cfg))
        nodes = scan_nodes(bus, EDS, listen_s=0.3)
    assert all(n.nmt_state == "OPERATIONAL" and n.supervision == "heartbeat" for n in nodes)
    assert nodes[0].mapping["TPDO1"][2] == "0x6061sub0 Modes of operation display"  # its fixed mapping


@pytest.mark.slow  # two fast scans of ~130 requests each (10 s)
def test_lss_finds_the_nodes_without_an_id_and_gives_them_theirs(buses):
    cfg = load_config(
        overrides={"sensor.enabled": False, "sim.drive.quirks": ["unconfigured:2", "unconfigured:3"]}
    )
    sim_bus, bus = buses
    with Simulator(cfg, sim_bus):
        assert [n.node_id for n in scan_nodes(bus, EDS, listen_s=0.2)] == [1]  # 2 and 3 have no id
        found = lss_fast_scan(bus)
        assert [(f.serial, f.assigned) for f in found] == [(SIM_SERIAL_BASE | 2, None)]  # the lowest address
        assigned = lss_fast_scan(bus, (2, 3))
        assert [(f.serial, f.assigned) for f in assigned] == [
            (SIM_SERIAL_BASE | 2, 2),
            (SIM_SERIAL_BASE | 3, 3),
        ]
        assert [n.node_id for n in scan_nodes(bus, EDS, listen_s=0.2)] == [1, 2, 3]
        assert len(configure_nodes(bus, node_setup_plan(cfg)).drive_codecs) == 3  # and they run


def test_an_id_the_simulated_node_cannot_take_is_refused_by_name(buses):
    cfg = load_config(overrides={"sensor.enabled": False, "sim.drive.quirks": ["unconfigured:3"]})
    sim_bus, bus = buses
    with Simulator(cfg, sim_bus), pytest.raises(NodeScanError, match=r"serial 0x53494D03 refused node id 9"):
        lss_fast_scan(bus, (9,))


def test_the_lss_slave_answers_the_fast_scan_only_where_the_bits_match():
    slave = LssSlave((0xCE0, 0x402, 0x10000, 0x1234), frozenset({2}))

    def scan(id_number: int, bit: int, sub: int, nxt: int) -> bool:
        data = bytes((0x51, *id_number.to_bytes(4, "little"), bit, sub, nxt))
        return slave.on_request(data) is not None

    assert scan(0, 0x80, 0, 0)  # every unconfigured slave answers the reset
    assert scan(0, 31, 0, 0) and not scan(0, 11, 0, 0)  # 0xCE0 has bit 11 set
    assert scan(0xCE0, 0, 0, 1)  # part 0 confirmed: part 1 next
    assert not scan(0xCE0, 0, 0, 1)  # part 0 is done
