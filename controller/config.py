"""Configuration: TOML files mapped onto frozen sections, validated once at start.

Every value has its unit in its name. A value outside its allowed range, of the wrong type,
or an unknown key is rejected with a ``ConfigError`` naming the key, the value and the
reason (controller/config_schema.py). ``controller/configs/cheope.toml`` holds the defaults and
documents every key.

Whose sections are where: the controller's own below; each robot's ``[robot.<kind>]`` and
each task's ``[task.<kind>]`` with its registry entry (controller/robots/<kind>/entry.py,
controller/tasks/builtin.py); the simulator's ``[sim]`` in controller/sim_config/sections.py. One file
configures both processes, so the whole document is validated before either starts.
"""

from __future__ import annotations

import copy
import json
import math
import re
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any, Literal

import msgspec

from controller.config_schema import ConfigError, Section, check_finite, convert_section, rng
from controller.configs import CONFIG_DIR
from controller.core.cycle_data import EmcyAction, Reaction
from controller.sim_config.sections import SimSection, check_sim_section
from controller.text_files import one_line, read_text_file

DEFAULT_CONFIG = CONFIG_DIR / "cheope.toml"


def _registered_sections(group: str) -> dict[str, type | None]:
    """``kind -> section type`` of the registered robots or tasks (imported here: they import this module)."""
    if group == "robot":
        from controller.robot_registry import robot_sections

        return dict(robot_sections())
    from controller.tasks.registry import task_sections

    return task_sections()


def _default_models(group: str) -> dict[str, Any]:
    return {kind: section() for kind, section in _registered_sections(group).items() if section is not None}


class RobotSection(Section, frozen=True):
    """``kind`` selects a registered robot (controller/robot_registry.py); ``[robot.<kind>]`` is its section.

    Every registered robot's section is parsed and kept (``models``), so a recording's
    configuration names all of them, as the shipped files do; ``model()`` is the selected one's.
    """

    kind: str = "cheope"
    models: Mapping[str, Any] = msgspec.field(default_factory=lambda: _default_models("robot"))

    def model(self, kind: str | None = None) -> Any:
        """The ``[robot.<kind>]`` section (default: the configured robot's)."""
        return self.models[kind or self.kind]


class ActuatorsSection(Section, frozen=True):
    node_ids: tuple[int, ...] = (1, 2, 3)
    counts_per_m: Annotated[float, rng(1.0, 1e12)] = 1.0e7
    # Rotary actuators (robot.kind = "uru": motor-shaft angles) use these instead of the _m keys.
    counts_per_rad: Annotated[float, rng(1.0, 1e12)] = 166886.05  # 2^20 counts per turn
    max_velocity_rad_s: Annotated[float, rng(0.0, 1e4, lo_open=True)] = 6.0
    max_acceleration_rad_s2: Annotated[float, rng(0.0, 1e6, lo_open=True)] = 60.0
    max_jerk_rad_s3: Annotated[float, rng(0.0, 1e9, lo_open=True)] = 3000.0
    max_velocity_m_s: Annotated[float, rng(0.0, 100.0, lo_open=True)] = 1.0
    max_acceleration_m_s2: Annotated[float, rng(0.0, 1e4, lo_open=True)] = 10.0
    max_jerk_m_s3: Annotated[float, rng(0.0, 1e7, lo_open=True)] = 500.0
    # The drives' own following-error monitor (CiA 402 0x6065 window, 0x6066 time), set at start.
    following_error_window_m: Annotated[float, rng(0.0, 10.0, lo_open=True)] = 0.005
    following_error_window_rad: Annotated[float, rng(0.0, 100.0, lo_open=True)] = 0.05
    following_error_time_s: Annotated[float, rng(0.0, 65.535)] = 0.01
    # How long past its last target a drive runs on blind when no new one comes (a hold-up of the
    # loop), then holds: whole periods of it go to the drives' object 0x2010 at start (node_setup.py).
    extrapolation_s: Annotated[float, rng(0.0, 0.1)] = 0.025
    # How long the drives wait for the next SYNC before they quick-stop on their own (EMCY 0x8240), set
    # at start in whole ms (their object 0x2011). Past extrapolation_s they already hold still; this
    # is how long a loop held up by its machine (a host that takes its CPU away) may stay away and
    # then carry on from where they stand. Below loop.heartbeat_consumer_s, the watch on a dead master.
    sync_watchdog_s: Annotated[float, rng(0.001, 65.535)] = 0.25
    vendor_id: Annotated[int, rng(0, 2**32 - 1)] = 0x00000CE0
    product_code: Annotated[int, rng(0, 2**32 - 1)] = 0x00000402
    # The drives' device description (EDS); "" is drivers/eds/cheope_drive.eds. The PDO mapping
    # written at start is the EDS's default unless listed here ("0x607A", "0x2000:1").
    eds_file: str = ""
    rpdo_objects: tuple[str, ...] = ()
    tpdo_objects: tuple[str, ...] = ()
    # CiA 402 homing before the first cycle (drivers/homing.py): 0 none, 17/18 negative/positive limit
    # switch, 35/37 current position. Positions and speeds in the actuators' unit (rad for rotary ones).
    homing_method: Literal[0, 17, 18, 35, 37] = 0
    home_offsets_m: tuple[float, ...] = (0.0, 0.0, 0.0)  # each drive's position at home (0x607C)
    homing_switch_speed_m_s: Annotated[float, rng(0.0, 100.0, lo_open=True)] = 0.1
    homing_zero_speed_m_s: Annotated[float, rng(0.0, 100.0, lo_open=True)] = 0.005
    homing_acceleration_m_s2: Annotated[float, rng(0.0, 1e4, lo_open=True)] = 1.0
    homing_timeout_s: Annotated[float, rng(0.1, 600.0)] = 30.0
    # How homing is judged done (drivers/homing.py): "attained" statusword bit 12, or "position" (a
    # drive that never sets it: bit 10 and the position within homing_position_window_m of its home
    # offset). homing_skip_if_homed: a drive that reports itself homed (mode 6, bit 12) is not homed again.
    homing_done: Literal["attained", "position"] = "attained"
    homing_position_window_m: Annotated[float, rng(0.0, 1.0, lo_open=True)] = 1.0e-4
    homing_skip_if_homed: bool = False
    # The drives' identity beyond vendor and product (0x1018 sub 3); unset: not checked.
    revision_number: Annotated[int, rng(0, 2**32 - 1)] | None = None
    # The PDO mapping: "write" it at start (the EDS's or rpdo_objects/tpdo_objects) and read it back,
    # or "read" it from the drive as it is (a fixed mapping); the codecs come from what is read.
    pdo_mapping: Literal["write", "read"] = "write"
    # How the controller and each drive watch each other: "heartbeat" (0x1017 produced, 0x1016
    # consumes the controller's) or "guarding" (the controller polls, 0x100C guard time, 0x100D life
    # time factor; the drive's life guarding watches the polls).
    supervision: Literal["heartbeat", "guarding"] = "heartbeat"
    guard_time_s: Annotated[float, rng(0.01, 60.0)] = 0.1
    life_time_factor: Annotated[int, rng(1, 255)] = 3
    # The fault reset (at set-up over SDO, in ENABLING by the controlword): bit 7 high for
    # fault_reset_hold_s (0: one cycle, the edge), then up to fault_reset_wait_s for the statusword to
    # leave FAULT, at most fault_reset_attempts times (0: until loop.enable_timeout_s).
    fault_reset_hold_s: Annotated[float, rng(0.0, 10.0)] = 0.0
    fault_reset_wait_s: Annotated[float, rng(0.0, 60.0)] = 0.0
    fault_reset_attempts: Annotated[int, rng(0, 1000)] = 0
    # The drives' EMCY error codes that do not fault: "0xFF01" or a range "0xFF00-0xFFFF" -> "warn"
    # (an event) or "hold" (a running task pauses until resumed); every other code faults.
    emcy_reactions: Mapping[str, EmcyAction] = msgspec.field(default_factory=dict)


