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
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from controller.errors import InputError

CONFIG_DIR = Path(__file__).parent / "configs"
DEFAULT_CONFIG = CONFIG_DIR / "cheope.toml"


class ConfigError(InputError):
    """Invalid configuration; the message names the key, the value and what is allowed."""


def value_range(lo: float | None = None, hi: float | None = None, *, lo_open: bool = False) -> dict[str, Any]:
    """Field metadata: the allowed range of a number (``lo_open``: ``lo`` itself excluded)."""
    return {"range": (lo, hi, lo_open)}


_r = value_range


def _registered_sections(group: str) -> dict[str, type | None]:
    """``kind -> section type`` of the registered robots or tasks (imported here: they import this module)."""
    if group == "robot":
        from controller.robots.registry import robot_sections

        return dict(robot_sections())
    from controller.tasks.registry import task_sections

    return task_sections()


def _default_models(group: str) -> dict[str, Any]:
    return {kind: section() for kind, section in _registered_sections(group).items() if section is not None}


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
class RobotSection:
    """``kind`` selects a registered robot (controller/robots/registry.py); ``[robot.<kind>]`` is its section.

    Every registered robot's section is parsed and kept (``models``), so a recording's
    configuration names all of them, as the shipped files do; ``model()`` is the selected one's.
    """

    kind: str = "cheope"
    margins: MarginsSection = MarginsSection()
    mass: MassSection = MassSection()
    models: Mapping[str, Any] = field(default_factory=lambda: _default_models("robot"), compare=False)

    def model(self, kind: str | None = None) -> Any:
        """The ``[robot.<kind>]`` section (default: the configured robot's)."""
        return self.models[kind or self.kind]


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
class TaskSection:
    """``kind`` selects a registered task (controller/tasks/registry.py); ``[task.<kind>]`` is its section."""

    kind: str = "path"
    models: Mapping[str, Any] = field(default_factory=lambda: _default_models("task"), compare=False)

    def model(self, kind: str | None = None) -> Any:
        """The ``[task.<kind>]`` section (default: the configured task's); None for a task without one."""
        return self.models.get(kind or self.kind)


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
    robot: RobotSection = field(default_factory=RobotSection)
    actuators: ActuatorsSection = ActuatorsSection()
    sensor: SensorSection = SensorSection()
    bus: BusSection = BusSection()
    loop: LoopSection = LoopSection()
    safety: SafetySection = SafetySection()
    task: TaskSection = field(default_factory=TaskSection)
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
    if cls in _GROUPS:
        return _build_group(cls, table, prefix)
    hints = typing.get_type_hints(cls)
    names = {f.name: f for f in dataclasses.fields(cls) if f.name != "models"}
    unknown = sorted(set(table) - set(names))
    if unknown:
        where = f"[{prefix}]" if prefix else "the top level"
        raise ConfigError(f"unknown key(s) {', '.join(unknown)} in {where}; known: {', '.join(sorted(names))}")
    kwargs = {}
    for name, value in table.items():
        key = f"{prefix}.{name}" if prefix else name
        kwargs[name] = _convert(key, hints[name], value, dict(names[name].metadata))
    return cls(**kwargs)


def _build_group(cls: type, table: dict[str, Any], prefix: str) -> Any:
    """``[robot]`` / ``[task]``: the fixed keys, then one section per registered kind (``[robot.<kind>]``)."""
    sections = _registered_sections(_GROUPS[cls])
    kinds = ", ".join(sections)
    kind = table.get("kind", _default_kind(cls))
    if kind not in sections:
        raise ConfigError(f"{prefix}.kind = {kind!r}: must be one of {kinds}")
    fixed = {k: v for k, v in table.items() if k not in sections}
    models: dict[str, Any] = {}
    for name, section in sections.items():
        if section is None:
            if name in table:
                raise ConfigError(f"[{prefix}.{name}]: the {name} {prefix} has no settings here")
            continue
        sub = table.get(name, {})
        if not isinstance(sub, dict):
            raise ConfigError(f"[{prefix}.{name}] must be a table, got {sub!r}")
        models[name] = _build(section, sub, f"{prefix}.{name}")
    fields = {f.name for f in dataclasses.fields(cls) if f.name != "models"}
    unknown = sorted(set(fixed) - fields)
    if unknown:
        raise ConfigError(f"unknown key(s) {', '.join(unknown)} in [{prefix}]; known: "
                          f"{', '.join(sorted(fields | set(sections)))}")
    built = _build_fixed(cls, fixed, prefix)
    return dataclasses.replace(built, models=models)


def _default_kind(cls: type) -> str:
    return str(next(f.default for f in dataclasses.fields(cls) if f.name == "kind"))


def _build_fixed(cls: type, table: dict[str, Any], prefix: str) -> Any:
    hints = typing.get_type_hints(cls)
    names = {f.name: f for f in dataclasses.fields(cls)}
    kwargs = {name: _convert(f"{prefix}.{name}", hints[name], value, dict(names[name].metadata))
              for name, value in table.items()}
    return cls(**kwargs, models={})


_GROUPS: dict[type, str] = {RobotSection: "robot", TaskSection: "task"}


def _cross_checks(cfg: Config) -> None:
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
    _registered_cross_checks(cfg)
    from sim_backend.fault_injection import FaultSpecError, parse_fault  # pure parsing, no I/O

    for i, text in enumerate(cfg.sim.faults):
        try:
            parse_fault(text)
        except FaultSpecError as err:
            raise ConfigError(f"sim.faults[{i}]: {err}") from err
    if cfg.bus.fd and cfg.bus.data_bitrate_bit_s < cfg.bus.bitrate_bit_s:
        raise ConfigError(
            f"bus.data_bitrate_bit_s = {cfg.bus.data_bitrate_bit_s} must be >= bus.bitrate_bit_s = "
            f"{cfg.bus.bitrate_bit_s}"
        )


def _registered_cross_checks(cfg: Config) -> None:
    """Each registered robot's and task's own checks, and whether the robot can run the task."""
    from controller.robots.registry import robot_entry
    from controller.tasks.registry import task_entry

    for kind, section in cfg.robot.models.items():
        check = robot_entry(kind).check
        if check is not None:
            check(section)
    for kind, section in cfg.task.models.items():
        check = task_entry(kind).check
        if check is not None:
            check(section)
    tasks = robot_entry(cfg.robot.kind).tasks
    if cfg.task.kind not in tasks:
        raise ConfigError(f"task.kind = {cfg.task.kind!r}: robot.kind = {cfg.robot.kind!r} runs "
                          f"{', '.join(repr(t) for t in tasks)}")


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
    robot, task = table.get("robot"), table.get("task")
    if isinstance(robot, dict) and isinstance(task, dict) and robot.get("kind") == "nspu" \
            and task.get("kind", "path") == "path":
        task["kind"] = "planned"  # earlier versions chose the 3-nSPU's planned task by robot.kind
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
    """Plain nested dict in the files' shape (for metadata, status answers and JSON)."""
    out: dict[str, Any] = {}
    for f in dataclasses.fields(cfg):
        value = getattr(cfg, f.name)
        if f.name == "models":
            out.update({kind: config_to_dict(section) for kind, section in value.items()})
        elif dataclasses.is_dataclass(value):
            out[f.name] = config_to_dict(value)
        else:
            out[f.name] = value
    return out


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
