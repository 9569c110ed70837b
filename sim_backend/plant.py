"""The simulated robot as one plant: drives, structure, environment and force sensor.

Both the simulator process (``server.py``) and the in-process loopback (``loopback.py``)
drive this object, so they simulate the same physics. Time is an argument: ``advance``
integrates everything up to ``now_s`` on one grid of equal sub-steps of at most
``substep_s``; ``sync`` answers a SYNC. In free space the structure carries no load, so the
mechanics reduce to the direct kinematics evaluated at the SYNC.

Cost, because a simulator that answers late looks like a late drive: the whole interval
between two SYNCs is integrated in one call, in plain floats. The drives go first, leaving a
trace of their positions and accelerations; the structure follows on the same grid, with the
kinematic TCP interpolated linearly between its values at the two ends (at 60 mm/s around a
70 mm radius that is 0.2 um off the arc over 2.5 ms) and the pose-dependent matrices (J, the
structure's M^-1 K, M^-1 D) evaluated once per interval, at its start (the TCP moves 0.15 mm in
2.5 ms; J changes by a part in a thousand).

The kinematics are the robot's simulator hook (``sim_backend/plant_kinematics.py``):
- Cheope: the closed-form direct kinematics of the slider positions [m];
- 3-URU: the direct kinematics from the motor-shaft angles [rad] (the drives are rotary),
  Newton from the previous pose (the assembly the platform is in);
- 3-nSPU: the pose (p, R) is integrated from the drives' actual leg lengths at every SYNC
  (``nspu.advance_pose_to_leg_lengths``, one RKMK4 step over the SYNC interval): the pose of a
  non-holonomic robot depends on the whole leg motion. ``tcp_m`` is the platform point P.
The drives start where the robot's start pose puts them (the URU's home position, the
nSPU's planned start pose); ``sim.drive.initial_positions_m`` is Cheope's. Only Cheope has
the compliant structure and the contact environment.

Two loads on Cheope's compliant structure (``sim_backend/mechanics.py``): the cogging force
(2 N by default) and the inertial load (on by default; the contour task's force filter and the
structure's damping in cheope.toml are set for it):

- ``sim.drive.cogging_force_n``: the cogging (detent) force of an iron-core linear motor,
  F_j = A sin(2 pi q_j / period + phase_j) on carriage j, a periodic joint-space disturbance
  with the magnet pitch as its period. It acts at the carriages, so on the structure as the
  Cartesian force J^T F; through the lumped stiffness k J^T J it moves the tool by
  J^-1 F / k, largest along the minor axis of J^T J (seed 001 §6: the velocity ellipsoid
  "indicates also the effects on repeatability ... due to uncertainty of joint motion").
  Typical values: 1-2 % of the rated force for iron-core motors (ironless ones have none but a
  smaller force ripple), magnet pitches of a few centimetres. Cheope's motors are not
  documented in seed 001; the default, 2 N (about 1 % of a 200 N motor) with the three magnet
  tracks mounted 120 deg apart, is the force-type disturbance through which the structure's
  compliance shows in the contour's force error (docs/concepts/contour-tracking.md).
- ``sim.structure_inertial_load``: the deflection is measured from the kinematic TCP, which
  accelerates with the drives, so M (s_kin'' + x'') = F - K x - D x'; s_kin'' = J^-1 q''
  (the J' s' term, about v^2 / rod length, is left out). Off, the tool follows the kinematic
  TCP without inertia, as the model did before.
"""

from __future__ import annotations

import logging
import math
from typing import cast

import numpy as np

