"""The pure control law built from a configuration: robot and task from their registries,
Ruckig's limits in the actuators' unit, the safety reactions. No I/O: the service, the replay's
verification and the tools build the same law from the same configuration here.
"""

from __future__ import annotations

from dataclasses import dataclass

from controller.config import Config, ConfigError, SafetySection
from controller.configured_robot import actuator_units, robot_from_config
from controller.core.contact_guard import ContactGuardConfig
from controller.core.control_law import ControlLaw
from controller.core.law_config import LawConfig, SafetyConfig
from controller.core.periods import cycles_in
from controller.core.ports import CAPABILITIES, ActuatorUnit, ForceWitnessModel, Robot, missing_capability
from controller.core.setpoint_smoothing import AxisLimits, RuckigSmoother
from controller.errors import CheopeError, RefusedError
from controller.node_plan import emcy_reactions, fault_reset_config
from controller.robot_registry import ActuatorUnits
from controller.tasks.registry import BuiltTask, RunReport, TaskSettings, task_entry
from drivers.bus_load import BusLoad, compute_bus_load, cyclic_frames
from drivers.pdo_codec import TORQUE_ACTUAL
from drivers.pdo_mapping import parse_object_reference


def planned_bus_load(cfg: Config) -> BusLoad:
    """The cyclic traffic's share of the bus (drivers/bus_load.py), checked before anything opens:
    the drives' PDOs as the configuration maps them (the EDS's default, or ``actuators.*_objects``)."""
    from drivers.node_setup import DRIVE_EDS, description_drive_codec, device_description_path

    a = cfg.actuators
    codec = description_drive_codec(
        a.node_ids[0], device_description_path(a.eds_file, DRIVE_EDS), a.rpdo_objects, a.tpdo_objects
    )
    frames = cyclic_frames(
        cfg.loop.rate_hz,
        len(a.node_ids),
        cfg.sensor.enabled,
        1.0 / cfg.loop.heartbeat_period_s,
        drive_pdo_bytes=codec.rpdo.size,
        tracker_hz=cfg.tracker.rate_hz if cfg.tracker.enabled else 0.0,
        drive_tpdo_bytes=codec.tpdo.size,
    )
    return compute_bus_load(
        frames,
        cfg.bus.bitrate_bit_s,
        fd=cfg.bus.fd,
        data_bit_s=cfg.bus.data_bitrate_bit_s if cfg.bus.fd else None,
    )


def build_robot(cfg: Config) -> Robot:
    try:
        return robot_from_config(cfg)
    except ConfigError:  # a ValueError too, already naming its keys: not the model's geometry
        raise
    except ValueError as err:
        raise ConfigError(f"[robot.{cfg.robot.kind}] geometry is inconsistent: {err}") from err


def task_settings(cfg: Config, units: ActuatorUnits) -> TaskSettings:
    """The settings every task may read beside its own section."""
    return TaskSettings(
        robot_section=cfg.robot.model(),
        units=units,
        settle_tolerance_m=cfg.loop.settle_tolerance_m,
        max_contact_force_n=cfg.safety.max_contact_force_n,
        tracker_enabled=cfg.tracker.enabled,
        witness_tolerance_n=cfg.safety.contact.tolerance_n,
        guarded_move_force_n=cfg.safety.contact.guarded_move_force_n,
        max_contact_speed_m_s=cfg.safety.contact.max_contact_speed_m_s,
        cell_stiffness_n_m=cfg.safety.contact.cell_stiffness_n_m,
        period_s=cfg.period_s,
    )


def build_task(cfg: Config, robot: Robot, units: ActuatorUnits) -> BuiltTask:
    """The configured task for ``robot``; WorkspaceError / PlanningError when it cannot be run."""
    entry = task_entry(cfg.task.kind)
    section = cfg.task.model() if entry.section is not None else None
    try:
        built = entry.build(section, robot, task_settings(cfg, units))
    except (CheopeError, ValueError):  # a refusal, or a model's argument check: named already
        raise
    except Exception as err:  # a plug-in's build gone wrong: one line naming the task, not a traceback
        raise RefusedError(f"task {cfg.task.kind} could not be built: {type(err).__name__}: {err}") from err
    if not isinstance(built, BuiltTask):
        raise RefusedError(f"task {cfg.task.kind}'s build gave {type(built).__name__}, not a BuiltTask")
    return built


def safety_config(s: SafetySection, units: ActuatorUnits, period_s: float) -> SafetyConfig:
    """``[safety]`` for the law, its position limits in the actuators' unit (the _rad keys for rotary
    ones), its windows in cycles of ``period_s`` (controller/core/periods.py)."""
    rotary = units.unit == ActuatorUnit.RADIAN
    c = s.contact
    return SafetyConfig(
        max_contact_force_n=s.max_contact_force_n,
        sensor_stale_cycles=cycles_in(s.sensor_stale_s, period_s),
        on_sensor_stale=s.on_sensor_stale,
        on_sensor_saturated=s.on_sensor_saturated,
        on_heartbeat_lost=s.on_heartbeat_lost,
        on_error_frames=s.on_error_frames,
        max_consecutive_late_cycles=cycles_in(s.max_consecutive_late_s, period_s),
        on_late_cycles=s.on_late_cycles,
        max_position_jump=s.max_position_jump_rad if rotary else s.max_position_jump_m,
        following_window=s.following_window_rad if rotary else s.following_window_m,
        on_unknown_node=s.on_unknown_node,
        on_foreign_sync=s.on_foreign_sync,
        on_foreign_nmt=s.on_foreign_nmt,
        on_foreign_command=s.on_foreign_command,
        on_duplicate_frames=s.on_duplicate_frames,
        on_rejected_frames=s.on_rejected_frames,
        on_frame_flood=s.on_frame_flood,
        sensor_breach_retract_s=s.sensor_breach_retract_s,
        contact=ContactGuardConfig(
            free_space_force_n=c.free_space_force_n,
            guarded_move_force_n=c.guarded_move_force_n,
            max_contact_force_n=s.max_contact_force_n,
            max_contact_speed_m_s=c.max_contact_speed_m_s,
            witness_required=c.witness_required,
            tolerance_n=c.tolerance_n,
            tolerance_fraction=c.tolerance_fraction,
            inertia_fraction=c.inertia_fraction,
            inertia_time_constant_s=c.inertia_time_constant_s,
            disagreement_s=c.disagreement_s,
            sensor_suspect_s=c.sensor_suspect_s,
            sensor_frozen_s=c.sensor_frozen_s,
            reaction_s=c.reaction_s,
            back_off_distance_m=c.back_off_distance_m,
            back_off_speed_m_s=c.back_off_speed_m_s,
            back_off_acceleration_m_s2=c.back_off_acceleration_m_s2,
        ),
    )


