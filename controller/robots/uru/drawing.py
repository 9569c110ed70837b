"""The 3-URU's 3D scene (entry point cheope.scene_drawings): base, motors, limbs and platform."""

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
class UruDrawing:
    """Three motors at A_i = d_b e_i, proximal links A_i C_i, distal links C_i B_i, platform at P."""

    cfg: Config
    robot_kind: str = "uru"

    def __post_init__(self) -> None:
        from controller.robots.uru.entry import build_uru

        self.robot = build_uru(self.cfg.robot.model("uru"))
        self.min_sin_th3 = self.cfg.robot.model("uru").min_sin_th3
        self.trail = ReferenceTrail()

    def fixed(self) -> list[Primitive]:
        g = self.robot.geometry
        e = np.eye(3)
        out = [Primitive("base", Shape.SPHERE, DARK, start=(0.0, 0.0, 0.0), radius_m=0.015, label="O")]
        for i in range(3):
            a = g.base_offset_m * e[i]
            out.append(
                Primitive("base", Shape.CAPSULE, GREY, start=(0.0, 0.0, 0.0), end=vec3(a), radius_m=0.008)
            )
            out.append(
                Primitive(
                    "motors",
                    Shape.CYLINDER,
                    DARK,
                    start=vec3(a - 0.03 * e[i]),
                    end=vec3(e[i]),
                    radius_m=0.025,
                    length_m=0.05,
                    label=f"motor {i + 1}",
                )
            )
        return out + workpiece_primitives(self.cfg)

    def actuated_joints(self) -> tuple[ActuatedJoint, ...]:
        """The three motors on the base: a shaft turning about e_i at A_i with a crank mark; the links
        it drives through the bevel gears (seed 003 eq. (7)-(13)) are passive, computed from the pose."""
        g = self.robot.geometry
        e = np.eye(3)
        out = []
        for i in range(3):
            across = e[(i + 1) % 3]
            out.append(
                ActuatedJoint(
                    f"motor_{i + 1}",
                    "revolute",
                    vec3(e[i]),
                    origin=vec3(g.base_offset_m * e[i]),
                    visuals=(
                        Primitive(
                            "motors", Shape.CYLINDER, STEEL, end=vec3(e[i]), radius_m=0.012, length_m=0.02
                        ),
                        box_between("motors", 0.02 * across, across, 0.03, 0.008, ORANGE),
                    ),
                )
            )
        return tuple(out)

    def moving(self, pose: MeasuredPose) -> list[Primitive]:
        from controller.errors import NoSolutionError
        from controller.robots.uru import kinematics as uru

        self.trail.add(pose.reference_m)
        out: list[Primitive] = []
        if pose.tcp_m is None:
            return out + self.trail.primitive()
        g = self.robot.geometry
        p = np.asarray(pose.tcp_m, dtype=float)
        try:
            conf = uru.configuration(g, p)
        except (NoSolutionError, ValueError):
            return out + self.trail.primitive()
        e = np.eye(3)
        for i in range(3):
            a = g.base_offset_m * e[i]
            c = a + g.f[i] * conf.u[i]  # seed 003 §2: c_i = a_i + f_i u_i
            b = p + g.platform_offset_m * e[i]  # b_i = p + d_p e_i
            serial = abs(math.sin(float(conf.th3_rad[i])))
            used = (1.0 - serial) / max(1.0 - self.min_sin_th3, 1e-9)
            out.append(
                Primitive(
                    "proximal_links",
                    Shape.CAPSULE,
                    BLUE,
                    start=vec3(a),
                    end=vec3(c),
                    radius_m=0.008,
                    label=f"link {i + 1}",
                )
            )
            out.append(
                Primitive(
                    "distal_links",
                    Shape.CAPSULE,
                    margin_color(used),
                    start=vec3(c),
                    end=vec3(b),
                    radius_m=0.007,
                    label=f"limb {i + 1}: sin th3 = {serial:.2f}",
                )
            )
            out.append(Primitive("joints", Shape.SPHERE, STEEL, start=vec3(c), radius_m=0.011))
            out.append(
                Primitive("platform", Shape.CAPSULE, STEEL, start=vec3(p), end=vec3(b), radius_m=0.009)
            )
        out.append(Primitive("tool", Shape.SPHERE, ORANGE, start=vec3(p), radius_m=0.014, label="P"))
        return out + force_arrow(pose) + self.trail.primitive()