from controller.config import Config
from controller.configured_robot import actuator_units, robot_from_config
from controller.core.linalg3 import Matrix3, as_rows, inverse3, matvec, transpose3
from controller.core.ports import ActuatorUnit, CompliantStructure, missing_capability
from controller.errors import NoSolutionError
from controller.robot_registry import check_axes
from controller.sim_config.sections import SimWorkpieceSection
from controller.tasks.registry import task_entry
from sim_backend.contact_disk import DiskEnvironment, DiskParams
from sim_backend.drive import DriveParams, DriveQuirks, SimulatedDrive
from sim_backend.environment import Environment, FreeSpace, series_stiffness_n_m
from sim_backend.force_sensor import SensorParams, SimulatedForceSensor
from sim_backend.mechanics import NO_ACCELERATION, ComplianceParams, CompliantTool
from sim_backend.plant_kinematics import plant_kinematics
from sim_backend.pose_tracker import SimulatedPoseTracker, TrackerParams
from sim_backend.quirks import QuirkValues, drive_quirks, quirks_of
from sim_backend.workpiece import (
    BUMP_RAMP_M,
    NOTCH_WALL_SLOPE,
    ContactParams,
    Feature,
    PolylineEnvironment,
    ShapeParams,
    outline,
)

log = logging.getLogger(__name__)

# How far behind a SYNC the simulated platform's pose may be integrated for a tracker sample there:
# the 3-nSPU's pose goes in 10-ms steps (ODOMETRY_INTERVAL_S), on a thread behind the answers, so
# up to 10 ms and a period or two of the loop behind when that thread keeps up (tracker_frames).
TRACKER_POSE_LAG_S = 0.03


def configured_drive_quirks(cfg: Config) -> list[DriveQuirks]:
    """Each drive's device-side quirks (sim.drive.quirks, sim_backend/quirks.py), in node order."""
    q = cfg.sim.quirk
    values = QuirkValues(
        q.power_stage_ready_s, q.fault_reset_hold_s, q.transition_delay_s, q.warning_emcy_code
    )
    return [
        drive_quirks(quirks_of(cfg.sim.drive.quirks, node, is_drive=True), values)
        for node in cfg.actuators.node_ids
    ]


def drive_params_from_config(cfg: Config) -> DriveParams:
    d = cfg.sim.drive
    u = actuator_units(cfg)  # m, or rad for the URU's motors; the stroke of the configured robot
    rotary = u.unit == ActuatorUnit.RADIAN  # the drive-side limits in the actuators' unit
    return DriveParams(
        bandwidth_hz=d.bandwidth_hz,
        damping_ratio=d.damping_ratio,
        max_velocity=d.max_velocity_rad_s if rotary else d.max_velocity_m_s,
        max_acceleration=d.max_acceleration_rad_s2 if rotary else d.max_acceleration_m_s2,
        quick_stop_deceleration=d.quick_stop_deceleration_rad_s2
        if rotary
        else d.quick_stop_deceleration_m_s2,
        velocity_feedforward=d.velocity_feedforward,
        stroke_min=u.stroke_min,
        stroke_max=u.stroke_max,
        counts_per_unit=u.counts_per_unit,
        sync_timeout_s=d.sync_timeout_s,
        substep_s=d.substep_s,
        negative_limit_switch=d.limit_switches_m[0],
        positive_limit_switch=d.limit_switches_m[1],
    )


def environment_kind(cfg: Config) -> str:
    """ "free" or "workpiece": sim.environment, or with "auto" what the configured task expects (until the
    controller announces its own task's at set-up, drivers/sim_environment.py)."""
    kind: str = cfg.sim.environment
    if kind == "auto":  # what the task expects: the contour task's workpiece (controller/tasks/builtin.py)
        kind = task_entry(cfg.task.kind).sim_environment
    return kind


def environment_from_config(cfg: Config) -> Environment:
    return environment_named(cfg, environment_kind(cfg))


def environment_named(cfg: Config, kind: str) -> Environment:
    """Free space, or the workpiece of ``[sim.workpiece]``."""
    if kind == "free":
        return FreeSpace()
    return workpiece_environment(cfg.sim.workpiece)


