"""The simulated robot as one plant: drives, structure, environment and force sensor.

Both the simulator process (``server.py``) and the in-process loopback (``loopback.py``)
drive this object, so they simulate the same physics. Time is an argument: ``advance``
integrates everything up to ``now_s`` in sub-steps of ``substep_s``; ``sync`` answers a SYNC.
In free space the structure carries no load, so the mechanics reduce to the direct
kinematics evaluated at the SYNC.

The mechanics depend on ``robot.kind`` (``_update_kinematics``):
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
  compliance shows in the contour's force error (README, "Contour tracking").
- ``sim.structure_inertial_load``: the deflection is measured from the kinematic TCP, which
  accelerates with the drives, so M (s_kin'' + x'') = F - K x - D x'; s_kin'' = J^-1 q''
  (the J' s' term, about v^2 / rod length, is left out). Off, the tool follows the kinematic
  TCP without inertia, as the model did before.
"""

from __future__ import annotations

import logging
import math

import numpy as np

from controller.config import Config
from controller.robots.errors import NoSolutionError
from controller.robots.registry import actuator_units, mass_model_from_config, robot_from_config
from drivers.pdo_codec import encode_drive_tpdo
from sim_backend.contact_disk import DiskEnvironment, DiskParams
from sim_backend.drive import DriveParams, SimulatedDrive
from sim_backend.environment import ZERO3, Environment, FreeSpace
from sim_backend.force_sensor import SensorParams, SimulatedForceSensor
from sim_backend.mechanics import NO_ACCELERATION, ComplianceParams, CompliantTool, Matrix3, as_rows, matvec

log = logging.getLogger(__name__)


def drive_params_from_config(cfg: Config) -> DriveParams:
    d = cfg.sim.drive
    u = actuator_units(cfg)  # m, or rad for the URU's motors; the stroke of the configured robot
    return DriveParams(
        bandwidth_hz=d.bandwidth_hz, damping_ratio=d.damping_ratio, max_velocity=u.sim_max_velocity,
        max_acceleration=u.sim_max_acceleration, quick_stop_deceleration=u.sim_quick_stop_deceleration,
        velocity_feedforward=d.velocity_feedforward,
        stroke_min=u.stroke_min, stroke_max=u.stroke_max, counts_per_unit=u.counts_per_unit,
        sync_timeout_s=d.sync_timeout_s, substep_s=d.substep_s,
    )


def initial_actuator_positions(cfg: Config, robot) -> tuple[float, ...]:
    """Where the simulated drives start: Cheope's configured positions, else the robot's start pose."""
    if cfg.robot.kind == "uru":
        return tuple(robot.inverse_kinematics(np.asarray(cfg.robot.uru.home_position_m)).tolist())
    if cfg.robot.kind == "nspu":
        return tuple(robot.start_leg_lengths_m().tolist())
    return tuple(cfg.sim.drive.initial_positions_m)


def environment_from_config(cfg: Config) -> Environment:
    kind = cfg.sim.environment
    if kind == "auto":
        kind = "disk" if cfg.task.kind == "contour" else "free"
    if kind == "free":
        return FreeSpace()
    d = cfg.sim.disk
    return DiskEnvironment(DiskParams(
        centre_m=d.centre_m, height_m=d.height_m, radius_m=d.radius_m, thickness_m=d.thickness_m,
        tool_radius_m=d.tool_radius_m, contact_stiffness_n_m=d.contact_stiffness_n_m,
        sensor_stiffness_n_m=d.sensor_stiffness_n_m, contact_damping_n_s_m=d.contact_damping_n_s_m,
        friction_coefficient=d.friction_coefficient))