class SensorSection(Section, frozen=True):
    enabled: bool = True
    node_id: Annotated[int, rng(1, 127)] = 16
    product_code: Annotated[int, rng(0, 2**32 - 1)] = 0x00000F75
    vendor_id: Annotated[int, rng(0, 2**32 - 1)] = 0x00000CE0
    eds_file: str = ""  # "" is drivers/eds/force_sensor.eds; its TPDO1/TPDO2 mapping is written at start


class TrackerSection(Section, frozen=True):
    """An optional pose tracker on the platform (drivers/pdo_codec.py: two TPDOs), read by the exchange.

    The 3-nSPU's planned task corrects its execution from it (controller/robots/nspu/planned_legs.py).
    """

    enabled: bool = False
    node_id: Annotated[int, rng(1, 127)] = 20
    rate_hz: Annotated[float, rng(0.1, 10000.0)] = 100.0  # its samples a second: the bus-load budget


class BusSection(Section, frozen=True):
    can: str = "udp_multicast"
    udp_port: Annotated[int, rng(1, 65535)] = 43113
    fd: bool = False
    bitrate_bit_s: Annotated[float, rng(1e4, 1e6)] = 1.0e6
    data_bitrate_bit_s: Annotated[float, rng(1e5, 1.2e7)] = 5.0e6
    max_load_percent: Annotated[float, rng(1.0, 100.0)] = 70.0
    # Who sends SYNC: "loop" (the cycle sends RPDOs then SYNC) or "kernel" (SocketCAN only: the
    # kernel's broadcast manager sends SYNC every period; the loop sends the RPDOs ahead of it).
    sync_producer: Literal["loop", "kernel"] = "loop"
    sync_lead_fraction: Annotated[float, rng(0.05, 0.9)] = (
        0.2  # kernel: RPDOs this part of a period before SYNC
    )
    # before sending anything, the controller listens this long for another master (SYNC, NMT,
    # RPDOs, SDO requests, its own node id's heartbeat), the simulator for devices with its node
    # ids (drivers/bus_presence.py); at least one loop.heartbeat_period_s to hear an idle controller [s]
    presence_listen_s: Annotated[float, rng(0.05, 10.0)] = 0.3


class LoopSection(Section, frozen=True):
    rate_hz: Annotated[float, rng(1.0, 4000.0)] = 400.0
    collect_fraction: Annotated[float, rng(0.05, 0.95)] = (
        0.8  # the answer window after SYNC (drivers/cyclic_exchange.py)
    )
    spin_us: Annotated[float, rng(0.0, 5000.0)] = 300.0
    gil_switch_interval_us: Annotated[float, rng(1.0, 100000.0)] = 200.0
    freeze_gc: bool = True  # gc.freeze() the start-up heap before the loop (controller/realtime.py)
    max_missing_s: Annotated[float, rng(0.0, 10.0, lo_open=True)] = 0.1  # a drive silent this long: fault
    # ... unless every device was silent with it: the simulator, the bus or their host paused, not
    # one device (docs/concepts/cycle.md, "Silence tolerated"). As long as the drives wait for SYNC;
    # never less than max_missing_s, whatever is set (SafetyMonitor.silent_too_long)
    max_bus_silence_s: Annotated[float, rng(0.0, 10.0, lo_open=True)] = 0.25
    heartbeat_period_s: Annotated[float, rng(0.01, 10.0)] = 0.1
    heartbeat_consumer_s: Annotated[float, rng(0.02, 60.0)] = 0.5
    controller_node_id: Annotated[int, rng(1, 127)] = 100
    enable_timeout_s: Annotated[float, rng(0.01, 60.0)] = 2.0
    sdo_timeout_s: Annotated[float, rng(0.01, 60.0)] = 1.0
    sdo_retries: Annotated[int, rng(0, 100)] = 0  # an SDO that times out or is aborted 0x0800002x, again
    boot_timeout_s: Annotated[float, rng(0.01, 600.0)] = 5.0  # a node may take this long to answer SDO
    boot_retries: Annotated[int, rng(0, 100)] = 0  # then an NMT reset node and as long again, this often
    stay_in_fault: bool = False  # keep cycling in FAULT (quick stop held) until a remote reset or a stop
    # a stop (signal, cheope stop, --duration, a lost recording) that has not reached DONE by then
    # quick-stops the drives: the process ends in bounded time whatever the drives answer
    stop_timeout_s: Annotated[float, rng(0.01, 600.0)] = 10.0
    hold_before_task_s: Annotated[float, rng(0.0, 60.0)] = 0.2
    settle_tolerance_m: Annotated[float, rng(0.0, 1.0, lo_open=True)] = 2.0e-5