def workpiece_environment(w: SimWorkpieceSection) -> DiskEnvironment | PolylineEnvironment:
    """The paper's plain disk with its exact model; any other shape, or a disk with features, as a polyline."""
    if w.shape == "disk" and not w.features:
        return DiskEnvironment(
            DiskParams(
                centre_m=w.centre_m,
                height_m=w.height_m,
                radius_m=w.radius_m,
                thickness_m=w.thickness_m,
                tool_radius_m=w.tool_radius_m,
                contact_stiffness_n_m=w.contact_stiffness_n_m,
                sensor_stiffness_n_m=w.sensor_stiffness_n_m,
                contact_damping_n_s_m=w.contact_damping_n_s_m,
                friction_coefficient=w.friction_coefficient,
            )
        )
    features = tuple(
        Feature(
            f.angle_deg, f.length_m, f.depth_m, NOTCH_WALL_SLOPE * f.depth_m if f.depth_m > 0 else BUMP_RAMP_M
        )
        for f in w.features
    )
    shape = ShapeParams(
        w.shape,
        w.centre_m,
        w.rotation_deg,
        w.radius_m,
        w.size_m,
        w.corner_radius_m,
        w.lobes,
        w.lobe_depth_m,
        features,
    )
    contact = ContactParams(
        w.height_m,
        w.thickness_m,
        w.tool_radius_m,
        w.contact_stiffness_n_m,
        w.sensor_stiffness_n_m,
        w.contact_damping_n_s_m,
        w.friction_coefficient,
    )
    return PolylineEnvironment(outline(shape), contact)


