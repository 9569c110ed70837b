"""Configuration: TOML files mapped onto frozen dataclasses, validated once at start.

Every value has its unit in its name. A value outside its allowed range, of the wrong type,
or an unknown key is rejected with a ``ConfigError`` naming the key, the value and the
reason. ``controller/configs/cheope.toml`` holds the defaults and documents every key.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

CONFIG_DIR = Path(__file__).parent / "configs"
DEFAULT_CONFIG = CONFIG_DIR / "cheope.toml"


class ConfigError(ValueError):
    """Invalid configuration; the message names the key, the value and what is allowed."""


def _r(lo: float | None = None, hi: float | None = None, *, lo_open: bool = False) -> dict[str, Any]:
    return {"range": (lo, hi, lo_open)}


@dataclass(frozen=True)
class CheopeSection:
    rod_length_m: float = field(default=0.50, metadata=_r(0.0, 10.0, lo_open=True))
    axis_tilt_deg: float = field(default=60.0, metadata=_r(1.0, 89.0))
    axis_azimuths_deg: tuple[float, float, float] = (0.0, 90.0, 180.0)
    platform_radius_m: float = field(default=0.05, metadata=_r(0.0, 1.0))
    platform_azimuths_deg: tuple[float, float, float] = (0.0, 90.0, 180.0)
    joint_neutral_tcp_m: tuple[float, float, float] = (0.0, 0.0, 0.50)
    joint_swing_limit_deg: float = field(default=22.0, metadata=_r(0.0, 90.0, lo_open=True))
    stroke_min_m: float = field(default=0.30, metadata=_r(-10.0, 10.0))
    stroke_max_m: float = field(default=0.90, metadata=_r(-10.0, 10.0))


@dataclass(frozen=True)
class MarginsSection:
    """Minimum distances from the singularity classes of seed 001 §5.1 and a conditioning bound."""

    min_direct_measure: float = field(default=0.20, metadata=_r(0.0, 1.0))
    min_inverse_measure: float = field(default=0.20, metadata=_r(0.0, 1.0))
    min_structural_measure: float = field(default=0.20, metadata=_r(0.0, 1.0))
    max_condition_number: float = field(default=10.0, metadata=_r(1.0, 1e6))


@dataclass(frozen=True)
class MassSection:
    platform_kg: float = field(default=8.0, metadata=_r(0.0, 1000.0))
    slider_kg: float = field(default=1.0, metadata=_r(0.0, 1000.0))
    rod_pair_kg: float = field(default=0.4, metadata=_r(0.0, 1000.0))
    actuator_stiffness_n_m: float = field(default=2.0e5, metadata=_r(0.0, 1e12, lo_open=True))


@dataclass(frozen=True)
class UruSection:
    """LaMaViP 3-URU (seed 003); see controller/robots/uru.py and controller/robots/uru_robot.py."""

    base_offset_m: float = field(default=0.10, metadata=_r(0.0, 10.0))
    platform_offset_m: float = field(default=0.10, metadata=_r(0.0, 10.0))
    proximal_lengths_m: tuple[float, float, float] = field(default=(0.20, 0.20, 0.20), metadata=_r(0.0, 10.0, lo_open=True))
    distal_lengths_m: tuple[float, float, float] = field(default=(0.20, 0.20, 0.20), metadata=_r(0.0, 10.0, lo_open=True))
    gear_ratios: tuple[float, float, float] = field(default=(1.0, 1.0, 1.0), metadata=_r(-1000.0, 1000.0))
    motor_offsets_rad: tuple[float, float, float] = field(default=(0.0, 0.0, 0.0), metadata=_r(-100.0, 100.0))
    knee_sign: int = field(default=1, metadata=_r(-1, 1))
    home_position_m: tuple[float, float, float] = (0.12, 0.12, 0.12)  # the simulator starts here
    motor_min_rad: float = field(default=-3.2, metadata=_r(-1000.0, 1000.0))  # motor-shaft range (drive stroke)
    motor_max_rad: float = field(default=4.8, metadata=_r(-1000.0, 1000.0))
    min_plane_distance_m: float = field(default=0.02, metadata=_r(0.0, 10.0))  # rotation loci eq. (17)
    min_det_v: float = field(default=0.05, metadata=_r(0.0, 1.0))  # translation eq. (20)
    min_det_s: float = field(default=0.05, metadata=_r(0.0, 1e6))  # actuation eq. (35)
    min_det_a: float = field(default=0.05, metadata=_r(0.0, 1e6))  # combined eq. (36)
    min_sin_th3: float = field(default=0.10, metadata=_r(0.0, 1.0))  # serial eq. (27)
    min_workspace_margin_m: float = field(default=0.02, metadata=_r(0.0, 10.0))  # boundary eq. (29)


@dataclass(frozen=True)
class NspuSection:
    """3-nSPU (seeds 000, 004): seed 000 §3.5 geometry, start and goal poses, planner, streaming."""

    length_unit_m: float = field(default=0.01, metadata=_r(0.0, 10.0, lo_open=True))  # the papers' aul
    r3_variant: str = field(default="symmetric", metadata={"choices": ("symmetric", "printed")})
    leg_min_m: float = field(default=0.20, metadata=_r(0.0, 10.0))
    leg_max_m: float = field(default=0.70, metadata=_r(0.0, 10.0))
    start_position_m: tuple[float, float, float] = (0.0, 0.0, 0.25)
    start_rpy_rad: tuple[float, float, float] = (0.0, 0.0, -0.5236)
    goal_position_m: tuple[float, float, float] = (-0.0185, -0.0251, 0.2713)
    goal_rpy_rad: tuple[float, float, float] = (0.075, 0.31, -0.532)
    horizon_s: float = field(default=1.0, metadata=_r(0.0, 1000.0, lo_open=True))  # plan time T
    harmonics: int = field(default=2, metadata=_r(0, 10))
    tolerance: float = field(default=1e-3, metadata=_r(0.0, 1.0, lo_open=True))
    max_iterations: int = field(default=50, metadata=_r(0, 10000))
    n_steps: int = field(default=200, metadata=_r(4, 100000))
    check_type2: bool = True  # refuse plans that cross the type-II locus (seed 000 eq. (26))
    restarts: int = field(default=0, metadata=_r(0, 100))
    stream_steps: int = field(default=1000, metadata=_r(10, 1000000))  # resolution of the streamed plan
    limit_fraction: float = field(default=0.5, metadata=_r(0.0, 1.0, lo_open=True))  # of the actuator limits


@dataclass(frozen=True)
class RobotSection:
    kind: str = field(default="cheope", metadata={"choices": ("cheope", "uru", "nspu")})
    cheope: CheopeSection = CheopeSection()
    uru: UruSection = UruSection()
    nspu: NspuSection = NspuSection()
    margins: MarginsSection = MarginsSection()
    mass: MassSection = MassSection()


@dataclass(frozen=True)
class ActuatorsSection:
    node_ids: tuple[int, int, int] = (1, 2, 3)
    counts_per_m: float = field(default=1.0e7, metadata=_r(1.0, 1e12))
    # Rotary actuators (robot.kind = "uru": motor-shaft angles) use these instead of the _m keys.
    counts_per_rad: float = field(default=166886.05, metadata=_r(1.0, 1e12))  # 2^20 counts per turn
    max_velocity_rad_s: float = field(default=6.0, metadata=_r(0.0, 1e4, lo_open=True))
    max_acceleration_rad_s2: float = field(default=60.0, metadata=_r(0.0, 1e6, lo_open=True))
    max_jerk_rad_s3: float = field(default=3000.0, metadata=_r(0.0, 1e9, lo_open=True))
    max_velocity_m_s: float = field(default=1.0, metadata=_r(0.0, 100.0, lo_open=True))
    max_acceleration_m_s2: float = field(default=10.0, metadata=_r(0.0, 1e4, lo_open=True))
    max_jerk_m_s3: float = field(default=500.0, metadata=_r(0.0, 1e7, lo_open=True))
    vendor_id: int = field(default=0x00000CE0, metadata=_r(0, 2**32 - 1))
    product_code: int = field(default=0x00000402, metadata=_r(0, 2**32 - 1))


@dataclass(frozen=True)
class SensorSection:
    enabled: bool = True
    node_id: int = field(default=16, metadata=_r(1, 127))
    product_code: int = field(default=0x00000F75, metadata=_r(0, 2**32 - 1))


@dataclass(frozen=True)
class BusSection:
    can: str = "udp_multicast"
    udp_port: int = field(default=43113, metadata=_r(1, 65535))
    fd: bool = False
    bitrate_bit_s: float = field(default=1.0e6, metadata=_r(1e4, 1e6))
    data_bitrate_bit_s: float = field(default=5.0e6, metadata=_r(1e5, 1.2e7))
    max_load_percent: float = field(default=70.0, metadata=_r(1.0, 100.0))


@dataclass(frozen=True)
class LoopSection:
    rate_hz: float = field(default=400.0, metadata=_r(1.0, 4000.0))
    collect_fraction: float = field(default=0.8, metadata=_r(0.05, 0.95))
    spin_us: float = field(default=300.0, metadata=_r(0.0, 5000.0))
    gil_switch_interval_us: float = field(default=200.0, metadata=_r(1.0, 100000.0))
    freeze_gc: bool = True  # gc.freeze() the start-up heap before the loop (controller/shell/realtime.py)
    max_missing_cycles: int = field(default=5, metadata=_r(1, 1000))
    heartbeat_period_s: float = field(default=0.1, metadata=_r(0.01, 10.0))
    heartbeat_consumer_s: float = field(default=0.5, metadata=_r(0.02, 60.0))
    controller_node_id: int = field(default=100, metadata=_r(1, 127))
    enable_timeout_s: float = field(default=2.0, metadata=_r(0.01, 60.0))
    sdo_timeout_s: float = field(default=1.0, metadata=_r(0.01, 60.0))
    stay_in_fault: bool = False  # keep cycling in FAULT (quick stop held) until a remote reset or a stop
    hold_before_task_s: float = field(default=0.2, metadata=_r(0.0, 60.0))
    settle_tolerance_m: float = field(default=2.0e-5, metadata=_r(0.0, 1.0, lo_open=True))


_REACTIONS = {"choices": ("fault", "warn", "ignore")}


@dataclass(frozen=True)
class SafetySection:
    """What the law does about each abnormal input (see controller/core/control_law.py, ``_safety``).

    "fault": quick stop through the controlword and stay in FAULT until a reset;
    "warn": record a warning event once per episode and go on; "ignore": nothing.
    Drive faults, EMCY, missing TPDOs (loop.max_missing_cycles), a bus-off, an actuator
    outside its stroke and a task reference outside the safe workspace always fault.
    """

    max_contact_force_n: float = field(default=60.0, metadata=_r(0.0, 10000.0, lo_open=True))
    sensor_stale_cycles: int = field(default=5, metadata=_r(1, 100000))
    on_sensor_stale: str = field(default="fault", metadata=_REACTIONS)
    on_sensor_saturated: str = field(default="fault", metadata=_REACTIONS)
    on_heartbeat_lost: str = field(default="fault", metadata=_REACTIONS)
    on_error_frames: str = field(default="warn", metadata=_REACTIONS)
    max_consecutive_late_cycles: int = field(default=50, metadata=_r(1, 1000000))
    on_late_cycles: str = field(default="fault", metadata=_REACTIONS)
    late_tolerance_fraction: float = field(default=0.5, metadata=_r(0.01, 10.0))


@dataclass(frozen=True)
class PathSection:
    """A circle in a plane parallel to XY: the first task of issue 2."""

    center_m: tuple[float, float, float] = (0.0, 0.0, 0.50)
    radius_m: float = field(default=0.08, metadata=_r(0.0, 1.0, lo_open=True))
    speed_m_s: float = field(default=0.10, metadata=_r(0.0, 10.0, lo_open=True))
    laps: float = field(default=1.0, metadata=_r(0.0, 1000.0, lo_open=True))
    ramp_s: float = field(default=0.5, metadata=_r(0.0, 60.0))
    check_samples: int = field(default=720, metadata=_r(8, 1_000_000))
    normal: tuple[float, float, float] = (0.0, 0.0, 1.0)  # the circle's plane normal (not normalised)


@dataclass(frozen=True)
class ContourSection:
    """Hybrid force/velocity contour tracking (seed 001 §7); see controller/tasks/contour_tracking.py."""

    expected_centre_m: tuple[float, float] = (0.0, 0.0)
    height_m: float = field(default=0.50, metadata=_r(-10.0, 10.0))
    expected_radius_m: float = field(default=0.07, metadata=_r(0.0, 1.0, lo_open=True))
    approach_direction_deg: float = field(default=0.0, metadata=_r(-360.0, 360.0))
    approach_clearance_m: float = field(default=0.005, metadata=_r(0.0, 1.0, lo_open=True))
    approach_speed_m_s: float = field(default=0.002, metadata=_r(0.0, 1.0, lo_open=True))
    max_approach_distance_m: float = field(default=0.02, metadata=_r(0.0, 1.0, lo_open=True))
    contact_force_n: float = field(default=1.0, metadata=_r(0.0, 1000.0, lo_open=True))
    force_setpoint_n: float = field(default=10.0, metadata=_r(0.0, 1000.0, lo_open=True))
    lap_speeds_m_s: tuple[float, ...] = field(default=(0.02, 0.04, 0.06, 0.06, 0.06), metadata=_r(0.0, 1.0, lo_open=True))
    tangential_acceleration_m_s2: float = field(default=0.05, metadata=_r(0.0, 100.0, lo_open=True))
    force_kp_m_s_per_n: float = field(default=3.5e-4, metadata=_r(0.0, 1.0))
    force_ki_m_s2_per_n: float = field(default=3.5e-3, metadata=_r(0.0, 10.0))
    max_normal_speed_m_s: float = field(default=0.02, metadata=_r(0.0, 10.0, lo_open=True))
    force_filter_hz: float = field(default=10.0, metadata=_r(0.1, 10000.0))
    normal_min_force_n: float = field(default=2.0, metadata=_r(0.0, 1000.0))
    max_force_n: float = field(default=40.0, metadata=_r(0.0, 1000.0, lo_open=True))
    contact_lost_force_n: float = field(default=1.0, metadata=_r(0.0, 1000.0))
    contact_lost_cycles: int = field(default=40, metadata=_r(1, 100000))
    on_contact_loss: str = field(default="reapproach", metadata={"choices": ("reapproach", "stop")})
    retract_distance_m: float = field(default=0.01, metadata=_r(0.0, 1.0, lo_open=True))
    retract_speed_m_s: float = field(default=0.02, metadata=_r(0.0, 1.0, lo_open=True))
    tare_s: float = field(default=0.1, metadata=_r(0.0, 60.0, lo_open=True))
    friction_estimate: float = field(default=0.1, metadata=_r(0.0, 2.0))
    normal_tracker_hz: float = field(default=1.5, metadata=_r(0.01, 50.0))
    comparison_press_m: float = field(default=6.0e-5, metadata=_r(0.0, 0.01))
    direction: int = field(default=1, metadata={"range": (-1, 1, False)})


@dataclass(frozen=True)
class TaskSection:
    kind: str = field(default="path", metadata={"choices": ("path", "contour")})
    path: PathSection = PathSection()
    contour: ContourSection = ContourSection()


@dataclass(frozen=True)
class SimDriveSection:
    """Simulated CiA 402 drive: a second-order position loop with drive-side limits."""

    bandwidth_hz: float = field(default=60.0, metadata=_r(0.1, 10000.0))
    damping_ratio: float = field(default=0.9, metadata=_r(0.05, 5.0))
    velocity_feedforward: float = field(default=1.0, metadata=_r(0.0, 1.0))
    max_velocity_m_s: float = field(default=2.0, metadata=_r(0.0, 100.0, lo_open=True))
    max_acceleration_m_s2: float = field(default=40.0, metadata=_r(0.0, 1e5, lo_open=True))
    quick_stop_deceleration_m_s2: float = field(default=5.0, metadata=_r(0.0, 1e5, lo_open=True))
    sync_timeout_s: float = field(default=0.05, metadata=_r(0.001, 60.0))
    substep_s: float = field(default=5.0e-4, metadata=_r(1e-6, 0.01))
    max_velocity_rad_s: float = field(default=12.0, metadata=_r(0.0, 1e4, lo_open=True))  # rotary drives
    max_acceleration_rad_s2: float = field(default=240.0, metadata=_r(0.0, 1e6, lo_open=True))
    quick_stop_deceleration_rad_s2: float = field(default=30.0, metadata=_r(0.0, 1e6, lo_open=True))
    initial_positions_m: tuple[float, float, float] = (0.71508, 0.56794, 0.42697)  # TCP at (0.09, 0, 0.5) m
    # Cheope's linear motors: a cogging force A sin(2 pi q / period + phase) on each carriage, acting
    # through the structure's actuator stiffness (sim_backend/plant.py); 0 N disables it
    cogging_force_n: float = field(default=2.0, metadata=_r(0.0, 1e4))
    cogging_period_m: float = field(default=0.024, metadata=_r(0.0, 1.0, lo_open=True))
    cogging_phases_deg: tuple[float, float, float] = (0.0, 120.0, 240.0)


@dataclass(frozen=True)
class SimSensorSection:
    noise_std_n: float = field(default=0.05, metadata=_r(0.0, 100.0))
    bias_n: tuple[float, float, float] = (0.10, -0.05, 0.02)
    range_n: float = field(default=300.0, metadata=_r(0.0, 327.0, lo_open=True))
    seed: int = 1
    sample_rate_hz: float = field(default=1000.0, metadata=_r(1.0, 100000.0))
    bandwidth_hz: float = field(default=200.0, metadata=_r(0.1, 100000.0))


@dataclass(frozen=True)
class SimDiskSection:
    """The workpiece of the contour task; known to the simulator only (sim_backend/contact_disk.py)."""

    centre_m: tuple[float, float] = (0.002, -0.001)
    height_m: float = field(default=0.50, metadata=_r(-10.0, 10.0))
    radius_m: float = field(default=0.07, metadata=_r(0.0, 1.0, lo_open=True))
    thickness_m: float = field(default=0.01, metadata=_r(0.0, 1.0, lo_open=True))
    tool_radius_m: float = field(default=0.0, metadata=_r(0.0, 0.1))
    contact_stiffness_n_m: float = field(default=1.0e6, metadata=_r(0.0, 1e12, lo_open=True))
    sensor_stiffness_n_m: float = field(default=3.0e5, metadata=_r(0.0, 1e12, lo_open=True))
    contact_damping_n_s_m: float = field(default=200.0, metadata=_r(0.0, 1e9))
    friction_coefficient: float = field(default=0.15, metadata=_r(0.0, 2.0))


@dataclass(frozen=True)
class SimSection:
    drive: SimDriveSection = SimDriveSection()
    sensor: SimSensorSection = SimSensorSection()
    structure_damping_ratio: float = field(default=0.5, metadata=_r(0.0, 10.0))
    structure_inertial_load: bool = True  # the structure also carries M times the drives' acceleration (plant.py)
    environment: str = field(default="auto", metadata={"choices": ("auto", "free", "disk")})
    disk: SimDiskSection = SimDiskSection()
    faults: tuple[str, ...] = ()  # fault injection, sim_backend/fault_injection.py: "drop:2@3.0+0.5", ...


@dataclass(frozen=True)
class RecordingSection:
    """The session recording (logs/recorder.py): one MCAP file per run of the controller."""

    enabled: bool = True
    directory: str = ""  # "" = $XDG_DATA_HOME/cheope/sessions (~/.local/share/cheope/sessions)
    buffer_bytes: int = field(default=4 << 20, metadata=_r(4096, 1 << 30))  # loop -> writer process; full: dropped
    chunk_size_bytes: int = field(default=65536, metadata=_r(1024, 64 * 1024 * 1024))  # uncompressed
    flush_interval_s: float = field(default=0.5, metadata=_r(0.01, 60.0))  # close a chunk at least this often


@dataclass(frozen=True)
class MonitoringSection:
    """Remote monitoring over Zenoh (controller/monitoring/): keys under ``<key_prefix>/<robot_id>/``."""

    enabled: bool = True
    robot_id: str = "cheope-1"
    key_prefix: str = "cheope"
    publish_rate_hz: float = field(default=50.0, metadata=_r(0.0, 4000.0, lo_open=True))  # >= loop rate: every cycle
    mode: str = field(default="peer", metadata={"choices": ("peer", "client")})
    listen: str = "tcp/127.0.0.1:7448"  # comma-separated Zenoh endpoints; "" listens nowhere
    on_listen_busy: str = field(default="free_port", metadata={"choices": ("free_port", "fail")})
    connect: str = ""  # comma-separated endpoints of routers or peers, e.g. "tcp/10.0.0.5:7447"
    config_file: str = ""  # a Zenoh JSON5 configuration file; keys it leaves unset get the loopback defaults
    allow_remote_commands: bool = False  # pause, resume, set_force; a remote stop is always accepted


@dataclass(frozen=True)
class Config:
    robot: RobotSection = RobotSection()
    actuators: ActuatorsSection = ActuatorsSection()
    sensor: SensorSection = SensorSection()
    bus: BusSection = BusSection()
    loop: LoopSection = LoopSection()
    safety: SafetySection = SafetySection()
    task: TaskSection = TaskSection()
    sim: SimSection = SimSection()
    recording: RecordingSection = RecordingSection()
    monitoring: MonitoringSection = MonitoringSection()

    @property
    def period_s(self) -> float:
        return 1.0 / self.loop.rate_hz


def _check_number(key: str, value: Any, meta: dict[str, Any], integer: bool) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or (integer and not isinstance(value, int)):
        raise ConfigError(f"{key} = {value!r}: expected {'an integer' if integer else 'a number'}")
    if not math.isfinite(value):
        raise ConfigError(f"{key} = {value!r}: must be finite")
    lo, hi, lo_open = meta.get("range", (None, None, False))
    if lo is not None and (value < lo or (lo_open and value == lo)):
        raise ConfigError(f"{key} = {value!r}: must be {'>' if lo_open else '>='} {lo}" +
                          (f" and <= {hi}" if hi is not None else ""))
    if hi is not None and value > hi:
        raise ConfigError(f"{key} = {value!r}: must be <= {hi}" + (f" and >= {lo}" if lo is not None else ""))


def _convert(key: str, tp: Any, value: Any, meta: dict[str, Any]) -> Any:
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            raise ConfigError(f"[{key}] must be a table, got {value!r}")
        return _build(tp, value, key)
    origin = typing.get_origin(tp)
    if origin is tuple:
        args = typing.get_args(tp)
        if len(args) == 2 and args[1] is Ellipsis:  # tuple[X, ...]: a list of any length
            if not isinstance(value, (list, tuple)):
                raise ConfigError(f"{key} = {value!r}: expected a list")
            return tuple(_convert(f"{key}[{i}]", args[0], v, meta) for i, v in enumerate(value))
        if not isinstance(value, (list, tuple)) or len(value) != len(args):
            raise ConfigError(f"{key} = {value!r}: expected a list of {len(args)} values")
        return tuple(_convert(f"{key}[{i}]", a, v, meta) for i, (a, v) in enumerate(zip(args, value)))
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{key} = {value!r}: expected true or false")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{key} = {value!r}: expected a string")
        choices = meta.get("choices")
        if choices and value not in choices:
            raise ConfigError(f"{key} = {value!r}: must be one of {', '.join(choices)}")
        return value
    if tp is int:
        _check_number(key, value, meta, integer=True)
        return value
    if tp is float:
        _check_number(key, value, meta, integer=False)
        return float(value)
    raise TypeError(f"unsupported config type {tp} for {key}")  # a bug in this module, not input


def _build(cls: type, table: dict[str, Any], prefix: str) -> Any:
    hints = typing.get_type_hints(cls)
    names = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(table) - set(names))
    if unknown:
        where = f"[{prefix}]" if prefix else "the top level"
        raise ConfigError(f"unknown key(s) {', '.join(unknown)} in {where}; known: {', '.join(sorted(names))}")
    kwargs = {}
    for name, value in table.items():
        key = f"{prefix}.{name}" if prefix else name
        kwargs[name] = _convert(key, hints[name], value, dict(names[name].metadata))
    return cls(**kwargs)


def _cross_checks(cfg: Config) -> None:
    c = cfg.robot.cheope
    if c.stroke_min_m >= c.stroke_max_m:
        raise ConfigError(
            f"robot.cheope.stroke_min_m = {c.stroke_min_m} must be < robot.cheope.stroke_max_m = {c.stroke_max_m}"
        )
    ids = list(cfg.actuators.node_ids) + ([cfg.sensor.node_id] if cfg.sensor.enabled else []) + [
        cfg.loop.controller_node_id]
    for i in cfg.actuators.node_ids:
        if not 1 <= i <= 127:
            raise ConfigError(f"actuators.node_ids = {list(cfg.actuators.node_ids)}: node ids must be in 1..127")
    if len(set(ids)) != len(ids):
        raise ConfigError(
            f"node ids must be distinct: actuators.node_ids = {list(cfg.actuators.node_ids)}, "
            f"sensor.node_id = {cfg.sensor.node_id}, loop.controller_node_id = {cfg.loop.controller_node_id}"
        )
    if cfg.loop.heartbeat_consumer_s <= cfg.loop.heartbeat_period_s:
        raise ConfigError(
            f"loop.heartbeat_consumer_s = {cfg.loop.heartbeat_consumer_s} must exceed "
            f"loop.heartbeat_period_s = {cfg.loop.heartbeat_period_s}"
        )
    _robot_cross_checks(cfg)
    from sim_backend.fault_injection import FaultSpecError, parse_fault  # pure parsing, no I/O

    for i, text in enumerate(cfg.sim.faults):
        try:
            parse_fault(text)
        except FaultSpecError as err:
            raise ConfigError(f"sim.faults[{i}]: {err}") from err
    if not cfg.task.contour.lap_speeds_m_s:
        raise ConfigError("task.contour.lap_speeds_m_s = []: needs at least one lap")
    if cfg.task.contour.direction not in (-1, 1):
        raise ConfigError(f"task.contour.direction = {cfg.task.contour.direction}: must be 1 or -1")
    if cfg.bus.fd and cfg.bus.data_bitrate_bit_s < cfg.bus.bitrate_bit_s:
        raise ConfigError(
            f"bus.data_bitrate_bit_s = {cfg.bus.data_bitrate_bit_s} must be >= bus.bitrate_bit_s = "
            f"{cfg.bus.bitrate_bit_s}"
        )


def _robot_cross_checks(cfg: Config) -> None:
    u, n = cfg.robot.uru, cfg.robot.nspu
    if u.knee_sign not in (-1, 1):
        raise ConfigError(f"robot.uru.knee_sign = {u.knee_sign}: must be 1 or -1")
    if any(k == 0 for k in u.gear_ratios):
        raise ConfigError(f"robot.uru.gear_ratios = {list(u.gear_ratios)}: must be non-zero")
    if u.motor_min_rad >= u.motor_max_rad:
        raise ConfigError(f"robot.uru.motor_min_rad = {u.motor_min_rad} must be < robot.uru.motor_max_rad = "
                          f"{u.motor_max_rad}")
    if n.leg_min_m >= n.leg_max_m:
        raise ConfigError(f"robot.nspu.leg_min_m = {n.leg_min_m} must be < robot.nspu.leg_max_m = {n.leg_max_m}")
    if sum(x * x for x in cfg.task.path.normal) < 1e-12:
        raise ConfigError(f"task.path.normal = {list(cfg.task.path.normal)}: must be a non-zero vector")
    if cfg.robot.kind != "cheope" and cfg.task.kind == "contour":
        raise ConfigError(f'task.kind = "contour" needs robot.kind = "cheope" (got {cfg.robot.kind!r})')


# Keys an earlier version wrote into recordings (``cheope.config``) and this one no longer has.
# They configured the recorder's and publisher's hand-off threads, which are gone; reading an
# old recording drops them instead of refusing the file.
RETIRED_KEYS = ("recording.queue_size", "monitoring.queue_size")


def recorded_config_from_dict(table: dict[str, Any]) -> Config:
    """The Config of a recording, written by this or an earlier version (``RETIRED_KEYS`` dropped)."""
    for dotted in RETIRED_KEYS:
        section, _, key = dotted.partition(".")
        if isinstance(table.get(section), dict):
            table[section].pop(key, None)
    return config_from_dict(table)


def config_from_dict(table: dict[str, Any]) -> Config:
    cfg = _build(Config, table, "")
    _cross_checks(cfg)
    return cfg


def load_config(path: Path | str | None = None, overrides: dict[str, Any] | None = None) -> Config:
    """Load ``path`` (default: the shipped cheope.toml) and apply dotted-key ``overrides``."""
    p = Path(path) if path is not None else DEFAULT_CONFIG
    try:
        with p.open("rb") as fh:
            table = tomllib.load(fh)
    except FileNotFoundError as err:
        raise ConfigError(f"configuration file {p} does not exist") from err
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"configuration file {p} is not valid TOML: {err}") from err
    for dotted, value in (overrides or {}).items():
        set_dotted(table, dotted, value)
    return config_from_dict(table)


def set_dotted(table: dict[str, Any], dotted: str, value: Any) -> None:
    *parents, leaf = dotted.split(".")
    node = table
    for part in parents:
        node = node.setdefault(part, {})
        if not isinstance(node, dict):
            raise ConfigError(f"cannot set {dotted}: {part} is not a table")
    node[leaf] = value


def config_to_dict(cfg: Any) -> dict[str, Any]:
    """Plain nested dict (for metadata, status answers and JSON)."""
    return dataclasses.asdict(cfg)


__all__ = [
    "DEFAULT_CONFIG",
    "Config",
    "ConfigError",
    "config_from_dict",
    "config_to_dict",
    "load_config",
    "set_dotted",
]


def parse_override(text: str) -> tuple[str, Any]:
    """``key.sub=value`` with a TOML value (``loop.rate_hz=1000``, ``bus.can="socketcan:vcan0"``)."""
    key, sep, raw = text.partition("=")
    if not sep or not key.strip():
        raise ConfigError(f"--set {text!r}: expected KEY=VALUE, e.g. loop.rate_hz=1000")
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw  # a bare word is taken as a string
    return key.strip(), value
