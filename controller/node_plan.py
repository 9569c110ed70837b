"""Each node's values from the configuration: the defaults of [loop] and [actuators] with its
own [[node]] table on top, and the devices' set-up plan (drivers/node_setup.py) built from them.

One place resolves them, so the set-up (boot and SDO timeouts, identity, supervision, the PDO
mapping, the fault reset over SDO, homing) and the control law (the fault reset by controlword)
see the same value for the same drive.
"""

from __future__ import annotations

from typing import TypeVar

from controller.config import Config, ConfigError, NodeSection, emcy_code_ranges
from controller.configured_robot import actuator_units
from controller.core.cia402 import FaultResetConfig
from controller.core.law_config import EmcyReaction
from controller.robot_registry import ActuatorUnits
from controller.tasks.registry import task_entry
from drivers.homing import HomingPlan
from drivers.node_setup import DRIVE_EDS, SENSOR_EDS, NodeOptions, NodeSetupPlan, device_description_path


def node_section(cfg: Config, node_id: int) -> NodeSection:
    """The node's [[node]] table (an empty one where it has none)."""
    for n in cfg.node:
        if n.node_id == node_id:
            return n
    return NodeSection(node_id=node_id)


T = TypeVar("T")


def _pick(own: T | None, default: T) -> T:
    return default if own is None else own


def fault_reset_config(cfg: Config, node_id: int) -> FaultResetConfig:
    a, n = cfg.actuators, node_section(cfg, node_id)
    return FaultResetConfig(
        hold_s=_pick(n.fault_reset_hold_s, a.fault_reset_hold_s),
        wait_s=_pick(n.fault_reset_wait_s, a.fault_reset_wait_s),
        attempts=_pick(n.fault_reset_attempts, a.fault_reset_attempts),
    )


def emcy_reactions(cfg: Config) -> tuple[EmcyReaction, ...]:
    return tuple(EmcyReaction(*r) for r in emcy_code_ranges(cfg.actuators.emcy_reactions))


def node_options(cfg: Config, node_id: int) -> NodeOptions:
    """What the set-up does with node ``node_id`` (a drive or the sensor)."""
    a, lp, n = cfg.actuators, cfg.loop, node_section(cfg, node_id)
    is_drive = node_id in cfg.actuators.node_ids
    return NodeOptions(
        boot_timeout_s=_pick(n.boot_timeout_s, lp.boot_timeout_s),
        boot_retries=_pick(n.boot_retries, lp.boot_retries),
        sdo_timeout_s=_pick(n.sdo_timeout_s, lp.sdo_timeout_s),
        sdo_retries=_pick(n.sdo_retries, lp.sdo_retries),
        revision=_pick(n.revision_number, a.revision_number if is_drive else None),
        serial=n.serial_number,
        supervision=_pick(n.supervision, a.supervision),
        guard_time_s=a.guard_time_s,
        life_time_factor=a.life_time_factor,
        pdo_mapping=_pick(n.pdo_mapping, a.pdo_mapping),
        fault_reset=fault_reset_config(cfg, node_id),
        fault_reset_timeout_s=lp.enable_timeout_s,
    )


def homing_plans(cfg: Config, units: ActuatorUnits) -> tuple[HomingPlan | None, ...] | None:
    """Each drive's homing (drivers/homing.py) in counts, None for a drive that does not home; None
    when no drive homes."""
    a = cfg.actuators
    per_unit = units.counts_per_unit
    plans: list[HomingPlan | None] = []
    for node_id, offset in zip(a.node_ids, a.home_offsets_m, strict=False):
        n = node_section(cfg, node_id)
        method = _pick(n.homing_method, a.homing_method)
        if method == 0:
            plans.append(None)
            continue
        plans.append(
            HomingPlan(
                method=method,
                home_offset_counts=_counts("actuators.home_offsets_m", offset, per_unit, signed=True),
                switch_speed_counts_s=_counts(
                    "actuators.homing_switch_speed_m_s", a.homing_switch_speed_m_s, per_unit
                ),
                zero_speed_counts_s=_counts(
                    "actuators.homing_zero_speed_m_s", a.homing_zero_speed_m_s, per_unit
                ),
                acceleration_counts_s2=_counts(
                    "actuators.homing_acceleration_m_s2", a.homing_acceleration_m_s2, per_unit
                ),
                timeout_s=a.homing_timeout_s,
                done=_pick(n.homing_done, a.homing_done),
                position_window_counts=max(1, round(a.homing_position_window_m * per_unit)),
                skip_if_homed=_pick(n.homing_skip_if_homed, a.homing_skip_if_homed),
                enable_timeout_s=cfg.loop.enable_timeout_s,
            )
        )
    return tuple(plans) if any(p is not None for p in plans) else None


