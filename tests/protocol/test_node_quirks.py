"""The nodes' own habits (sim_backend/quirks.py) over a bus: the simulator in-process on a python-can
``virtual`` bus, the controller's set-up (drivers/node_setup.py) as the master. Each is handled by
configuration alone; without it the set-up refuses with one line naming the node and the behaviour."""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable

import pytest

from controller.config import load_config
from controller.core.cia402 import PowerState
from controller.node_plan import node_setup_plan
from drivers.cyclic_exchange import CyclicExchange
from drivers.node_setup import NodeSetupError, SetupStoppedError, configure_nodes
from drivers.pdo_codec import PositionScale
from sim_backend.server import Simulator


def config(**overrides):
    return load_config(overrides={"sensor.enabled": False, **overrides})


def set_up(buses, cfg):
    sim_bus, bus = buses
    with Simulator(cfg, sim_bus) as sim:
        return configure_nodes(bus, node_setup_plan(cfg)), sim


def refused(buses, cfg, words: str) -> str:
    with pytest.raises(NodeSetupError, match=words) as err:
        set_up(buses, cfg)
    return str(err.value)


def test_a_node_that_boots_late_is_waited_for_up_to_its_boot_timeout(buses):
    late = {"sim.drive.quirks": ["late_boot:2"], "sim.quirk.boot_delay_s": 0.8}
    report, _ = set_up(buses, config(**late))
    assert any(n.startswith("node 2: booted late: first SDO answer after") for n in report.notes), (
        report.notes
    )


def test_a_node_that_boots_later_than_its_boot_timeout_is_named(buses):
    late = {"sim.drive.quirks": ["late_boot:2"], "sim.quirk.boot_delay_s": 0.8, "loop.boot_timeout_s": 0.3}
    refused(buses, config(**late), r"node 2 did not answer SDO requests within 0\.3 s .*loop\.boot_timeout_s")


def test_a_stop_requested_while_a_node_boots_ends_the_set_up_at_once(buses):
    """A signal or ``cheope stop`` during the wait for a silent node: before, the set-up waited out
    loop.boot_timeout_s (times its retries), past a service manager's stop timeout."""
    late = {"sim.drive.quirks": ["late_boot:1"], "sim.quirk.boot_delay_s": 60.0, "loop.boot_timeout_s": 600.0}
    cfg = config(**late)
    sim_bus, bus = buses
    stop = _StopAtCheck(2)  # node 1's set-up has begun: the stop comes inside its boot wait
    with (
        Simulator(cfg, sim_bus),
        pytest.raises(SetupStoppedError, match=r"node 1: stopped on request during its boot"),
    ):
        configure_nodes(bus, node_setup_plan(cfg), stop)


class _StopAtCheck(threading.Event):
    """A stop request that the set-up finds set from its ``n``-th look on."""

    def __init__(self, n: int) -> None:
        super().__init__()
        self.looks, self.n = 0, n

    def is_set(self) -> bool:
        self.looks += 1
        return self.looks >= self.n


def test_a_stop_requested_during_homing_ends_it_with_the_drive_disabled(buses):
    slow = {  # about 3 s to the switch at 0.1 m/s: the stop comes while the drive moves
        "actuators.homing_method": 17,
        "actuators.home_offsets_m": [0.32] * 3,
        "actuators.homing_switch_speed_m_s": 0.1,
        "actuators.homing_timeout_s": 600.0,
    }
    cfg = config(**slow)
    sim_bus, bus = buses
    stop = threading.Event()
    with Simulator(cfg, sim_bus) as sim:
        drive = sim.drives[0]
        homing = lambda: drive.mode_of_operation == 6 and drive.power == PowerState.OPERATION_ENABLED  # noqa: E731
        waiter = threading.Thread(target=_stop_when, args=(homing, stop))
        waiter.start()
        with pytest.raises(SetupStoppedError, match=r"node 1: stopped on request during homing"):
            configure_nodes(bus, node_setup_plan(cfg), stop)
        waiter.join()
        assert drive.power != PowerState.OPERATION_ENABLED and drive.position > 0.33  # not at its switch