class ContactGuardSection(Section, frozen=True):
    """The contact guard (controller/core/contact_guard.py): every move of an enabled robot is judged
    against what the task's reference says about contact, on the larger of the force sensor's reading
    and the drives' effort witness; past a limit the tool backs off along the force, then FAULT."""

    free_space_force_n: Annotated[float, rng(0.1, 10000.0)] = 10.0  # no contact expected: a collision above
    guarded_move_force_n: Annotated[float, rng(0.1, 10000.0)] = 25.0  # a guarded move (approach) above this
    max_contact_speed_m_s: Annotated[float, rng(0.0, 10.0, lo_open=True)] = (
        0.1  # a task's move expecting contact
    )
    # The stiffest contact the cell presents to the tool: the sensor, its mount and the part, in series
    # (a spring). A guarded move's speed must stop within the force limit against it
    # (controller/core/contact_budget.py); the shipped simulated cell: 1e6 and 3e5 in series, 2.3e5.
    cell_stiffness_n_m: Annotated[float, rng(1.0, 1e12)] = 2.4e5
    # A task that reads the force sensor runs only where the drives report their effort (0x6077 mapped in
    # actuators.tpdo_objects) and the robot maps it to a force: the sensor's second witness.
    witness_required: bool = True
    tolerance_n: Annotated[float, rng(0.0, 10000.0)] = 6.0  # sensor vs witness: the witness's own error ...
    tolerance_fraction: Annotated[float, rng(0.0, 10.0)] = 0.25  # ... plus this share of the larger force
    inertia_fraction: Annotated[float, rng(0.0, 10.0)] = 1.0  # ... plus this share of |M a|, its recent peak
    inertia_time_constant_s: Annotated[float, rng(0.001, 10.0)] = (
        0.1  # ... fading with this (the structure rings)
    )
    disagreement_s: Annotated[float, rng(0.0, 10.0, lo_open=True)] = 0.025  # apart this long: suspect
    sensor_suspect_s: Annotated[float, rng(0.0, 600.0)] = 2.0  # the task's time to resolve it; then back off
    # pressing, fresh samples the same to the last bit this long: the sensor is frozen (0: not judged)
    sensor_frozen_s: Annotated[float, rng(0.0, 10.0)] = 0.025
    # where contact is sought or made, a force rising sample after sample trips the guard when it would
    # pass the limit within this (a reaction's time to stop it; 0: the limit alone)
    reaction_s: Annotated[float, rng(0.0, 1.0)] = 0.0075
    back_off_distance_m: Annotated[float, rng(0.0, 1.0)] = 0.005  # the protective back-off along the force
    back_off_speed_m_s: Annotated[float, rng(0.0, 1.0, lo_open=True)] = 0.02
    back_off_acceleration_m_s2: Annotated[float, rng(0.0, 100.0, lo_open=True)] = 0.5
    # A back-off's braking reaches the actuators' max acceleration within this (its jerk: that over
    # this), where a planned move's jerk takes max_acceleration / max_jerk (20 ms on Cheope).
    reaction_ramp_s: Annotated[float, rng(0.0001, 1.0)] = 0.002


class SafetySection(Section, frozen=True):
    """What the law does about each abnormal input (see controller/core/control_law.py, ``_safety``).

    "fault": quick stop through the controlword and stay in FAULT until a reset;
    "warn": record a warning event once per episode and go on; "ignore": nothing.
    Drive faults, EMCY, missing TPDOs (loop.max_missing_s), a bus-off, an actuator
    outside its stroke and a task reference outside the safe workspace always fault.
    """

    max_contact_force_n: Annotated[float, rng(0.0, 10000.0, lo_open=True)] = 60.0
    sensor_stale_s: Annotated[float, rng(0.0, 100.0, lo_open=True)] = 0.1
    on_sensor_stale: Reaction = Reaction("fault")
    on_sensor_saturated: Reaction = Reaction("fault")
    on_heartbeat_lost: Reaction = Reaction("fault")
    on_error_frames: Reaction = Reaction("warn")
    max_consecutive_late_s: Annotated[float, rng(0.0, 1000.0, lo_open=True)] = 0.125
    on_late_cycles: Reaction = Reaction("fault")
    late_tolerance_fraction: Annotated[float, rng(0.01, 10.0)] = 0.5
    # Position plausibility (always a fault): a measured position further from the drive's last one
    # than actuators.max_velocity allows plus this is a jump; further than the window from the
    # commanded one while enabled is a following error. _rad: rotary actuators.
    max_position_jump_m: Annotated[float, rng(0.0, 10.0, lo_open=True)] = 0.005
    max_position_jump_rad: Annotated[float, rng(0.0, 100.0, lo_open=True)] = 0.05
    # 3 mm: the contour demos over the bus measured at most 0.71 mm off the expected position (3 runs,
    # 2026-12-06); a carriage jammed 50 ms at 80 mm/s built 4.8 mm, under 10 mm, and once let go it
    # drove the tool back into the part at 221.4 N (block:3@30+0.05 at 80-mm/s laps; at 3 mm: 13.1 N).
    following_window_m: Annotated[float, rng(0.0, 10.0, lo_open=True)] = 0.003
    following_window_rad: Annotated[float, rng(0.0, 100.0, lo_open=True)] = 0.1
    # The whole bus (drivers/cyclic_exchange.py): frames nobody configured should send.
    on_unknown_node: Reaction = Reaction("warn")  # unconfigured nodes' frames; 29-bit frames
    on_foreign_sync: Reaction = Reaction("fault")  # a second SYNC producer
    on_foreign_nmt: Reaction = Reaction("fault")  # someone else's NMT command to our nodes
    # someone else's RPDO or SDO request to our drives, or a drive's SDO answer to one
    on_foreign_command: Reaction = Reaction("fault")
    # A device's TPDO twice in one answer window: the sample is never used (as if missing); this is
    # what to do about a second sender on the bus (docs/concepts/supervision.md: why "fault").
    on_duplicate_frames: Reaction = Reaction("fault")
    on_rejected_frames: Reaction = Reaction(
        "warn"
    )  # a configured node's frame of the wrong length (per burst)
    on_frame_flood: Reaction = Reaction("fault")
    max_foreign_frames_per_cycle: Annotated[int, rng(1, 100000)] = 16
    # A second sender on the force sensor's COB-ID (a duplicate or impossible frame from its node)
    # while a task that can retract without force data holds the tool in contact: the task retracts,
    # then the fault (the sensor's data is never used again); past this time [s] the fault comes
    # anyway. 0: the quick stop at once, in contact. Any other task: the fault at once.
    sensor_breach_retract_s: Annotated[float, rng(0.0, 60.0)] = 2.0
    contact: ContactGuardSection = msgspec.field(default_factory=ContactGuardSection)


