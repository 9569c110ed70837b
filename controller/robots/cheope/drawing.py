"""Cheope's 3D scene (entry point cheope.scene_drawings): base, inclined rails, sliders, rod pairs,
platform and tool, coloured by the margins left (logs/robot_drawing.py draws it)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from logs.robot_drawing import (
    BLUE,
    DARK,
    GREY,
    ORANGE,
    STEEL,
    ActuatedJoint,
    MeasuredPose,
    Primitive,
    ReferenceTrail,
    Shape,
    box_between,
    force_arrow,
    margin_color,
    vec3,
    workpiece_primitives,
)

if TYPE_CHECKING:
    from controller.config import Config


@dataclass
class CheopeDrawing:
    """Three carriages on prismatic guides along the cone of axes n_j, rods to the platform joints."""

    cfg: Config
    robot_kind: str = "cheope"

    def __post_init__(self) -> None:
        from controller.robots.cheope.entry import build_cheope

        self.robot = build_cheope(self.cfg.robot.model("cheope"))
        self.section = self.cfg.robot.model("cheope")
        self.trail = ReferenceTrail()

    def fixed(self) -> list[Primitive]:
        g, c = self.robot.geometry, self.section
        out = [
            Primitive(
                "base",
                Shape.CYLINDER,
                DARK,
                start=(0.0, 0.0, -0.02),
                end=(0.0, 0.0, 1.0),
                radius_m=0.12,
                length_m=0.04,
                label="base {0}",
            )
        ]
        for j, n in enumerate(g.axes):
            out.append(
                Primitive(
                    "guides",
                    Shape.CAPSULE,
                    GREY,
                    start=vec3(c.stroke_min_m * n - 0.03 * n),
                    end=vec3(c.stroke_max_m * n + 0.03 * n),
                    radius_m=0.012,
                    label=f"guide {j + 1}",
                )
            )
            out.append(
                Primitive(
                    "guides",
                    Shape.CAPSULE,
                    STEEL,
                    start=vec3(0.0 * n),
                    end=vec3(c.stroke_min_m * n),
                    radius_m=0.008,
                )
            )
        return out + workpiece_primitives(self.cfg)

    def actuated_joints(self) -> tuple[ActuatedJoint, ...]:
        """The three linear motors: a carriage sliding along its prismatic axis n_j (seed 001 §3)."""
        return tuple(
            ActuatedJoint(
                f"slider_{j + 1}",
                "prismatic",
                vec3(n),
                visuals=(box_between("sliders", np.zeros(3), n, 0.06, 0.04, BLUE),),
            )
            for j, n in enumerate(self.robot.geometry.axes)
        )

    def moving(self, pose: MeasuredPose) -> list[Primitive]:
        from controller.robots.cheope.model import joint_swing_rad

        g = self.robot.geometry
        self.trail.add(pose.reference_m)
        out: list[Primitive] = []
        q = np.asarray(pose.q, dtype=float)
        if q.shape != (3,) or not np.isfinite(q).all():
            return out + self.trail.primitive()
        sliders = q[:, None] * g.axes
        for j, s in enumerate(sliders):
            out.append(box_between("sliders", s, g.axes[j], 0.06, 0.04, BLUE, f"q{j + 1} = {q[j]:.4f} m"))
        if pose.tcp_m is not None:
            tcp = np.asarray(pose.tcp_m, dtype=float)
            joints = tcp + g.platform_vectors
            swing = joint_swing_rad(g, tcp, q)
            limit = self.robot.limits.joint_swing_limit_rad
            for j in range(3):
                out.append(
                    Primitive(
                        "rods",
                        Shape.CAPSULE,
                        margin_color(float(swing[j]) / limit),
                        start=vec3(sliders[j]),
                        end=vec3(joints[j]),
                        radius_m=0.007,
                        label=f"rod {j + 1}: joint swing {math.degrees(float(swing[j])):.1f} of "
                        f"{math.degrees(limit):.0f} deg",
                    )
                )
                out.append(Primitive("platform", Shape.SPHERE, STEEL, start=vec3(joints[j]), radius_m=0.011))
            out.append(
                Primitive(
                    "platform",
                    Shape.CYLINDER,
                    STEEL,
                    start=vec3((*tcp, 0.0, 0.0, 0.03)),
                    end=(0.0, 0.0, 1.0),
                    radius_m=g.platform_radius_m * 1.15,
                    length_m=0.012,
                )
            )
            out.append(
                Primitive(
                    "tool",
                    Shape.CYLINDER,
                    ORANGE,
                    start=vec3((*tcp, 0.0, 0.0, 0.012)),
                    end=(0.0, 0.0, 1.0),
                    radius_m=0.004,
                    length_m=0.024,
                    label="tool",
                )
            )
            out.append(Primitive("tool", Shape.SPHERE, ORANGE, start=vec3(tcp), radius_m=0.005))
        return out + force_arrow(pose) + self.trail.primitive()
