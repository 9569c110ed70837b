"""The 3-nSPU's 3D scene (entry point cheope.scene_drawings): base, legs and the platform's pose."""

from __future__ import annotations

import contextlib
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from logs.robot_drawing import BLUE, DARK, ORANGE, STEEL, ActuatedJoint, MeasuredPose, Primitive, Shape, vec3

if TYPE_CHECKING:
    from controller.config import Config


@dataclass
class NspuDrawing:
    """Spheres at A_i with their nS planes, prismatic legs A_i B_i, the platform triangle B_1 B_2 B_3.

    The pose is not a function of the leg lengths (non-holonomic joints): the drawing integrates
    it from the configured start pose through the leg lengths it is given, one RKMK4 step per
    call (``advance_pose_to_leg_lengths``, seed 000), as the controller's odometry does with
    smaller steps; at ``DEFAULT_SCENE_RATE_HZ`` that is one 1.7 ms step per 50 ms.
    """

    cfg: Config
    robot_kind: str = "nspu"

    def __post_init__(self) -> None:
        from controller.robots.nspu.entry import build_nspu

        self.robot = build_nspu(self.cfg.robot.model("nspu"))
        self.pose = self.robot.start
        self.last: tuple[float, np.ndarray] | None = None

    def fixed(self) -> list[Primitive]:
        g = self.robot.geometry
        out: list[Primitive] = []
        for i in range(3):
            out.append(
                Primitive("base", Shape.SPHERE, DARK, start=vec3(g.a_m[i]), radius_m=0.012, label=f"A{i + 1}")
            )
            out.append(
                Primitive(
                    "base",
                    Shape.CYLINDER,
                    (0.5, 0.5, 0.55, 0.35),
                    start=vec3(g.a_m[i]),
                    end=vec3(g.r[i]),
                    radius_m=0.05,
                    length_m=0.002,
                    label=f"nS plane {i + 1}",
                )
            )
        return out

    def actuated_joints(self) -> tuple[ActuatedJoint, ...]:
        """The three legs: each a prismatic joint along the leg, from A_i (its direction set by the
        passive nS joint, computed: the leg's drawn part ``legs_<i>``) to B_i, a rod of the shortest
        leg length ending at B_i."""
        rod_m = self.cfg.robot.model("nspu").leg_min_m
        return tuple(
            ActuatedJoint(
                f"leg_{i + 1}",
                "prismatic",
                (0.0, 0.0, 1.0),
                parent=f"legs_{i}",
                visuals=(
                    Primitive(
                        "legs",
                        Shape.CAPSULE,
                        BLUE,
                        start=(0.0, 0.0, -rod_m),
                        end=(0.0, 0.0, 0.0),
                        radius_m=0.006,
                    ),
                ),
            )
            for i in range(3)
        )

    def moving(self, pose: MeasuredPose) -> list[Primitive]:
        from controller.errors import NoSolutionError
        from controller.robots.nspu.kinematics import NspuModelError, advance_pose_to_leg_lengths, limb_state

        q = np.asarray(pose.q, dtype=float)
        if q.shape != (3,) or not np.isfinite(q).all():
            return []
        if self.last is not None and pose.t_s > self.last[0]:
            # keep the last pose when this one does not solve: a drawing never stops a recording
            with contextlib.suppress(NspuModelError, NoSolutionError, ValueError):
                self.pose = advance_pose_to_leg_lengths(
                    self.robot.geometry, self.pose, q, pose.t_s - self.last[0]
                )
        self.last = (pose.t_s, q)
        g = self.robot.geometry
        limbs = limb_state(g, self.pose.p_m, self.pose.R)
        out: list[Primitive] = []
        for i in range(3):
            b = limbs.b[i]
            out.append(
                Primitive(
                    "legs",
                    Shape.CAPSULE,
                    BLUE,
                    start=vec3(g.a_m[i]),
                    end=vec3(b),
                    radius_m=0.006,
                    label=f"leg {i + 1}: {q[i]:.4f} m",
                )
            )
            out.append(Primitive("platform", Shape.SPHERE, STEEL, start=vec3(b), radius_m=0.008))
        ring = (*(vec3(limbs.b[i]) for i in range(3)), vec3(limbs.b[0]))
        out.append(Primitive("platform", Shape.LINE, STEEL, points=ring, radius_m=0.004))
        out.append(
            Primitive("tool", Shape.SPHERE, ORANGE, start=vec3(self.pose.p_m), radius_m=0.006, label="P")
        )
        return out