class TaskSection(Section, frozen=True):
    """``kind`` selects a registered task (controller/tasks/registry.py); ``[task.<kind>]`` is its section."""

    kind: str = "path"
    models: Mapping[str, Any] = msgspec.field(default_factory=lambda: _default_models("task"))

    def model(self, kind: str | None = None) -> Any:
        """The ``[task.<kind>]`` section (default: the configured task's); None for a task without one."""
        return self.models.get(kind or self.kind)


class RecordingSection(Section, frozen=True):
    """The session recording (logs/recorder.py): one MCAP file per run of the controller."""

    enabled: bool = True
    directory: str = ""  # "" = $XDG_DATA_HOME/cheope/sessions (~/.local/share/cheope/sessions)
    # loop -> writer process; full: dropped. At least a pipe's own 64 KiB: at the 4 KiB allowed
    # before, most cycles of a quiet run were dropped, the first with its keyframe (an outside
    # tester's finding: 12 045 dropped in 8 s, the file unverifiable)
    buffer_bytes: Annotated[int, rng(1 << 16, 1 << 30)] = 4 << 20
    # uncompressed; at 400 Hz (about 300 kB/s) flush_interval_s closes it first. Larger chunks
    # compress better: a 180-s path session rewritten with 0.5, 1 and 2 s chunks took 0.512, 0.483
    # and 0.466 GB an hour. 2 s (about 600 kB, near the 768 kB the MCAP libraries default to) bounds
    # what a killed writer loses (its open chunk); a killed controller loses nothing (the writer ends the file).
    chunk_size_bytes: Annotated[int, rng(1024, 64 * 1024 * 1024)] = 1048576
    flush_interval_s: Annotated[float, rng(0.01, 60.0)] = 2.0  # close a chunk at least this often
    # the writer process gone (killed, disk full, file size limit) or the free-space guard below:
    # "stop" ends the run through STOPPING (a session that must be recorded is not worth running
    # blind; a controlled stop, not a FAULT: the machine is sound), "warn" stops only the recording
    on_failure: Literal["stop", "warn"] = "stop"
    # A long-lived service (logs/session_writer.py): the session goes on in a new file, which
    # starts with a keyframe of the controller's state, past either limit (0: no limit) ...
    max_file_size_mb: Annotated[float, rng(0.0, 1e7)] = 256.0  # [MB]: half an hour of the default session
    max_file_duration_s: Annotated[float, rng(0.0, 1e7)] = 3600.0  # [s]
    # ... the oldest recordings of the directory are deleted past this total, never an open file (0: keep all)
    keep_total_size_gb: Annotated[float, rng(0.0, 1e6)] = 20.0  # [GB]: about 40 h of the default session
    # below this much free space [MB] on the directory's file system the recording stops (on_failure),
    # leaving room to close the file and for the rest of the system
    min_free_space_mb: Annotated[float, rng(0.0, 1e7)] = 1024.0
    # the robot in 3D (/scene, live views): moving parts drawn at this rate [Hz], by the writer process
    scene_rate_hz: Annotated[float, rng(0.1, 1000.0)] = 20.0
    # live views, fed by the writer process (logs/live_views.py); they need the recording enabled
    live_rerun: str = ""  # "" off, "spawn" (a viewer), "serve" (gRPC + web viewer), or a rerun+http:// URL
    live_foxglove: str = ""  # "" off, or "HOST:PORT" of a Foxglove WebSocket server (foxglove-sdk)
    # the live Foxglove server's /can: the frames since the last message, at most this often [Hz] (0: no /can live)
    live_can_rate_hz: Annotated[float, rng(0.0, 1000.0)] = 10.0


class MonitoringSection(Section, frozen=True):
    """Remote monitoring over Zenoh (controller/monitoring/): keys under ``<key_prefix>/<robot_id>/``."""

    enabled: bool = True
    # "": <host>-<4 hex digits>, unique (controller/monitoring/robot_identity.py); at most 64
    # characters (it names a file of the runtime directory, local_controllers.py)
    robot_id: Annotated[str, msgspec.Meta(max_length=64)] = ""
    key_prefix: str = "cheope"
    publish_rate_hz: Annotated[float, rng(0.0, 4000.0, lo_open=True)] = 50.0  # >= loop rate: every cycle
    mode: Literal["peer", "client"] = "peer"
    listen: str = "tcp/127.0.0.1:7448"  # comma-separated Zenoh endpoints; "" listens nowhere
    on_listen_busy: Literal["free_port", "fail"] = "free_port"
    connect: str = ""  # comma-separated endpoints of routers or peers, e.g. "tcp/10.0.0.5:7447"
    config_file: str = ""  # a Zenoh JSON5 configuration file; keys it leaves unset get the loopback defaults
    allow_remote_commands: bool = False  # pause, resume, set_force; a remote stop is always accepted


class NodeSection(Section, frozen=True):
    """``[[node]]``: one node's own values where it differs from the others (unset: the defaults of
    [loop] and [actuators]); drivers/node_setup.py and the law use them through controller/node_plan.py."""

    node_id: Annotated[int, rng(1, 127)]
    serial_number: Annotated[int, rng(0, 2**32 - 1)] | None = None  # 0x1018 sub 4, checked at start
    revision_number: Annotated[int, rng(0, 2**32 - 1)] | None = None  # 0x1018 sub 3
    boot_timeout_s: Annotated[float, rng(0.01, 600.0)] | None = None
    boot_retries: Annotated[int, rng(0, 100)] | None = None
    sdo_timeout_s: Annotated[float, rng(0.01, 60.0)] | None = None
    sdo_retries: Annotated[int, rng(0, 100)] | None = None
    # a drive's only (not the sensor's):
    supervision: Literal["heartbeat", "guarding"] | None = None
    pdo_mapping: Literal["write", "read"] | None = None
    fault_reset_hold_s: Annotated[float, rng(0.0, 10.0)] | None = None
    fault_reset_wait_s: Annotated[float, rng(0.0, 60.0)] | None = None
    fault_reset_attempts: Annotated[int, rng(0, 1000)] | None = None
    homing_method: Literal[0, 17, 18, 35, 37] | None = None
    homing_done: Literal["attained", "position"] | None = None
    homing_skip_if_homed: bool | None = None


