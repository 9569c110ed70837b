"""The simulator's configuration: ``[sim]`` and its sub-tables, in the same file as the controller's.

The simulated devices read these (sim_backend/plant.py, drive.py, force_sensor.py,
contact_disk.py, workpiece.py, fault_injection.py); the controller never does. ``check_sim_section`` is the
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
    sync_timeout_s: Annotated[float, rng(0.001, 60.0)] = 0.1
    substep_s: Annotated[float, rng(1e-6, 0.01)] = 5.0e-4
    max_velocity_rad_s: Annotated[float, rng(0.0, 1e4, lo_open=True)] = 12.0  # rotary drives
    max_acceleration_rad_s2: Annotated[float, rng(0.0, 1e6, lo_open=True)] = 240.0
    quick_stop_deceleration_rad_s2: Annotated[float, rng(0.0, 1e6, lo_open=True)] = 30.0
    initial_positions_m: tuple[float, ...] = (0.71508, 0.56794, 0.42697)  # TCP at (0.09, 0, 0.5) m
    # Incremental encoders: each drive reports its true position plus this offset until homed (rad
    # for rotary drives); the homing limit switches close below / above these true positions.
    encoder_offsets_m: tuple[float, ...] = (0.0, 0.0, 0.0)
    limit_switches_m: tuple[float, float] = (0.32, 0.88)
    # Cheope's linear motors: a cogging force A sin(2 pi q / period + phase) on each carriage, acting
    # through the structure's actuator stiffness (sim_backend/plant.py); 0 N disables it
    cogging_force_n: Annotated[float, rng(0.0, 1e4)] = 2.0
    cogging_period_m: Annotated[float, rng(0.0, 1.0, lo_open=True)] = 0.024
    cogging_phases_deg: tuple[float, float, float] = (0.0, 120.0, 240.0)
    # A real drive's habits (sim_backend/quirks.py): "NAME" for every drive, "NAME:NODE" for one
    # node (the node's own, such as late_boot or slow_sdo, may name the sensor); [sim.quirk] holds
    # their values. [] is the ideal CiA 402 drive.
    quirks: tuple[str, ...] = ()


class SimQuirkSection(Section, frozen=True):
    """The values of the quirks ``sim.drive.quirks`` names (sim_backend/quirks.py says what each does)."""

    power_stage_ready_s: Annotated[float, rng(0.0, 60.0)] = 3.0  # boots_in_fault: FAULT this long after boot
    fault_reset_hold_s: Annotated[float, rng(0.0, 5.0)] = 0.05  # fault_reset_hold: bit 7 held this long
    transition_delay_s: Annotated[float, rng(0.0, 5.0)] = 0.3  # slow_power_states: each transition up
    boot_delay_s: Annotated[float, rng(0.0, 60.0)] = 3.0  # late_boot: boot-up this long after power-on
    sdo_delay_min_s: Annotated[float, rng(0.0, 5.0)] = 0.02  # slow_sdo: each answer this late ...
    sdo_delay_max_s: Annotated[float, rng(0.0, 5.0)] = 0.05  # ... to this late (uniform, seeded)
    sdo_abort_every: Annotated[int, rng(2, 1000)] = 10  # sdo_aborts: every n-th request aborted
    # fixed_mapping: the TPDO1 it has and keeps ("INDEX" or "INDEX:SUB"; its RPDO1 is the EDS's)
    fixed_tpdo_objects: tuple[str, ...] = ("0x6041", "0x6064", "0x6061")
    warning_emcy_code: Annotated[int, rng(0x0001, 0xFFFF)] = 0xFF01  # warning_emcy_on_enable
    bus_off_after_s: Annotated[float, rng(0.0, 3600.0)] = 2.0  # bus_off: error passive, after the first SYNC
    error_passive_s: Annotated[float, rng(0.0, 60.0)] = 0.2  # then bus-off this much later
    bus_off_restart_s: Annotated[float, rng(0.0, 60.0)] = 0.5  # and the bus restarted after this
    seed: Annotated[int, rng(0, 2**32 - 1)] = 3  # slow_sdo's delays (numpy's seeds are unsigned)


class SimSensorSection(Section, frozen=True):
    noise_std_n: Annotated[float, rng(0.0, 100.0)] = 0.05
    bias_n: tuple[float, float, float] = (0.10, -0.05, 0.02)
    range_n: Annotated[float, rng(0.0, 327.0, lo_open=True)] = 300.0
    seed: Annotated[int, rng(0, 2**32 - 1)] = 1
    sample_rate_hz: Annotated[float, rng(1.0, 100000.0)] = 1000.0
    bandwidth_hz: Annotated[float, rng(0.1, 100000.0)] = 200.0


class SimFeatureSection(Section, frozen=True):
    """A notch (``depth_m`` > 0) or bump (``depth_m`` < 0) on the workpiece's boundary (sim_backend/workpiece.py)."""

    angle_deg: Annotated[float, rng(-360.0, 360.0)] = (
        0.0  # its middle, about the workpiece's centre (before rotation)
    )
    length_m: Annotated[float, rng(0.0, 0.5, lo_open=True)] = 0.01  # along the boundary
    depth_m: Annotated[float, rng(-0.01, 0.01)] = 0.002  # inwards; negative: a raised stretch (bump)