class RobotPlant:
    def __init__(self, cfg: Config, environment: Environment | None = None) -> None:
        self.kind = cfg.robot.kind
        self.robot = robot_from_config(cfg)
        params = drive_params_from_config(cfg)
        self.drives = [SimulatedDrive(params, position=x) for x in initial_actuator_positions(cfg, self.robot)]
        self.pose = self.robot.start if self.kind == "nspu" else None  # nSPU: the integrated pose
        self._pose_time_s: float | None = None
        s = cfg.sim.sensor
        self.sensor = SimulatedForceSensor(SensorParams(s.noise_std_n, s.bias_n, s.range_n, s.seed,
                                                        s.sample_rate_hz, s.bandwidth_hz)) \
            if cfg.sensor.enabled else None
        self.environment = environment or environment_from_config(cfg)
        self.loaded = not isinstance(self.environment, FreeSpace)
        self.tool = CompliantTool(ComplianceParams(cfg.robot.mass.actuator_stiffness_n_m,
                                                   cfg.sim.structure_damping_ratio, mass_model_from_config(cfg)))
        self.substep_s = cfg.sim.drive.substep_s
        self.structure_refresh_s = 1e-3
        self._structure_time_s = -1.0
        self._v_kin = np.zeros(3)
        d = cfg.sim.drive
        self._cogging_n = d.cogging_force_n if self.kind == "cheope" else 0.0
        self._cogging_k = 2.0 * math.pi / d.cogging_period_m
        self._cogging_phase = tuple(math.radians(a) for a in d.cogging_phases_deg)
        self._jt: Matrix3 = ((0.0,) * 3,) * 3
        self._jinv: Matrix3 = ((0.0,) * 3,) * 3
        self._inertial = cfg.sim.structure_inertial_load
        self.time_s: float | None = None
        self.last_sync_s: float | None = None
        self.tcp_kinematic_m = np.zeros(3)
        self.force_n = ZERO3
        self._update_kinematics()

    @property
    def tcp_m(self) -> np.ndarray:
        """Where the tool really is: the kinematic TCP plus the structure's deflection."""
        return self.tcp_kinematic_m + np.asarray(self.tool.deflection_m)

    def _update_kinematics(self) -> np.ndarray | None:
        q = np.array([d.position for d in self.drives])
        try:
            if self.kind == "cheope":
                self.tcp_kinematic_m = self.robot.direct_kinematics(q)
            elif self.kind == "uru":  # Newton from the previous pose: the assembly the platform is in
                guess = self.tcp_kinematic_m if np.any(self.tcp_kinematic_m) else None
                self.tcp_kinematic_m = self.robot.direct_kinematics(q, guess)
            else:
                self._integrate_pose(q)
        except NoSolutionError:
            log.warning("simulated actuators at %s m have no assembly", q.tolist())
            return None
        return q

    def _integrate_pose(self, q_m: np.ndarray) -> None:
        """nSPU: advance the pose so that its legs reach the drives' actual lengths (seed 000 eq. (11))."""
        from controller.robots.nspu import advance_pose_to_leg_lengths, leg_lengths

        t = self.time_s
        if self._pose_time_s is not None and t is not None and t > self._pose_time_s:
            if np.any(np.abs(q_m - leg_lengths(self.robot.geometry, self.pose)) > 1e-12):
                self.pose = advance_pose_to_leg_lengths(self.robot.geometry, self.pose, q_m, t - self._pose_time_s)
        self._pose_time_s = t
        self.tcp_kinematic_m = np.array(self.pose.p_m)

    def advance(self, now_s: float, check_sync_timeout: bool = True) -> None:
        """Integrate drives and structure up to ``now_s``; see ``SimulatedDrive._watchdog`` for the flag."""
        if self.time_s is None:
            self.time_s = now_s
            for d in self.drives:
                d.advance(now_s, check_sync_timeout)
            return
        if not self.loaded:
            for d in self.drives:
                d.advance(now_s, check_sync_timeout)
            self.time_s = max(self.time_s, now_s)
            return
        while self.time_s < now_s:
            dt = min(self.substep_s, now_s - self.time_s)
            t1 = self.time_s + dt
            for d in self.drives:
                d.advance(t1, check_sync_timeout)
            self._mechanics(t1, dt)
            self.time_s = t1

    def _mechanics(self, t_s: float, dt: float) -> None:
        if t_s - self._structure_time_s >= self.structure_refresh_s:
            # every millisecond: kinematics and the structure's matrices at the current pose
            if self._update_kinematics() is None:
                return
            jac = self.robot.jacobian(self.tcp_kinematic_m)
            self._v_kin = np.linalg.solve(jac, np.array([d.velocity for d in self.drives]))
            self.tool.set_structure(jac)
            self._jt = as_rows(jac.T)
            self._jinv = as_rows(np.linalg.inv(jac))
            self._structure_time_s = t_s
        else:  # in between, the kinematic TCP moves on with its velocity
            self.tcp_kinematic_m = self.tcp_kinematic_m + self._v_kin * dt
        force, torque = self.environment.contact_wrench(self.tcp_m, self._v_kin + np.asarray(self.tool.velocity_m_s))
        self.force_n = force
        fx, fy, fz = float(force[0]), float(force[1]), float(force[2])
        if self._cogging_n:  # the carriages' cogging forces, on the structure as J^T f
            f = tuple(self._cogging_n * math.sin(self._cogging_k * d.position + ph)
                      for d, ph in zip(self.drives, self._cogging_phase))
            jf = matvec(self._jt, f)
            fx, fy, fz = fx + jf[0], fy + jf[1], fz + jf[2]
        # the kinematic TCP's acceleration J^-1 q'' loads the structure
        ab = matvec(self._jinv, tuple(d.acceleration for d in self.drives)) if self._inertial else NO_ACCELERATION
        self.tool.step((fx, fy, fz), dt, ab)
        if self.sensor is not None:
            self.sensor.observe(t_s, dt, force, torque)

    def sync(self, now_s: float) -> tuple[list[bytes], tuple[bytes, bytes] | None]:
        """Latch the drives' targets, sample everything at ``now_s``: the TPDO payloads."""
        self.advance(now_s, check_sync_timeout=False)
        self.last_sync_s = now_s
        for d in self.drives:
            d.on_sync(now_s)
        if not self.loaded:
            self._update_kinematics()
            if self.sensor is not None:
                force, torque = self.environment.contact_wrench(self.tcp_m, np.zeros(3))
                self.sensor.observe(now_s, 1.0, force, torque)
        drives = [encode_drive_tpdo(d.statusword(), d.position_counts()) for d in self.drives]
        sensor = self.sensor.frames() if self.sensor is not None else None
        return drives, sensor