class RobotPlant:
    def __init__(self, cfg: Config, environment: Environment | None = None) -> None:
        self.robot = robot_from_config(cfg)
        check_axes(
            cfg.robot.kind,
            self.robot.n_actuators,
            {"sim.drive.encoder_offsets_m": cfg.sim.drive.encoder_offsets_m},
        )
        self.kinematics = plant_kinematics(cfg, self.robot)  # the robot's simulator hook
        params = drive_params_from_config(cfg)
        self.drives = [
            SimulatedDrive(params, position=x, encoder_offset=offset, quirks=quirks)
            for x, offset, quirks in zip(
                self.kinematics.initial_positions(),
                cfg.sim.drive.encoder_offsets_m,
                configured_drive_quirks(cfg),
            )
        ]
        self._check_positions_fit_the_encoder(params)
        s = cfg.sim.sensor
        self.sensor = (
            SimulatedForceSensor(
                SensorParams(s.noise_std_n, s.bias_n, s.range_n, s.seed, s.sample_rate_hz, s.bandwidth_hz)
            )
            if cfg.sensor.enabled
            else None
        )
        self.tracker: SimulatedPoseTracker | None = None
        if cfg.tracker.enabled:  # the platform's pose: only a hook that integrates one has it (the 3-nSPU's)
            if not hasattr(self.kinematics, "pose") or not hasattr(self.kinematics, "pose_time_s"):
                raise ValueError(
                    f"tracker.enabled: the simulated {cfg.robot.kind} has no platform pose to track "
                    "(only the 3-nSPU's simulator integrates one)"
                )
            t = cfg.sim.tracker
            self.tracker = SimulatedPoseTracker(
                TrackerParams(t.rate_hz, t.position_noise_m, t.angle_noise_rad, t.seed)
            )
        self.environment = environment or environment_from_config(cfg)
        self.loaded = not isinstance(self.environment, FreeSpace)
        # The robot's own structure (its model's masses and stiffness: CompliantStructure), or none:
        # a rigid robot in free space, and a workpiece refused (set_environment).
        self._kind = cfg.robot.kind
        self._max_contact_force_n = cfg.safety.max_contact_force_n
        self._compliance = (
            None
            if missing_capability(self.robot, CompliantStructure)
            else ComplianceParams(
                cast(CompliantStructure, self.robot).actuator_stiffness_n_m,
                cfg.sim.structure_damping_ratio,
                cast(CompliantStructure, self.robot).masses,
            )
        )
        self._check_structure()
        self.tool = CompliantTool(self._compliance) if self._compliance is not None else None
        self.substep_s = cfg.sim.drive.substep_s
        w = cfg.sim.workpiece
        self._contact_k = series_stiffness_n_m(w.contact_stiffness_n_m, w.sensor_stiffness_n_m)
        self._contact_c = w.contact_damping_n_s_m
        self._declared_k = cfg.safety.contact.cell_stiffness_n_m
        self._check_contact_integrable()
        self._check_cell_as_declared()
        d = cfg.sim.drive
        self._cogging_n = d.cogging_force_n if self.kinematics.cogging else 0.0
        self._cogging_k = 2.0 * math.pi / d.cogging_period_m
        self._cogging_phase = tuple(math.radians(a) for a in d.cogging_phases_deg)
        self._j: Matrix3 = ((0.0,) * 3,) * 3
        self._jt: Matrix3 = ((0.0,) * 3,) * 3
        self._jinv: Matrix3 = ((0.0,) * 3,) * 3
        # The drives report their effort (0x6077) where the structure is modelled.
        self._reports_effort = self._compliance is not None
        self._sync_velocities: tuple[float, ...] | None = None  # the carriages' at the last SYNC
        self._inertial = cfg.sim.structure_inertial_load
        self.time_s: float | None = None
        self.last_sync_s: float | None = None
        self.tcp_kinematic_m = np.zeros(3)
        self.force_n = np.zeros(3)
        # the most one contact presses the part [N]: a ball wedged between two walls presses each
        # harder than the sum the sensor feels (workpiece.py); the sum's size where one touches
        self.contact_load_n = 0.0
        self._update_kinematics()
        self._check_start_outside_the_part()

    @property
    def environment_kind(self) -> str:
        return "free" if isinstance(self.environment, FreeSpace) else "workpiece"

    def set_environment(self, environment: Environment) -> None:
        """Another workpiece, at set-up (the controller's task announced it): the structure starts
        undeflected, and is loaded from now on only when something can touch the tool."""
        self.environment = environment
        self.loaded = not isinstance(environment, FreeSpace)
        self._check_structure()
        self._check_contact_integrable()
        self._check_cell_as_declared()
        self._check_start_outside_the_part()
        self.tool = CompliantTool(self._compliance) if self._compliance is not None else None
        self.force_n = np.zeros(3)
        self.contact_load_n = 0.0
        if self.loaded and self.time_s is not None:
            self._refresh_structure()

    def _check_positions_fit_the_encoder(self, params: DriveParams) -> None:
        """Each drive's start, as its encoder reports it (0x6064, INTEGER32 counts), must fit: 500 m at
        1e7 counts/m failed in the TPDO's pack with a traceback naming no key (an outside tester's)."""
        for j, drive in enumerate(self.drives, start=1):
            counts = (drive.position + drive.encoder_offset) * params.counts_per_unit
            if not -(2**31) <= counts <= 2**31 - 1:
                raise ValueError(
                    f"drive {j} starts at {drive.position:g} (sim.drive.initial_positions_m, or the robot's "
                    f"simulator hook) with encoder offset {drive.encoder_offset:g} "
                    f"(sim.drive.encoder_offsets_m): {counts:.3g} counts at {params.counts_per_unit:g} counts "
                    "per unit do not fit the encoder's INTEGER32 position (0x6064)"
                )

    def _check_structure(self) -> None:
        """A workpiece presses on the robot's structure: only a robot that models one can meet it."""
        if self.loaded and self._compliance is None:
            raise ValueError(
                f"the simulated workpiece presses on the robot's structure, and robot.kind = {self._kind!r} "
                f"lacks {missing_capability(self.robot, CompliantStructure)} (the CompliantStructure "
                "capability, controller/plugin_api.py); "
                'run it in free space: sim.environment = "free"'
            )

    def _check_contact_integrable(self) -> None:
        """The part's contact (its spring and the sensor's in series, and its damper) on the tool's
        mass m within what the substep h's semi-implicit Euler integrates (mechanics.py): h sqrt(k/m)
        and h c/m at most 1, half the undamped bound of 2, for the damper and the structure's own
        spring beside it. Beyond, the simulator invents forces: an outside tester's 1e10 N/m part
        at 0.5 ms read 4 907 N and threw the TCP 2.7 m (44dbcbc); at 1 (a 3.4e7 N/m series
        stiffness at the defaults) the contour demo still tracks."""
        if not self.loaded or self._compliance is None:
            return
        m, h = self._compliance.masses.translating_kg, self.substep_s
        k, c = self._contact_k, self._contact_c
        if h * math.sqrt(k / m) <= 1.0 and h * c / m <= 1.0:
            return
        most_s = min(math.sqrt(m / k), m / c if c > 0.0 else math.inf)
        raise ValueError(
            f"the simulated part is too stiff for the simulator's substep: sim.workpiece "
            f"contact_stiffness_n_m and sensor_stiffness_n_m in series {k:.3g} N/m, contact_damping_n_s_m "
            f"= {c:g} N s/m on the tool's {m:g} kg need sim.drive.substep_s <= {most_s:.2g} s (it is "
            f"{h:g} s); shorten the substep or soften the part"
        )

    def _check_cell_as_declared(self) -> None:
        """The simulated cell no stiffer than the controller is told (safety.contact.cell_stiffness_n_m):
        the guarded moves' speeds are checked against that figure (controller/core/contact_budget.py),
        and a stiffer part than declared met them at up to 125 N in an outside tester's demo with the
        default speeds. A real cell stiffer than its declaration is the user's error, which no
        controller can see before the touch; the simulator does not stage it unasked."""
        if not self.loaded or self._contact_k <= self._declared_k * (1.0 + 1e-9):
            return
        raise ValueError(
            f"the simulated part is stiffer than the controller is told: sim.workpiece contact_stiffness_n_m "
            f"and sensor_stiffness_n_m in series {self._contact_k:.3g} N/m, above "
            f"safety.contact.cell_stiffness_n_m = {self._declared_k:.3g} N/m; declare the cell as it is "
            "(its guarded moves' speeds are then checked against it) or soften the part"
        )

    def _check_start_outside_the_part(self) -> None:
        """A robot that starts inside the simulated part is a misplaced part or start, not a run: the
        first cycle would meet hundreds of newtons (424 N for a plug-in robot's start in the disk)."""
        if not self.loaded or not hasattr(self, "tcp_kinematic_m"):
            return
        x, y, z = (float(v) for v in self.tcp_kinematic_m)
        fx, fy, fz = self.environment.contact_force(x, y, z, 0.0, 0.0)
        force_n = math.sqrt(fx * fx + fy * fy + fz * fz)
        if force_n > self._max_contact_force_n:
            raise ValueError(
                f"the simulated robot starts inside the workpiece: at its start, TCP {[round(v, 4) for v in (x, y, z)]} m "
                f"(its simulator hook's initial positions), the part pushes {force_n:.0f} N, over "
                f"safety.max_contact_force_n = {self._max_contact_force_n:g} N; place the part elsewhere "
                "([sim.workpiece] centre_m, height_m) or start the robot outside it"
            )

    @property
    def tcp_m(self) -> np.ndarray:
        """Where the tool really is: the kinematic TCP plus the structure's deflection."""
        if self.tool is None:
            return self.tcp_kinematic_m.copy()
        tcp: np.ndarray = self.tcp_kinematic_m + np.asarray(self.tool.deflection_m)
        return tcp

    def _update_kinematics(self) -> np.ndarray | None:
        q = np.array([d.position for d in self.drives])
        return q if self.update_kinematics(self.time_s, q) else None

    def advance(self, now_s: float, check_sync_timeout: bool = True) -> None:
        """Integrate drives and structure up to ``now_s``; see ``SimulatedDrive._watchdog`` for the flag."""
        if self.time_s is None:
            self.time_s = now_s
            for d in self.drives:
                d.advance(now_s, check_sync_timeout)
            if self.loaded:
                self._refresh_structure()
            return
        span = now_s - self.time_s
        if span <= 0.0:
            return
        if not self.loaded:
            for d in self.drives:
                d.advance(now_s, check_sync_timeout)
            self.time_s = now_s
            return
        n = max(1, math.ceil(span / self.substep_s - 1e-9))
        traces: list[list[float]] = [[] for _ in self.drives]
        for d, trace in zip(self.drives, traces):
            d.advance(now_s, check_sync_timeout, n, trace)
        self._structure(self.time_s, span, n, traces)
        self.time_s = now_s
        self._refresh_structure(kinematics_done=True)

    def _refresh_structure(self, kinematics_done: bool = False) -> None:
        """The kinematic TCP and the pose-dependent matrices at the drives' current positions."""
        if not kinematics_done and self._update_kinematics() is None:
            return
        robot = cast(CompliantStructure, self.robot)  # loaded: checked at start (_check_structure)
        jac = as_rows(robot.jacobian(self.tcp_kinematic_m))
        cast(CompliantTool, self.tool).set_structure(jac)
        self._j = jac
        self._jt = transpose3(jac)
        self._jinv = inverse3(jac)

    def _structure(self, t0_s: float, span_s: float, n: int, traces: list[list[float]]) -> None:
        """The structure's deflection, the contact force and the sensor over one interval."""
        k0 = self.tcp_kinematic_m
        q1 = np.array([d.position for d in self.drives])
        try:
            k1 = self.kinematics.tcp_m(self.time_s, q1, k0)
        except NoSolutionError:
            log.warning("simulated actuators at %s m have no assembly", q1.tolist())
            k1 = k0
        self.tcp_kinematic_m = k1
        k0x, k0y, k0z = float(k0[0]), float(k0[1]), float(k0[2])
        vkx, vky, vkz = (
            (float(k1[0]) - k0x) / span_s,
            (float(k1[1]) - k0y) / span_s,
            (float(k1[2]) - k0z) / span_s,
        )
        h = span_s / n
        tool, env, sensor = self.tool, self.environment, self.sensor
        assert tool is not None  # loaded: the robot has a structure (_check_structure)
        cogging, ck, phases = self._cogging_n, self._cogging_k, self._cogging_phase
        jt, jinv, inertial = self._jt, self._jinv, self._inertial
        sin = math.sin
        force: tuple[float, float, float] = (0.0, 0.0, 0.0)
        for i in range(n):
            tau = (i + 1) * h
            dx, dy, dz = tool.deflection_m
            tvx, tvy, _ = tool.velocity_m_s
            force = env.contact_force(
                k0x + vkx * tau + dx, k0y + vky * tau + dy, k0z + vkz * tau + dz, vkx + tvx, vky + tvy
            )
            fx, fy, fz = force
            j = 2 * i
            if cogging:  # the carriages' cogging forces, on the structure as J^T f
                jf = matvec(
                    jt,
                    tuple(
                        cogging * sin(ck * tr[j] + ph)  # type: ignore[arg-type]
                        for tr, ph in zip(traces, phases)
                    ),
                )
                fx, fy, fz = fx + jf[0], fy + jf[1], fz + jf[2]
            # the kinematic TCP's acceleration J^-1 q'' loads the structure
            ab = (
                matvec(jinv, (traces[0][j + 1], traces[1][j + 1], traces[2][j + 1]))
                if inertial
                else NO_ACCELERATION
            )
            tool.step((fx, fy, fz), h, ab)
            if sensor is not None:
                sensor.observe(t0_s + tau, h, force[0], force[1], force[2])
        self.force_n = np.array(force)
        one_wall_n = float(getattr(env, "last_max_normal_force_n", 0.0))
        self.contact_load_n = max(math.sqrt(force[0] ** 2 + force[1] ** 2 + force[2] ** 2), one_wall_n)
        self._loaded_efforts()

    def _loaded_efforts(self) -> None:
        """Each motor's force holding its carriage against the structure: tau = -J^-T (K x + D x').

        K = k J^T J and D = c J^T J (``mechanics.py``), so J^-T K x = k J x: the motor j pushes
        -(k (J x)_j + c (J x')_j) along +q_j. In a static contact K x = F, so J^T tau = -F; while the
        tool accelerates the structure carries its inertia too (M (a + x'') = F - K x - D x'), which
        the controller's witness adds back from its commanded acceleration
        (controller/core/contact_guard.py). Cogging enters through the deflection it causes.
        """
        tool, compliance = self.tool, self._compliance
        assert tool is not None and compliance is not None  # loaded: a structure (_check_structure)
        jx = matvec(self._j, tool.deflection_m)
        jv = matvec(self._j, tool.velocity_m_s)
        k, c = compliance.actuator_stiffness_n_m, compliance.actuator_damping_n_s_m
        for d, x, v in zip(self.drives, jx, jv):
            d.effort_n = -(k * x + c * v)

    def _free_efforts(self, interval_s: float) -> None:
        """In free space the motors accelerate the structure: tau = J^-T M J^-1 q'' (no deflection kept).

        q'' is each carriage's mean acceleration over the SYNC interval: the drive's effort signal is
        filtered as a drive's torque actual value is (its instantaneous acceleration jumps at every
        segment of the linearly interpolated target, which its current loop smooths).
        """
        previous = self._sync_velocities
        self._sync_velocities = tuple(d.velocity for d in self.drives)
        if previous is None or interval_s <= 0.0:
            return
        try:
            jac = as_rows(cast(CompliantStructure, self.robot).jacobian(self.tcp_kinematic_m))
        except NoSolutionError:
            return
        qdd = tuple((v - v0) / interval_s for v, v0 in zip(self._sync_velocities, previous))
        jinv = inverse3(jac)
        a = matvec(jinv, (qdd[0], qdd[1], qdd[2]))
        assert self._compliance is not None  # efforts are reported only with a structure
        masses = self._compliance.masses
        m0, mq = masses.translating_kg, masses.per_actuator_kg
        # M a = m0 a + mq J^T J a, and J a = q'': tau = J^-T (m0 a) + mq q''
        tau = matvec(transpose3(jinv), (m0 * a[0], m0 * a[1], m0 * a[2]))
        for d, t, acc in zip(self.drives, tau, qdd):
            d.effort_n = t + mq * acc

    def sync(self, now_s: float) -> None:
        """Latch the drives' targets at ``now_s`` (the TPDOs are packed by ``device_pdos.py``)."""
        self.advance(now_s, check_sync_timeout=False)
        if not self.loaded and self._reports_effort:
            self._free_efforts(now_s - self.last_sync_s if self.last_sync_s is not None else 0.0)
        self.last_sync_s = now_s
        for d in self.drives:
            d.on_sync(now_s)
        if not self.loaded and self.sensor is not None:
            self.sensor.observe(now_s, 1.0, 0.0, 0.0, 0.0)  # free space: nothing touches the tool

    def tracker_frames(self, now_s: float) -> tuple[bytes, bytes] | None:
        """The pose tracker's two TPDOs at this SYNC if a sample is due (of the pose as the simulator has it).

        None, and the sample waits for a later SYNC, while the pose is integrated only up to more than
        ``TRACKER_POSE_LAG_S`` before ``now_s``: the simulator process integrates it on a thread of its
        own, behind the answers (``kinematics_sample``), and a starved thread fell seconds behind on a
        slow host. A sample of that old pose, sent as this SYNC's, showed the 3-nSPU's platform where
        it had been during the motion, and the correcting plans that started there drove it 6-542 mm
        off its goal (2 of 3 runs of the tracker's closed loop over the bus, 2026-12-03). A real
        tracker that cannot measure sends nothing.
        """
        if self.tracker is None:
            return None
        pose_time_s = self.kinematics.pose_time_s  # type: ignore[attr-defined]  # checked at construction
        if pose_time_s is not None and pose_time_s < now_s - TRACKER_POSE_LAG_S:
            return None
        pose = self.kinematics.pose  # type: ignore[attr-defined]
        return self.tracker.frames(now_s, pose.p_m, pose.R)

    def kinematics_sample(self) -> tuple[float, np.ndarray] | None:
        """After a SYNC in free space: (time, drive positions) for ``update_kinematics``, else None.

        In free space the TPDOs carry only the drives' positions; the pose (the direct
        kinematics, or the 3-nSPU's integration of its whole leg motion, 1.7 ms a step in numpy)
        is the simulator's own view and must not delay them: the simulator process hands the
        sample to a thread of its own, the in-process loopback updates at once.
        """
        if self.loaded or self.time_s is None:
            return None
        return self.time_s, np.array([d.position for d in self.drives])

    def update_kinematics(self, t_s: float | None, q: np.ndarray) -> bool:
        """The pose at ``t_s`` from the drives' positions ``q``; False where they have no assembly."""
        try:
            self.tcp_kinematic_m = self.kinematics.tcp_m(t_s, q, self.tcp_kinematic_m)
        except NoSolutionError:
            log.warning("simulated actuators at %s m have no assembly", q.tolist())
            return False
        return True