DRIVE_ONLY_NODE_KEYS = (
    "supervision",
    "pdo_mapping",
    "fault_reset_hold_s",
    "fault_reset_wait_s",
    "fault_reset_attempts",
    "homing_method",
    "homing_done",
    "homing_skip_if_homed",
)


class Config(Section, frozen=True):
    robot: RobotSection = msgspec.field(default_factory=RobotSection)
    actuators: ActuatorsSection = msgspec.field(default_factory=ActuatorsSection)
    sensor: SensorSection = msgspec.field(default_factory=SensorSection)
    tracker: TrackerSection = msgspec.field(default_factory=TrackerSection)
    bus: BusSection = msgspec.field(default_factory=BusSection)
    loop: LoopSection = msgspec.field(default_factory=LoopSection)
    safety: SafetySection = msgspec.field(default_factory=SafetySection)
    task: TaskSection = msgspec.field(default_factory=TaskSection)
    sim: SimSection = msgspec.field(default_factory=SimSection)
    recording: RecordingSection = msgspec.field(default_factory=RecordingSection)
    monitoring: MonitoringSection = msgspec.field(default_factory=MonitoringSection)
    node: tuple[NodeSection, ...] = ()  # [[node]] tables: one node's own values

    @property
    def period_s(self) -> float:
        return 1.0 / self.loop.rate_hz

    @property
    def drive_extrapolation_periods(self) -> int:
        """``actuators.extrapolation_s`` in whole periods: the drives' object 0x2010."""
        return int(self.actuators.extrapolation_s * self.loop.rate_hz + 1e-9)

    @property
    def drive_sync_watchdog_ms(self) -> int:
        """``actuators.sync_watchdog_s`` in whole ms: the drives' object 0x2011."""
        return round(self.actuators.sync_watchdog_s * 1000.0)  # the key's range starts at 1 ms


def _build_config(table: dict[str, Any]) -> Config:
    """The whole document: the registered groups ([robot], [task]) by hand, the rest by msgspec."""
    if not isinstance(table, dict):
        raise ConfigError(f"the configuration must be a table, got {table!r}")
    groups = {name: _build_group(cls, table[name], name) for name, cls in _GROUPS.items() if name in table}
    rest = {k: v for k, v in table.items() if k not in _GROUPS}
    cfg = convert_section(rest, Config, "")
    return msgspec.structs.replace(cfg, **groups) if groups else cfg


def _build_group(cls: type[RobotSection | TaskSection], table: Any, prefix: str) -> Any:
    """``[robot]`` / ``[task]``: its own keys, then one section per registered kind (``[robot.<kind>]``)."""
    if not isinstance(table, dict):
        raise ConfigError(f"[{prefix}] must be a table, got {table!r}")
    sections = _registered_sections(prefix)
    kind = table.get("kind", cls.__struct_defaults__[0])
    if not isinstance(kind, str) or kind not in sections:
        from controller.plugins import ROBOTS_GROUP, TASKS_GROUP, why_not_loaded

        why = (
            why_not_loaded(ROBOTS_GROUP if prefix == "robot" else TASKS_GROUP, kind)
            if isinstance(kind, str)
            else ""
        )
        raise ConfigError(
            f"{prefix}.kind = {kind!r}: must be one of {', '.join(sections)}" + (f" ({why})" if why else "")
        )
    models: dict[str, Any] = {}
    for name, section in sections.items():
        sub = table.get(name, {})
        if section is None:
            if name in table:
                raise ConfigError(f"[{prefix}.{name}]: the {name} {prefix} has no settings")
            continue
        if not isinstance(sub, dict):
            raise ConfigError(f"[{prefix}.{name}] must be a table, got {sub!r}")
        models[name] = convert_section(sub, section, f"{prefix}.{name}")
    own = {k: v for k, v in table.items() if k not in sections}
    if "models" in own:
        raise ConfigError(f"unknown key(s) models in [{prefix}]")
    return msgspec.structs.replace(convert_section(own, cls, prefix), models=models)


_GROUPS: dict[str, type[RobotSection | TaskSection]] = {"robot": RobotSection, "task": TaskSection}


def _check_live_views(r: RecordingSection) -> None:
    """The live-view settings are refused at start, not when the writer process tries them."""
    if (
        r.live_rerun
        and r.live_rerun not in ("spawn", "serve")
        and not r.live_rerun.startswith(("rerun+http://", "rerun+https://"))
    ):
        raise ConfigError(
            f'recording.live_rerun = {r.live_rerun!r}: must be "" (off), "spawn", "serve" '
            "or a rerun+http://HOST:PORT/proxy URL"
        )
    if r.live_foxglove:
        _, sep, port = r.live_foxglove.rpartition(":")
        if not sep or not port.isdigit() or int(port) > 65535:
            raise ConfigError(
                f"recording.live_foxglove = {r.live_foxglove!r}: must be HOST:PORT with a port in "
                "0..65535 (0: a free port)"
            )


def _check_rotation(r: RecordingSection) -> None:
    """A file limit below a chunk would rotate on every chunk; retention below a file would delete the open one's peers."""
    if 0 < r.max_file_size_mb * 1e6 < 4 * r.chunk_size_bytes:
        raise ConfigError(
            f"recording.max_file_size_mb = {r.max_file_size_mb:g}: must be 0 (no limit) or at least "
            f"four chunks (recording.chunk_size_bytes = {r.chunk_size_bytes}): "
            f"{4 * r.chunk_size_bytes / 1e6:g} MB"
        )
    if 0 < r.max_file_duration_s < 2 * r.flush_interval_s:
        raise ConfigError(
            f"recording.max_file_duration_s = {r.max_file_duration_s:g}: must be 0 (no limit) or at least "
            f"two flush intervals (recording.flush_interval_s = {r.flush_interval_s:g}): "
            f"{2 * r.flush_interval_s:g} s"
        )
    if r.keep_total_size_gb and r.max_file_size_mb and r.keep_total_size_gb * 1e3 < 2 * r.max_file_size_mb:
        raise ConfigError(
            f"recording.keep_total_size_gb = {r.keep_total_size_gb:g}: must be 0 (keep all) or hold at "
            f"least two files of recording.max_file_size_mb = {r.max_file_size_mb:g} MB"
        )


