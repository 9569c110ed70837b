"""The task's world comes from the controller: its set-up announces the environment to the simulator.

A simulator started without the task (sim.environment = "auto", task.kind at its default) places
what the controller's task needs when the controller writes it over SDO (drivers/sim_environment.py);
one configured to another environment refuses, and the controller's start fails with one line.
"""

from __future__ import annotations

import canopen
import pytest

from controller.config import load_config
from controller.node_plan import node_setup_plan
from drivers.node_setup import NodeSetupError, configure_nodes
from drivers.sim_environment import SIM_ENVIRONMENT_INDEX
from sim_backend.contact_disk import DiskEnvironment
from sim_backend.environment import FreeSpace
from sim_backend.server import Simulator


def test_a_simulator_started_without_the_task_places_the_disk_the_controllers_contour_needs(buses):
    sim_bus, bus = buses
    with Simulator(load_config(), sim_bus) as sim:  # the path task by default: free space
        assert isinstance(sim.plant.environment, FreeSpace) and not sim.plant.loaded
        configure_nodes(bus, node_setup_plan(load_config(overrides={"task.kind": "contour"})))
        assert isinstance(sim.plant.environment, DiskEnvironment) and sim.plant.loaded
        sensor = sim.nodes[load_config().sensor.node_id]
        assert sensor.sdo[SIM_ENVIRONMENT_INDEX].raw == 1


def test_the_next_controller_with_a_path_task_gets_free_space_again(buses):
    sim_bus, bus = buses
    with Simulator(load_config(overrides={"task.kind": "contour"}), sim_bus) as sim:
        assert sim.plant.loaded
        configure_nodes(bus, node_setup_plan(load_config()))
        assert isinstance(sim.plant.environment, FreeSpace) and not sim.plant.loaded


def test_a_simulator_configured_to_another_environment_refuses_and_the_start_fails_in_one_line(buses):
    sim_bus, bus = buses
    with Simulator(load_config(overrides={"sim.environment": "free"}), sim_bus) as sim:
        with pytest.raises(NodeSetupError) as err:
            configure_nodes(bus, node_setup_plan(load_config(overrides={"task.kind": "contour"})))
        assert isinstance(sim.plant.environment, FreeSpace)
    message = str(err.value)
    assert "\n" not in message
    assert (
        'sim.environment = "free"' in message
        and 'task.kind = "contour"' in message
        and "workpiece" in message
    )


def test_a_sensor_without_the_object_is_a_real_one_and_the_set_up_goes_on(buses, monkeypatch):
    sim_bus, bus = buses
    with Simulator(load_config(), sim_bus) as sim:
        od = sim.nodes[load_config().sensor.node_id].object_dictionary
        del od.indices[SIM_ENVIRONMENT_INDEX]  # as the real sensor's dictionary: no such object
        od.names.pop("Simulated environment", None)
        report = configure_nodes(bus, node_setup_plan(load_config(overrides={"task.kind": "contour"})))
        assert report.sensor_codecs is not None and isinstance(sim.plant.environment, FreeSpace)


def test_an_unknown_environment_code_is_refused_by_the_simulator(buses):
    sim_bus, bus = buses
    cfg = load_config()
    with Simulator(cfg, sim_bus):
        network = canopen.Network(bus)
        network.connect()
        try:
            node = network.add_node(cfg.sensor.node_id)
            with pytest.raises(canopen.SdoAbortedError, match="0x06090030"):
                node.sdo.download(SIM_ENVIRONMENT_INDEX, 0, bytes([7]))
        finally:
            network.disconnect()