def position_plausibility(units: ActuatorUnits, safety: SafetyConfig, period_s: float) -> tuple[float, float]:
    """What the exchange judges every drive candidate by (drivers/cyclic_exchange.py), in actuator
    units: the speed limit over one period, and the margin the law's jump check allows."""
    return units.max_velocity * period_s, safety.max_position_jump


@dataclass(frozen=True)
class Assembly:
    law: ControlLaw
    reports: tuple[RunReport, ...]  # the task's own run reports (observers with a summary)
    units: ActuatorUnits  # the actuators' unit and limits, resolved once for the whole run


def check_capabilities(cfg: Config, robot: Robot) -> None:
    """The robot has every optional capability its task calls (``TaskEntry.needs``): refused at start,
    naming what it lacks, never an AttributeError in the middle of a run."""
    for capability in task_entry(cfg.task.kind).needs:
        lacks = missing_capability(robot, capability)
        if lacks:
            raise ConfigError(
                f"task.kind = {cfg.task.kind!r} needs the robot's {capability.__name__} "
                f"({CAPABILITIES[capability]}: controller/plugin_api.py), and robot.kind = "
                f"{cfg.robot.kind!r} lacks {lacks}"
            )


def check_force_witness(cfg: Config, robot: Robot) -> None:
    """A task that reads the force sensor runs with the sensor's second witness, unless told not to:
    the drives must report their effort (0x6077 in their TPDO) and the robot must map it to a force."""
    if not (task_entry(cfg.task.kind).uses_force_sensor and cfg.safety.contact.witness_required):
        return
    fix = "or set safety.contact.witness_required = false to run on the force sensor alone"
    if missing_capability(robot, ForceWitnessModel):
        raise ConfigError(
            f"task.kind = {cfg.task.kind!r} reads the force sensor, and robot.kind = {cfg.robot.kind!r} cannot "
            f"tell the contact force from its drives' efforts (the sensor's second witness); {fix}"
        )
    if not any(parse_object_reference(o) == TORQUE_ACTUAL for o in cfg.actuators.tpdo_objects):
        raise ConfigError(
            f"task.kind = {cfg.task.kind!r} reads the force sensor: its second witness is the drives' effort, "
            f"the torque actual value 0x6077, which actuators.tpdo_objects = {list(cfg.actuators.tpdo_objects)} "
            f'does not map; add "0x6077" {fix}'
        )


def assemble(cfg: Config, robot: Robot | None = None) -> Assembly:
    robot = robot or build_robot(cfg)
    check_capabilities(cfg, robot)
    check_force_witness(cfg, robot)
    a = actuator_units(cfg)  # m or rad
    built = build_task(cfg, robot, a)
    n = robot.n_actuators
    reaction_jerk = max(a.max_jerk, a.max_acceleration / cfg.safety.contact.reaction_ramp_s)
    limits = AxisLimits(
        (a.max_velocity,) * n, (a.max_acceleration,) * n, (a.max_jerk,) * n, (reaction_jerk,) * n
    )
    law_cfg = LawConfig(
        period_s=cfg.period_s,
        enable_timeout_s=cfg.loop.enable_timeout_s,
        hold_before_task_s=cfg.loop.hold_before_task_s,
        max_missing_cycles=cycles_in(cfg.loop.max_missing_s, cfg.period_s),
        max_bus_silence_cycles=cycles_in(cfg.loop.max_bus_silence_s, cfg.period_s),
        settle_tolerance=cfg.loop.settle_tolerance_m,
        safety=safety_config(cfg.safety, a, cfg.period_s),
        max_speed=a.max_velocity,
        position_unit=a.unit.value,
        rest_target=0.5 * (a.stroke_min + a.stroke_max),
        drive_node_ids=tuple(cfg.actuators.node_ids),
        sensor_in_task=task_entry(cfg.task.kind).uses_force_sensor,
        sensor_node_id=cfg.sensor.node_id if cfg.sensor.enabled else 0,
        task_retracts_on_sensor_breach=task_entry(cfg.task.kind).retracts_on_sensor_breach,
        fault_resets=tuple(fault_reset_config(cfg, node) for node in cfg.actuators.node_ids),
        emcy_reactions=emcy_reactions(cfg),
        drive_extrapolation_periods=cfg.drive_extrapolation_periods,
    )
    return Assembly(
        ControlLaw(robot, built.task, RuckigSmoother(limits, cfg.period_s), law_cfg), built.reports, a
    )


def build_law(cfg: Config, robot: Robot | None = None) -> ControlLaw:
    return assemble(cfg, robot).law