def _counts(key: str, value: float, counts_per_unit: float, signed: bool = False) -> int:
    """``value`` in encoder counts for a drive's 32-bit object (0x607C INTEGER32, the speeds,
    acceleration and window UNSIGNED32): a value that does not fit is the configuration's error,
    named here, before the bus is opened (a home offset of 1e300 m failed at the SDO write as
    "Value does not fit in specified type", naming nothing)."""
    scaled = value * counts_per_unit  # 1e300 m at 1e9 counts/m: infinity, which round() refuses
    lo, hi = (-(2**31), 2**31 - 1) if signed else (0, 2**32 - 1)
    if not lo - 0.5 < scaled < hi + 0.5:
        kind = "INTEGER32" if signed else "UNSIGNED32"
        raise ConfigError(
            f"{key} = {value:g}: {scaled:.3g} counts at {counts_per_unit:g} counts per unit "
            f"do not fit the drive's {kind} object"
        )
    return round(scaled)


def _following_error_objects(cfg: Config, units: ActuatorUnits) -> dict[str, int]:
    """0x6065 in encoder counts and 0x6066 in ms from ``[actuators]`` (the _rad keys for rotary drives)."""
    a = cfg.actuators
    window = a.following_error_window_rad if units.unit.value == "rad" else a.following_error_window_m
    key = "actuators.following_error_window_" + ("rad" if units.unit.value == "rad" else "m")
    return {
        "following_error_window_counts": _counts(key, window, units.counts_per_unit),
        "following_error_time_ms": round(a.following_error_time_s * 1000),
    }


def expected_environment(cfg: Config) -> str:
    """The world the controller announces to a simulated sensor: sim.environment when set, else its task's."""
    explicit: str = cfg.sim.environment
    return explicit if explicit != "auto" else task_entry(cfg.task.kind).sim_environment


def node_setup_plan(cfg: Config) -> NodeSetupPlan:
    units = actuator_units(cfg)
    sensor_id = cfg.sensor.node_id if cfg.sensor.enabled else None
    nodes = (*cfg.actuators.node_ids, *((sensor_id,) if sensor_id is not None else ()))
    return NodeSetupPlan(
        drive_ids=tuple(cfg.actuators.node_ids),
        sensor_id=sensor_id,
        vendor_id=cfg.actuators.vendor_id,
        drive_product_code=cfg.actuators.product_code,
        sensor_product_code=cfg.sensor.product_code,
        controller_id=cfg.loop.controller_node_id,
        heartbeat_period_s=cfg.loop.heartbeat_period_s,
        heartbeat_consumer_s=cfg.loop.heartbeat_consumer_s,
        cycle_period_s=cfg.period_s,
        extrapolation_periods=cfg.drive_extrapolation_periods,
        sync_watchdog_ms=cfg.drive_sync_watchdog_ms,
        drive_eds=device_description_path(cfg.actuators.eds_file, DRIVE_EDS),
        sensor_eds=device_description_path(cfg.sensor.eds_file, SENSOR_EDS),
        sensor_vendor_id=cfg.sensor.vendor_id,
        drive_rpdo_objects=cfg.actuators.rpdo_objects,
        drive_tpdo_objects=cfg.actuators.tpdo_objects,
        homing=homing_plans(cfg, units),
        **_following_error_objects(cfg, units),
        sim_environment=expected_environment(cfg) if cfg.sensor.enabled else None,
        task_kind=cfg.task.kind,
        nodes={node: node_options(cfg, node) for node in nodes},
    )