def _cross_checks(cfg: Config) -> None:
    _check_live_views(cfg.recording)
    _check_rotation(cfg.recording)
    ids = (
        list(cfg.actuators.node_ids)
        + ([cfg.sensor.node_id] if cfg.sensor.enabled else [])
        + [cfg.loop.controller_node_id]
        + ([cfg.tracker.node_id] if cfg.tracker.enabled else [])
    )
    for i in cfg.actuators.node_ids:
        if not 1 <= i <= 127:
            raise ConfigError(
                f"actuators.node_ids = {list(cfg.actuators.node_ids)}: node ids must be in 1..127"
            )
    if len(set(ids)) != len(ids):
        raise ConfigError(
            f"node ids must be distinct: actuators.node_ids = {list(cfg.actuators.node_ids)}, "
            f"sensor.node_id = {cfg.sensor.node_id}, loop.controller_node_id = {cfg.loop.controller_node_id}"
            + (f", tracker.node_id = {cfg.tracker.node_id}" if cfg.tracker.enabled else "")
        )
    if cfg.actuators.sync_watchdog_s <= cfg.actuators.extrapolation_s + 2.0 / cfg.loop.rate_hz:
        raise ConfigError(
            f"actuators.sync_watchdog_s = {cfg.actuators.sync_watchdog_s} must exceed "
            f"actuators.extrapolation_s = {cfg.actuators.extrapolation_s} by more than two periods "
            f"(loop.rate_hz = {cfg.loop.rate_hz}): the drives would quick-stop while they run on"
        )
    if cfg.loop.heartbeat_consumer_s <= cfg.loop.heartbeat_period_s:
        raise ConfigError(
            f"loop.heartbeat_consumer_s = {cfg.loop.heartbeat_consumer_s} must exceed "
            f"loop.heartbeat_period_s = {cfg.loop.heartbeat_period_s}"
        )
    _check_nodes(cfg)
    _check_contact_limits(cfg)
    emcy_code_ranges(cfg.actuators.emcy_reactions)
    _registered_cross_checks(cfg)
    check_sim_section(
        cfg.sim,
        tuple(cfg.actuators.node_ids),
        cfg.sensor.node_id if cfg.sensor.enabled else None,
        1.0 / cfg.loop.rate_hz,
    )
    if cfg.bus.fd and cfg.bus.data_bitrate_bit_s < cfg.bus.bitrate_bit_s:
        raise ConfigError(
            f"bus.data_bitrate_bit_s = {cfg.bus.data_bitrate_bit_s} must be >= bus.bitrate_bit_s = "
            f"{cfg.bus.bitrate_bit_s}"
        )


def _check_contact_limits(cfg: Config) -> None:
    """The contact guard's limits rise with what the task expects: free space, a guarded move, a
    contact by design. Out of order, one of them never acts (an outside tester's
    safety.contact.guarded_move_force_n = 1000 above the 60-N contact limit was accepted, 44dbcbc)."""
    c, limit = cfg.safety.contact, cfg.safety.max_contact_force_n
    if not c.free_space_force_n <= c.guarded_move_force_n <= limit:
        raise ConfigError(
            f"safety.contact.free_space_force_n = {c.free_space_force_n:g} N <= "
            f"safety.contact.guarded_move_force_n = {c.guarded_move_force_n:g} N <= "
            f"safety.max_contact_force_n = {limit:g} N must hold: a guarded move expects more force than "
            "free space and less than a contact by design"
        )
    if c.sensor_frozen_s > 0.0 and cfg.sim.sensor.noise_std_n == 0.0:
        # A real sensor's noise changes its counts every sample; a noiseless simulated one holding
        # still in contact (a pause) repeats its sample to the last bit, which the guard calls frozen.
        raise ConfigError(
            "sim.sensor.noise_std_n = 0 with safety.contact.sensor_frozen_s = "
            f"{c.sensor_frozen_s:g} s: a noiseless sensor at rest in contact sends the same sample to the "
            "last bit, which the contact guard takes for a frozen sensor; give the simulated sensor noise "
            "or set safety.contact.sensor_frozen_s = 0"
        )


def _check_nodes(cfg: Config) -> None:
    """Each [[node]] names a configured node once; a drive's own keys are not given to the sensor."""
    drives = tuple(cfg.actuators.node_ids)
    sensor = cfg.sensor.node_id if cfg.sensor.enabled else None
    seen: set[int] = set()
    for i, n in enumerate(cfg.node):
        if n.node_id in seen:
            raise ConfigError(f"node[{i}].node_id = {n.node_id}: given twice; one [[node]] table per node")
        seen.add(n.node_id)
        if n.node_id not in drives and n.node_id != sensor:
            raise ConfigError(
                f"node[{i}].node_id = {n.node_id}: not a configured node (actuators.node_ids = "
                f"{list(drives)}" + (f", sensor.node_id = {sensor}" if sensor is not None else "") + ")"
            )
        if n.node_id not in drives:
            given = [k for k in DRIVE_ONLY_NODE_KEYS if getattr(n, k) is not None]
            if given:
                raise ConfigError(
                    f"node[{i}] (node {n.node_id}, the sensor): {', '.join(given)} is a drive's only"
                )


_CODE = r"0[xX][0-9a-fA-F]{1,4}"


def emcy_code_ranges(table: Mapping[str, EmcyAction]) -> tuple[tuple[int, int, EmcyAction], ...]:
    """``actuators.emcy_reactions`` as (first code, last code, action), refused naming a bad key."""
    out = []
    for key, action in table.items():
        m = re.fullmatch(rf"\s*({_CODE})\s*(?:-\s*({_CODE})\s*)?", key)
        first, last = (int(m[1], 16), int(m[2] or m[1], 16)) if m else (0, -1)
        if not m or not 0 < first <= last:
            raise ConfigError(
                f'actuators.emcy_reactions: key {key!r}: must be an EMCY error code "0xFF01" or a '
                f'range "0xFF00-0xFFFF" within 0x0001..0xFFFF (0x0000 is the error reset)'
            )
        out.append((first, last, action))
    return tuple(out)


