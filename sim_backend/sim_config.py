"""The simulator's configuration: ``[sim]`` and its sub-tables, in the same file as the controller's.

The simulated devices read these (sim_backend/plant.py, drive.py, force_sensor.py,
contact_disk.py, fault_injection.py); the controller never does. ``check_sim_section`` is the
checks msgspec's types cannot express (the fault specs parse).
"""

from __future__ import annotations

from typing import Annotated, Literal

import msgspec

from controller.config_schema import ConfigError, Section, rng


class SimDriveSection(Section, frozen=True):
    """Simulated CiA 402 drive: a second-order position loop with drive-side limits."""

    bandwidth_hz: Annotated[float, rng(0.1, 10000.0)] = 60.0
    damping_ratio: Annotated[float, rng(0.05, 5.0)] = 0.9
    velocity_feedforward: Annotated[float, rng(0.0, 1.0)] = 1.0
    max_velocity_m_s: Annotated[float, rng(0.0, 100.0, lo_open=True)] = 2.0
    max_acceleration_m_s2: Annotated[float, rng(0.0, 1e5, lo_open=True)] = 40.0
    quick_stop_deceleration_m_s2: Annotated[float, rng(0.0, 1e5, lo_open=True)] = 5.0
    sync_timeout_s: Annotated[float, rng(0.001, 60.0)] = 0.05
    substep_s: Annotated[float, rng(1e-6, 0.01)] = 5.0e-4
    max_velocity_rad_s: Annotated[float, rng(0.0, 1e4, lo_open=True)] = 12.0  # rotary drives
    max_acceleration_rad_s2: Annotated[float, rng(0.0, 1e6, lo_open=True)] = 240.0
    quick_stop_deceleration_rad_s2: Annotated[float, rng(0.0, 1e6, lo_open=True)] = 30.0
    initial_positions_m: tuple[float, float, float] = (0.71508, 0.56794, 0.42697)  # TCP at (0.09, 0, 0.5) m
    # Cheope's linear motors: a cogging force A sin(2 pi q / period + phase) on each carriage, acting
    # through the structure's actuator stiffness (sim_backend/plant.py); 0 N disables it
    cogging_force_n: Annotated[float, rng(0.0, 1e4)] = 2.0
    cogging_period_m: Annotated[float, rng(0.0, 1.0, lo_open=True)] = 0.024
    cogging_phases_deg: tuple[float, float, float] = (0.0, 120.0, 240.0)


class SimSensorSection(Section, frozen=True):
    noise_std_n: Annotated[float, rng(0.0, 100.0)] = 0.05
    bias_n: tuple[float, float, float] = (0.10, -0.05, 0.02)
    range_n: Annotated[float, rng(0.0, 327.0, lo_open=True)] = 300.0
    seed: int = 1
    sample_rate_hz: Annotated[float, rng(1.0, 100000.0)] = 1000.0
    bandwidth_hz: Annotated[float, rng(0.1, 100000.0)] = 200.0


class SimDiskSection(Section, frozen=True):
    """The workpiece of the contour task; known to the simulator only (sim_backend/contact_disk.py)."""

    centre_m: tuple[float, float] = (0.002, -0.001)
    height_m: Annotated[float, rng(-10.0, 10.0)] = 0.50
    radius_m: Annotated[float, rng(0.0, 1.0, lo_open=True)] = 0.07
    thickness_m: Annotated[float, rng(0.0, 1.0, lo_open=True)] = 0.01
    tool_radius_m: Annotated[float, rng(0.0, 0.1)] = 0.0
    contact_stiffness_n_m: Annotated[float, rng(0.0, 1e12, lo_open=True)] = 1.0e6
    sensor_stiffness_n_m: Annotated[float, rng(0.0, 1e12, lo_open=True)] = 3.0e5
    contact_damping_n_s_m: Annotated[float, rng(0.0, 1e9)] = 200.0
    friction_coefficient: Annotated[float, rng(0.0, 2.0)] = 0.15


class SimSection(Section, frozen=True):
    drive: SimDriveSection = msgspec.field(default_factory=SimDriveSection)
    sensor: SimSensorSection = msgspec.field(default_factory=SimSensorSection)
    structure_damping_ratio: Annotated[float, rng(0.0, 10.0)] = 0.5
    structure_inertial_load: bool = True  # the structure also carries M times the drives' acceleration (plant.py)
    environment: Literal["auto", "free", "disk"] = "auto"
    disk: SimDiskSection = msgspec.field(default_factory=SimDiskSection)
    faults: tuple[str, ...] = ()  # fault injection, sim_backend/fault_injection.py: "drop:2@3.0+0.5", ...


def check_sim_section(sim: SimSection) -> None:
    from sim_backend.fault_injection import FaultSpecError, parse_fault  # pure parsing, no I/O

    for i, text in enumerate(sim.faults):
        try:
            parse_fault(text)
        except FaultSpecError as err:
            raise ConfigError(f"sim.faults[{i}]: {err}") from err