class SimWorkpieceSection(Section, frozen=True):
    """The contour task's workpiece; known to the simulator only (sim_backend/workpiece.py, contact_disk.py)."""

    shape: Literal["disk", "ellipse", "rounded_rectangle", "rounded_star", "kidney"] = "disk"
    centre_m: tuple[float, float] = (0.002, -0.001)
    rotation_deg: Annotated[float, rng(-360.0, 360.0)] = 0.0  # about +Z, of the shape's own frame
    height_m: Annotated[float, rng(-10.0, 10.0)] = 0.50
    radius_m: Annotated[float, rng(0.0, 1.0, lo_open=True)] = 0.07  # disk; star and kidney: mean radius
    size_m: tuple[
        Annotated[float, rng(0.0, 1.0, lo_open=True)], Annotated[float, rng(0.0, 1.0, lo_open=True)]
    ] = (0.08, 0.06)  # ellipse: semi-axes; rectangle: half extents
    corner_radius_m: Annotated[float, rng(0.0, 1.0)] = 0.004  # rounded rectangle
    lobes: Annotated[int, rng(2, 12)] = 5  # rounded star
    lobe_depth_m: Annotated[float, rng(0.0, 0.5)] = 0.008  # star: lobe amplitude; kidney: depth of its dent
    features: tuple[SimFeatureSection, ...] = ()  # notches and bumps
    thickness_m: Annotated[float, rng(0.0, 1.0, lo_open=True)] = 0.01
    tool_radius_m: Annotated[float, rng(0.0, 0.1)] = 0.0
    contact_stiffness_n_m: Annotated[float, rng(0.0, 1e12, lo_open=True)] = 1.0e6
    sensor_stiffness_n_m: Annotated[float, rng(0.0, 1e12, lo_open=True)] = 3.0e5
    contact_damping_n_s_m: Annotated[float, rng(0.0, 1e9)] = 200.0
    friction_coefficient: Annotated[float, rng(0.0, 2.0)] = 0.15


class SimNspuSection(Section, frozen=True):
    """The simulated 3-nSPU's difference from the controller's model (issue 20: model mismatch).

    The simulator integrates the platform with this geometry; the controller plans and streams
    with its own (``[robot.nspu]``).  All zero: the two are the same.
    """

    leg_offset_m: tuple[float, float, float] = (0.0, 0.0, 0.0)  # physical leg length minus encoder reading
    w4_axis_error_rad: tuple[float, float, float] = (
        0.0,
        0.0,
        0.0,
    )  # platform U-joint axis w4i turned about z x w4i
    r_axis_error_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)  # nS-plane normal r_i turned about z x r_i
    # the platform starts this far from the plan's start position (orientation kept); the drives read its legs
    start_offset_m: tuple[float, float, float] = (0.0, 0.0, 0.0)