def _registered_cross_checks(cfg: Config) -> None:
    """Each registered robot's and task's own checks, and whether the robot can run the task."""
    from controller.robot_registry import robot_entry
    from controller.tasks.registry import task_entry

    for kind, section in cfg.robot.models.items():
        check = robot_entry(kind).check
        if check is not None:
            check(section)
    for kind, section in cfg.task.models.items():
        check = task_entry(kind).check
        if check is not None:
            check(section)
    tasks = runnable_tasks(cfg.robot.kind)
    if cfg.task.kind not in tasks:
        raise ConfigError(
            f"task.kind = {cfg.task.kind!r}: robot.kind = {cfg.robot.kind!r} runs "
            f"{', '.join(repr(t) for t in tasks)}"
        )


def runnable_tasks(robot_kind: str) -> tuple[str, ...]:
    """The tasks a robot runs: those its entry lists (the first is its demo's), then every task
    whose entry names the robot."""
    from controller.robot_registry import robot_entry
    from controller.tasks.registry import task_entry, task_kinds

    own = robot_entry(robot_kind).tasks
    return own + tuple(k for k in task_kinds() if k not in own and robot_kind in task_entry(k).robots)


# Keys an earlier version wrote into recordings (``cheope.config``) and this one no longer has.
# They configured the recorder's and publisher's hand-off threads, which are gone; reading an
# old recording drops them instead of refusing the file.
RETIRED_KEYS = ("recording.queue_size", "monitoring.queue_size")
# A recording's cell, written before safety.contact.cell_stiffness_n_m existed: the key's least value
# (recorded_config_from_dict)
UNDECLARED_CELL_STIFFNESS_N_M = 1.0


# Tables and lists within each other, at most: the deepest key of the product is 4 levels down
# (robot.cheope.mass.platform_kg), a workpiece's points 2 more.
MAX_CONFIG_DEPTH = 32


def config_table_from_json(text: str) -> dict[str, Any]:
    """A configuration written as JSON (a recording's ``cheope.config``, the controller's status)
    as a table, or a ``ConfigError`` saying what it is instead: JSON that is a list (an
    AttributeError deep in the loader), nested 100 000 deep (a RecursionError), no JSON at all."""
    try:
        table = json.loads(text)
    except RecursionError:
        raise ConfigError(f"the configuration is nested more than {MAX_CONFIG_DEPTH} levels deep") from None
    except ValueError as err:
        raise ConfigError(f"the configuration is not JSON: {err}") from None
    if not isinstance(table, dict):
        raise ConfigError(f"the configuration is a JSON {_json_kind(table)}, not an object of sections")
    if _depth(table) > MAX_CONFIG_DEPTH:
        raise ConfigError(f"the configuration is nested more than {MAX_CONFIG_DEPTH} levels deep")
    return table


def _json_kind(value: object) -> str:
    kinds = ((list, "array"), (str, "string"), (bool, "boolean"), (int | float, "number"))
    return next((name for t, name in kinds if isinstance(value, t)), "null")


def _depth(value: object) -> int:
    """How many tables and lists ``value`` holds within each other (without recursion: a file's
    nesting must not decide the stack's)."""
    deepest, todo = 0, [(value, 1)]
    while todo:
        item, level = todo.pop()
        children = item.values() if isinstance(item, dict) else item if isinstance(item, list) else ()
        if isinstance(item, dict | list):
            deepest = max(deepest, level)
            if level <= MAX_CONFIG_DEPTH:  # deeper is refused anyway
                todo.extend((child, level + 1) for child in children)
    return deepest


def recorded_config_from_dict(table: dict[str, Any]) -> Config:
    """The Config of a recording, written by this or an earlier version (``RETIRED_KEYS`` dropped)."""
    for dotted in RETIRED_KEYS:
        section, _, key = dotted.partition(".")
        if isinstance(table.get(section), dict):
            table[section].pop(key, None)
    table = _cycles_as_seconds(table)  # a recording's max_missing_cycles, read as the time below
    actuators, loop = table.setdefault("actuators", {}), table.get("loop")
    if isinstance(loop, dict) and "max_bus_silence_s" not in loop and "max_missing_s" in loop:
        # before every device's shared silence had its own tolerance it faulted as one drive's did
        loop["max_bus_silence_s"] = loop["max_missing_s"]
    if isinstance(actuators, dict) and "extrapolation_s" not in actuators:
        # before the drives' 0x2010 was written they ran on one period past a missing target
        rate_hz = loop.get("rate_hz") if isinstance(loop, dict) else None
        if not (isinstance(rate_hz, int | float) and math.isfinite(rate_hz) and rate_hz > 0):
            # an unusable rate (a --set of nan) is named as itself below, not through this derived key
            rate_hz = LoopSection().rate_hz
        actuators["extrapolation_s"] = 1.0 / rate_hz
    if isinstance(actuators, dict) and "sync_watchdog_s" not in actuators:
        # before 0x2011 was written the drives kept their power-on watchdog: the simulated drive's
        sim = table.get("sim")
        drive = sim.get("drive") if isinstance(sim, dict) else None
        power_on = drive.get("sync_timeout_s") if isinstance(drive, dict) else None
        actuators["sync_watchdog_s"] = power_on if isinstance(power_on, int | float) else 0.1
    safety = table.get("safety")
    contact = safety.get("contact") if isinstance(safety, dict) else None
    if isinstance(contact, dict) and "cell_stiffness_n_m" not in contact:
        # written before the cell's stiffness was declared, when no guarded speed was checked against
        # it (controller/core/contact_budget.py): the least stiffness, so that the law the session ran
        # is rebuilt as it ran (a 250-Hz session with the shipped speeds would be refused now)
        contact["cell_stiffness_n_m"] = UNDECLARED_CELL_STIFFNESS_N_M
    robot, task = table.get("robot"), table.get("task")
    if (
        isinstance(robot, dict)
        and isinstance(task, dict)
        and robot.get("kind") == "nspu"
        and task.get("kind", "path") == "path"
    ):
        task["kind"] = "planned"  # earlier versions chose the 3-nSPU's planned task by robot.kind
    try:
        return config_from_dict(table)
    except ConfigError:
        # A limit tightened since the file was written (recording.buffer_bytes at least 64 KiB, a
        # robot id of at most 64 characters, the simulator's seeds and switches): the sections
        # that do not shape the law take their defaults, so that the recording still replays and
        # verifies. What the law reads is checked as written, and refused if it is wrong.
        return config_from_dict({k: v for k, v in table.items() if k not in _NOT_THE_LAWS})