def _stop_when(condition: Callable[[], bool], stop: threading.Event) -> None:
    deadline = time.monotonic() + 120.0
    while not condition() and time.monotonic() < deadline:
        time.sleep(0.005)
    stop.set()


def test_a_node_that_needs_an_nmt_reset_to_boot_gets_one(buses):
    quirk = {"sim.drive.quirks": ["needs_nmt_reset:3"], "loop.boot_timeout_s": 0.3}
    refused(buses, config(**quirk), r"node 3 did not answer .*loop\.boot_retries")
    report, _ = set_up(buses, config(**quirk, **{"loop.boot_retries": 1}))
    assert (
        "node 3: no SDO answer within 0.3 s: NMT reset node sent (1 of 1, loop.boot_retries)" in report.notes
    )


def test_slow_sdo_answers_are_waited_for_by_the_sdo_timeout(buses):
    slow = {"sim.drive.quirks": ["slow_sdo:1"]}  # 20-50 ms each
    refused(
        buses,
        config(**slow, **{"loop.sdo_timeout_s": 0.015}),
        r"node 1: reading 0x1018sub1: no answer within",
    )
    report, _ = set_up(buses, config(**slow, **{"node": [{"node_id": 1, "sdo_timeout_s": 0.1}]}))
    assert len(report.drive_codecs) == 3


def test_occasional_sdo_aborts_are_retried(buses):
    flaky = {"sim.drive.quirks": ["sdo_aborts"], "sim.quirk.sdo_abort_every": 7}
    refused(
        buses,
        config(**flaky),
        r"refused: Code 0x08000020.*\(refused for now, not for good: loop\.sdo_retries\)",
    )
    report, _ = set_up(buses, config(**flaky, **{"loop.sdo_retries": 1}))
    assert any("SDO transfer(s) repeated (loop.sdo_retries)" in n for n in report.notes), report.notes


def test_a_fixed_mapping_is_read_not_written(buses):
    fixed = {"sim.drive.quirks": ["fixed_mapping:2"]}
    sim_bus, bus = buses
    with Simulator(config(**fixed), sim_bus):
        with pytest.raises(
            NodeSetupError, match=r"node 2: writing 0x1600sub0 = 0x0 refused: Code 0x06010002"
        ) as err:
            configure_nodes(bus, node_setup_plan(config(**fixed)))
        assert '(a fixed PDO mapping: actuators.pdo_mapping = "read")' in str(err.value)
        # the refused remap left its RPDO1 invalid (the procedure's first step): reading makes it valid again
        cfg = config(**fixed, **{"node": [{"node_id": 2, "pdo_mapping": "read"}]})
        report = configure_nodes(bus, node_setup_plan(cfg))
    tpdo = report.drive_codecs[1].tpdo
    assert [(o.index, o.subindex) for o in tpdo.objects] == [(0x6041, 0), (0x6064, 0), (0x6061, 0)]
    assert "node 2: its RPDO1 was not valid: made valid again" in report.notes


def test_a_fixed_mapping_without_the_position_cannot_be_run(buses):
    cfg = config(
        **{
            "sim.drive.quirks": ["fixed_mapping:2"],
            "sim.quirk.fixed_tpdo_objects": ["0x6041", "0x606C"],
            "actuators.pdo_mapping": "read",
        }
    )
    refused(
        buses,
        cfg,
        r"node 2 .*must map the statusword 0x6041 and the position actual value 0x6064: the controller cannot run",
    )


