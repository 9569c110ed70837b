"""The robots' URDF and the transforms of their links (controller/ros2/robot_description.py): no ROS needed."""

from __future__ import annotations

import numpy as np
import pytest

from controller.config import load_config
from controller.configured_robot import robot_from_config
from controller.robot_registry import robot_entry
from controller.ros2.robot_description import RobotDescription, primitive_frame, rotate
from logs.robot_drawing import MeasuredPose, drawing_for_config


def test_the_links_transforms_put_each_part_where_the_drawing_draws_it():
    """The URDF's tree with the bridge's /tf: the actuated links from the joint positions land where
    the drawing puts the sliders, the TCP link on the measured TCP (no ROS needed)."""
    from controller.ros2.robot_description import RobotDescription
    from logs.robot_drawing import MeasuredPose, drawing_for_config

    cfg = load_config()
    robot = robot_from_config(cfg)
    drawing = drawing_for_config(cfg)
    q = (0.52, 0.55, 0.58)
    tcp = tuple(float(x) for x in robot.direct_kinematics(np.asarray(q)))
    pose = MeasuredPose(0.0, q, tcp, None)
    moving = drawing.moving(pose)
    description = RobotDescription(drawing, "cheope", (0.3, 0.9), pose)
    tfs = {t.child: t for t in description.transforms(pose, moving)}
    sliders = [p for p in moving if p.entity == "sliders"]
    for j, p in enumerate(sliders):
        link = tfs[f"slider_{j + 1}_link"]
        visual = description.joints[j].visuals[0]
        at = tuple(a + b for a, b in zip(link.translation, rotate(link.rotation, visual.start), strict=True))
        assert at == pytest.approx(primitive_frame(p)[0], abs=1e-12)
    assert tfs["tcp"].translation == tcp
    rods = [p for p in moving if p.entity == "rods"]
    assert tfs["rods_0"].translation == rods[0].start


@pytest.mark.parametrize(("kind", "joints"), [("cheope", "slider"), ("uru", "motor"), ("nspu", "leg")])
def test_every_robot_has_a_urdf_a_parser_reads_with_its_actuated_joints(kind, joints):
    from urdf_parser_py.urdf import URDF

    cfg = load_config(robot_entry(kind).config_file)
    drawing = drawing_for_config(cfg)
    lo, hi = robot_entry(kind).stroke(cfg.robot.model())
    robot = robot_from_config(cfg)
    if (
        kind == "nspu"
    ):  # its pose is integrated along the legs' motion: the drawing starts at the configured one
        q, tcp = (lo + (hi - lo) * 0.4,) * 3, None
    else:
        tcp = (0.02, 0.03, 0.45 if kind == "cheope" else 0.15)
        q = tuple(float(x) for x in robot.inverse_kinematics(np.asarray(tcp)))
    first = MeasuredPose(0.0, q, tcp, None)
    description = RobotDescription(drawing, kind, (lo, hi), first)
    model = URDF.from_xml_string(description.urdf)
    actuated = [j for j in model.joints if j.type in ("prismatic", "revolute")]
    assert [j.name for j in actuated] == [f"{joints}_{i}" for i in (1, 2, 3)] == list(description.joint_names)
    assert all((j.limit.lower, j.limit.upper) == pytest.approx((lo, hi)) for j in actuated)
    links = {link.name for link in model.links}
    assert {"base", "tcp"} <= links and model.get_root() == "base"
    assert description.passive_names  # rods, links, legs, platform: computed, floating
    # every transform the bridge publishes is of a link the URDF has, under the parent the URDF gives it
    parents = {j.child: j.parent for j in model.joints}
    moving = drawing.moving(first)
    for t in description.static_transforms() + description.transforms(first, moving):
        assert parents[t.child] == t.parent, t