_NOT_THE_LAWS = ("recording", "monitoring", "sim")  # sections a recorded law does not read


def _migrate(table: dict[str, Any]) -> dict[str, Any]:
    """Older files and recordings: ``[sim.disk]`` is ``[sim.workpiece]`` (shape "disk") since issue 26;
    ``[robot.margins]`` and ``[robot.mass]`` are Cheope's, ``[robot.cheope.margins]`` and
    ``[robot.cheope.mass]``, since issue 29 (an old key given with --set lands there too);
    the windows counted in cycles are times since issue 37 (``CYCLE_KEYS_NOW_SECONDS``)."""
    table = _cycles_as_seconds(table)
    robot = table.get("robot")
    if isinstance(robot, dict) and ("margins" in robot or "mass" in robot):
        robot = dict(robot)
        cheope = dict(robot.get("cheope") or {})
        for name in ("margins", "mass"):
            if isinstance(robot.get(name), dict):
                cheope[name] = {**(cheope.get(name) or {}), **robot.pop(name)}
        robot["cheope"] = cheope
        table = {**table, "robot": robot}
    sim = table.get("sim")
    if isinstance(sim, dict) and "disk" in sim and "workpiece" not in sim:
        sim = {**sim, "workpiece": sim["disk"]}
        del sim["disk"]
        if sim.get("environment") == "disk":
            sim["environment"] = "workpiece"
        table = {**table, "sim": sim}
    return table


# Windows given in cycles until issue 37, in seconds since (controller/core/periods.py): (section, old
# key, new key). An older file's or recording's count, or a --set of the old key, is the same time at
# the file's own rate, so that a recording replays bit for bit.
CYCLE_KEYS_NOW_SECONDS = (
    ("loop", "max_missing_cycles", "max_missing_s"),
    ("safety", "sensor_stale_cycles", "sensor_stale_s"),
    ("safety", "max_consecutive_late_cycles", "max_consecutive_late_s"),
    ("safety.contact", "disagreement_cycles", "disagreement_s"),
    ("task.contour", "contact_lost_cycles", "contact_lost_s"),
    ("task.contour", "stale_hold_cycles", "stale_hold_s"),
    ("task.contour", "witness_verdict_cycles", "witness_verdict_s"),
)


def _cycles_as_seconds(table: dict[str, Any]) -> dict[str, Any]:
    given = [
        (dotted, old, new) for dotted, old, new in CYCLE_KEYS_NOW_SECONDS if old in _section_at(table, dotted)
    ]
    if not given:
        return table
    table = copy.deepcopy(table)  # the caller's table (a recording's, a file's) stays as it was
    loop = table.get("loop")
    rate_hz = loop.get("rate_hz") if isinstance(loop, dict) else None
    if not isinstance(rate_hz, int | float) or isinstance(rate_hz, bool) or not rate_hz > 0:
        rate_hz = LoopSection().rate_hz  # a wrong rate is the loop section's to refuse, by its own name
    for dotted, old, new in given:
        section = _section_at(table, dotted)
        cycles = section.pop(old)
        if not isinstance(cycles, int) or isinstance(cycles, bool) or cycles < 1:
            raise ConfigError(
                f"{dotted}.{old} = {cycles!r}: a whole number of cycles >= 1 was expected (the key "
                f"is {dotted}.{new} now, in seconds)"
            )
        section[new] = cycles / rate_hz  # given, the old key says it (a --set of it too)
    return table


def _section_at(table: dict[str, Any], dotted: str) -> dict[str, Any]:
    """The table at ``dotted`` ("safety.contact"), or an empty one where there is none."""
    node: Any = table
    for name in dotted.split("."):
        node = node.get(name) if isinstance(node, dict) else None
    return node if isinstance(node, dict) else {}


def config_from_dict(table: dict[str, Any]) -> Config:
    check_finite(table)
    cfg = _build_config(_migrate(table))
    _cross_checks(cfg)
    return cfg


def load_config(path: Path | str | None = None, overrides: dict[str, Any] | None = None) -> Config:
    """Load ``path`` (default: the shipped cheope.toml) and apply dotted-key ``overrides``."""
    p = Path(path) if path is not None else DEFAULT_CONFIG
    table = read_toml_table(p)
    for dotted, value in (overrides or {}).items():
        set_dotted(table, dotted, value)
    return config_from_dict(table)


def read_toml_table(path: Path) -> dict[str, Any]:
    """The TOML document at ``path``; whatever is wrong with the file is one ``ConfigError`` naming it."""
    text = read_text_file(path, "configuration file", ConfigError)
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"configuration file {path} is not valid TOML: {one_line(err)}") from None
    except RecursionError:  # tomllib reads nested arrays and inline tables recursively
        raise ConfigError(f"configuration file {path} nests arrays or tables too deeply") from None


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
    for f in msgspec.structs.fields(cfg):
        value = getattr(cfg, f.name)
        if f.name == "models":
            out.update({kind: config_to_dict(section) for kind, section in value.items()})
        elif isinstance(value, msgspec.Struct):
            out[f.name] = config_to_dict(value)
        elif isinstance(value, tuple) and value and isinstance(value[0], msgspec.Struct):  # a list of tables
            out[f.name] = [config_to_dict(v) for v in value]
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
    if any(c in text for c in "\n\r"):
        # TOML read the value's first line and took the rest for keys of its own, which no one
        # looked at: `loop.rate_hz=400<newline>loop.spin_us=-5` set the rate and dropped the rest
        raise ConfigError(f"--set {text!r}: a line break in KEY=VALUE; give each key its own --set")
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError as err:
        if raw.strip()[:1] in ("[", "{", '"', "'"):  # meant as a list, a table or a quoted text
            raise ConfigError(f"--set {key.strip()}={raw}: not a TOML value ({err})") from None
        value = raw  # a bare word is taken as a string
    except ValueError as err:  # an integer of over 4 300 digits: Python's own limit, in its words
        raise ConfigError(f"--set {key.strip()}: {err}") from None
    return key.strip(), value