def test_a_drive_without_heartbeat_is_supervised_by_node_guarding(buses):
    guarding = {"sim.drive.quirks": ["guarding_only"]}
    cfg = config(**guarding, **{"actuators.supervision": "guarding"})
    sim_bus, bus = buses
    with Simulator(cfg, sim_bus) as sim:
        with pytest.raises(
            NodeSetupError, match=r"writing 0x1017sub0 = 0x64 refused: Code 0x06020000"
        ) as err:
            configure_nodes(bus, node_setup_plan(config(**guarding)))
        assert 'a drive without heartbeat: actuators.supervision = "guarding"' in str(err.value)
        configure_nodes(bus, node_setup_plan(cfg))  # the same drives, started again with guarding
        assert all(d.heartbeat_consumer_s == pytest.approx(0.3) for d in sim.drives)  # 0x100C x 0x100D
        for guarded, lost in (({n: (0.1, 3) for n in (1, 2, 3)}, ()), ({}, (1, 2, 3))):
            ex = CyclicExchange(bus, (1, 2, 3), PositionScale(1e7), None, 100, 40, guarded=guarded)
            deadline = time.monotonic() + 1.0
            while time.monotonic() < deadline:  # 1 s of 100 Hz cycles
                ex.send(None)
                feedback = ex.collect(time.monotonic() + 0.01)
            # no heartbeat (not even after the refused 0x1017 write), only the answers to guarding
            assert feedback.lost_heartbeats == lost, guarded


def test_a_drive_without_node_guarding_refuses_it_by_name(buses):
    cfg = config(
        **{"sim.drive.quirks": ["heartbeat_only:3"], "node": [{"node_id": 3, "supervision": "guarding"}]}
    )
    refused(buses, cfg, r'node 3: writing 0x100Csub0 = 0x64 refused: .*supervision = "heartbeat"')


def test_a_drive_in_fault_at_start_is_reset_and_verified_with_its_error_code(buses):
    fault = {"sim.drive.quirks": ["boots_in_fault:1"], "sim.quirk.power_stage_ready_s": 0.6}
    refused(
        buses,
        config(**fault, **{"loop.enable_timeout_s": 0.3}),
        r"node 1 stays in FAULT after \d+ fault reset\(s\) in 0\.\d s: statusword 0x0208, error code 0x603F = 0x3220",
    )
    report, _sim = set_up(buses, config(**fault, **{"actuators.fault_reset_wait_s": 0.2}))
    assert any(
        n.startswith("node 1: was in FAULT at start (0x603F = 0x3220); reset after") for n in report.notes
    )


def test_the_identity_is_checked_to_the_revision_and_serial_where_configured(buses):
    refused(
        buses,
        config(node=[{"node_id": 2, "serial_number": 0x1234}]),
        r"node 2: identity 0x1018 sub 4 serial number reads 0x53494D02, expected 0x00001234",
    )
    refused(
        buses,
        config(**{"actuators.revision_number": 0x20000}),
        r"node 1: identity 0x1018 sub 3 revision number reads 0x00010000, expected 0x00020000",
    )
    report, _ = set_up(buses, config(**{"actuators.revision_number": 0x10000}))
    assert {i.revision for i in report.identities} == {0x10000}


def test_a_drive_that_reports_itself_homed_is_not_homed_again(buses):
    cfg = config(
        **{
            "actuators.homing_method": 37,
            "actuators.home_offsets_m": [0.71508, 0.56794, 0.42697],
            "actuators.homing_skip_if_homed": True,
        }
    )
    sim_bus, bus = buses
    with Simulator(cfg, sim_bus):
        first = configure_nodes(bus, node_setup_plan(cfg))
        second = configure_nodes(bus, node_setup_plan(cfg))  # a second start, the drives not restarted
    assert not any("homing skipped" in n for n in first.notes)
    assert sum("homing skipped" in n for n in second.notes) == 3


def test_a_drive_without_homing_is_named_and_runs_with_homing_off_for_it(buses):
    homing = {"actuators.homing_method": 37, "actuators.home_offsets_m": [0.71508, 0.56794, 0.42697]}
    quirk = {"sim.drive.quirks": ["no_homing:2"], **homing}
    refused(
        buses,
        config(**quirk),
        r"node 2: writing 0x6060sub0 = 0x6 refused: Code 0x06090030.*homing_method = 0",
    )
    report, sim = set_up(buses, config(**quirk, node=[{"node_id": 2, "homing_method": 0}]))
    assert math.isclose(report.initial_positions_counts[1] / 1e7, sim.drives[1].position, abs_tol=1e-6)