class SimTrackerSection(Section, frozen=True):
    """The simulated pose tracker on the 3-nSPU's platform ([tracker] enabled): sim_backend/pose_tracker.py."""

    rate_hz: Annotated[float, rng(0.1, 10000.0)] = 100.0  # samples a second (at most one per SYNC)
    position_noise_m: Annotated[float, rng(0.0, 0.01)] = 5.0e-5  # standard deviation of each coordinate
    angle_noise_rad: Annotated[float, rng(0.0, 0.1)] = 2.0e-4  # of each rotation-vector component
    seed: Annotated[int, rng(0, 2**32 - 1)] = 2


class SimSection(Section, frozen=True):
    drive: SimDriveSection = msgspec.field(default_factory=SimDriveSection)
    sensor: SimSensorSection = msgspec.field(default_factory=SimSensorSection)
    structure_damping_ratio: Annotated[float, rng(0.0, 10.0)] = 0.5
    structure_inertial_load: bool = (
        True  # the structure also carries M times the drives' acceleration (plant.py)
    )
    # "auto": what the controller's task announces at set-up (drivers/sim_environment.py); "free"/"workpiece"
    # fixed, and a controller whose task needs the other one is refused at its start
    environment: Literal["auto", "free", "workpiece"] = "auto"
    workpiece: SimWorkpieceSection = msgspec.field(default_factory=SimWorkpieceSection)
    nspu: SimNspuSection = msgspec.field(default_factory=SimNspuSection)
    tracker: SimTrackerSection = msgspec.field(default_factory=SimTrackerSection)
    faults: tuple[str, ...] = ()  # fault injection, sim_backend/fault_injection.py: "drop:2@3.0+0.5", ...
    quirk: SimQuirkSection = msgspec.field(default_factory=SimQuirkSection)


def check_sim_section(
    sim: SimSection, drive_nodes: tuple[int, ...], sensor_node: int | None, period_s: float
) -> None:
    """The faults parse, name nodes on the configured bus, have sane values and can fire at the
    loop's period ``period_s`` (--inject); the 3-nSPU's model mismatch stays a mismatch."""
    for key in ("leg_offset_m", "w4_axis_error_rad", "r_axis_error_rad", "start_offset_m"):
        vals = getattr(sim.nspu, key)
        limit = 0.01 if key.endswith("_m") else 0.1
        if not all(abs(v) <= limit for v in vals):
            raise ConfigError(
                f"sim.nspu.{key} = {list(vals)}: each must be within +-{limit} (a mismatch, not a new robot)"
            )
    from controller.sim_config.fault_specs import FaultSpecError, check_fault
    from controller.sim_config.quirk_specs import QuirkSpecError, check_quirk

    for i, text in enumerate(sim.faults):
        try:
            check_fault(text, drive_nodes, sensor_node, period_s)
        except FaultSpecError as err:
            raise ConfigError(f"sim.faults[{i}]: {err}") from err
    for i, text in enumerate(sim.drive.quirks):
        try:
            check_quirk(text, drive_nodes, sensor_node)
        except QuirkSpecError as err:
            raise ConfigError(f"sim.drive.quirks[{i}]: {err}") from err
    low, high = sim.drive.limit_switches_m
    if not low < high:
        raise ConfigError(
            f"sim.drive.limit_switches_m = {[low, high]}: the negative switch must lie below the positive one"
        )
    q = sim.quirk
    if q.sdo_delay_max_s < q.sdo_delay_min_s:
        raise ConfigError(
            f"sim.quirk.sdo_delay_max_s = {q.sdo_delay_max_s}: must be >= sim.quirk.sdo_delay_min_s = "
            f"{q.sdo_delay_min_s}"
        )
