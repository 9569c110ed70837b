"""The polyline workpiece's contact (sim_backend/workpiece.py): the tool's ball reaches into the part
by its true overlap with the profile, its radius less the signed distance of its centre from the
whole boundary, wherever the tool is and whatever notches and bumps the config gives it.

The reference here is brute force: every segment sampled densely, the nearest sample, and inside or
out by counting the boundary's crossings of a ray (no nearest-point reasoning shared with the model).
"""

from __future__ import annotations

import itertools
import math

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from controller.config import load_config, parse_override
from sim_backend.plant import workpiece_environment
from sim_backend.workpiece import (
    BUMP_RAMP_M,
    NOTCH_WALL_SLOPE,
    SHAPES,
    ContactParams,
    Feature,
    PolylineEnvironment,
    ShapeParams,
    outline,
)

DENSE = 16  # samples per segment of the reference: 0.1-0.2 mm segments, 6-12 um apart


def reference_penetration(points: np.ndarray, tool_radius_m: float, x: float, y: float) -> float:
    """The ball's overlap with the polygon ``points`` by brute force (see the module's text)."""
    a, b = points, np.roll(points, -1, axis=0)
    s = np.linspace(0.0, 1.0, DENSE, endpoint=False)[None, :, None]
    dense = (a[:, None, :] + s * (b - a)[:, None, :]).reshape(-1, 2)
    distance = float(np.min(np.hypot(dense[:, 0] - x, dense[:, 1] - y)))
    # crossings of the ray from (x, y) towards +x: odd inside
    straddles = (a[:, 1] > y) != (b[:, 1] > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        at_x = a[:, 0] + (y - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
    inside = int(np.count_nonzero(straddles & (at_x > x))) % 2 == 1
    return tool_radius_m + distance if inside else tool_radius_m - distance


def feature(angle_deg: float, length_m: float, depth_m: float) -> Feature:
    """A feature as the simulator builds it from [[sim.workpiece.features]] (sim_backend/plant.py)."""
    return Feature(angle_deg, length_m, depth_m, NOTCH_WALL_SLOPE * depth_m if depth_m > 0 else BUMP_RAMP_M)


def environment(shape: str, features: tuple[Feature, ...], tool_radius_m: float) -> PolylineEnvironment:
    params = ShapeParams(shape, (0.002, -0.001), 0.0, 0.07, (0.08, 0.06), 0.004, 5, 0.008, features)
    contact = ContactParams(0.5, 0.01, tool_radius_m, 1.0e6, 3.0e5, 200.0, 0.15)
    return PolylineEnvironment(outline(params), contact)


# the config's ranges (controller/sim_config/sections.py, SimFeatureSection) within the shipped disk's
# perimeter (0.44 m); the tool's radius up to 5 mm
features = st.builds(
    feature,
    st.floats(-180.0, 180.0),
    st.floats(0.0005, 0.2),
    st.floats(-0.01, 0.01),
)


@settings(max_examples=40, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(
    shape=st.sampled_from(SHAPES),
    notch=features,
    tool_radius_m=st.floats(0.0, 0.005),
    spots=st.lists(
        st.tuples(st.integers(0, 4095), st.floats(-0.015, 0.015), st.floats(-0.005, 0.005)),
        min_size=8,
        max_size=8,
    ),
)
def test_the_penetration_is_the_balls_true_overlap_with_the_profile(shape, notch, tool_radius_m, spots):
    env = environment(shape, (notch,), tool_radius_m)
    tolerance = 2.0 * math.dist(env.points[0], env.points[1]) / DENSE
    for vertex, across, along in spots:  # near a vertex: along its normal and its tangent
        (px, py), (nx, ny) = env.points[vertex], env.normals[vertex]
        x, y = px + across * nx - along * ny, py + across * ny + along * nx
        depth, _, _ = env.penetration(x, y)
        assert abs(depth - reference_penetration(env.points, tool_radius_m, x, y)) <= tolerance, (x, y)
        contacts = env.contacts(x, y)  # the deepest of them the nearest point's; the others within the ball
        assert contacts[0] == env.penetration(x, y)
        assert all(0.0 < d <= contacts[0][0] for d, _, _ in contacts[1:]), contacts


def test_the_testers_deep_narrow_notch_is_met_where_its_walls_are():
    """A tool sliding 0.1 mm inside the disk's rim across a notch 1 mm long and 4 mm deep: the walk
    from the last segment stayed on the notch's far wall (the tool 7-9 mm inside at 0-10 N), then
    found the whole depth at once (1529 N in the tester's run). The true overlap changes no faster
    than the tool moves and is the brute-force one at every step."""
    env = environment("disk", (feature(90.0, 0.001, 0.004),), 0.0)
    centre = (0.002, -0.001)
    step = 5e-5
    previous = None
    for k in range(400):  # 20 mm of travel, from 80 to 96 degrees
        angle = math.radians(80.0) + k * step / 0.0699
        x, y = centre[0] + 0.0699 * math.cos(angle), centre[1] + 0.0699 * math.sin(angle)
        depth, _, _ = env.penetration(x, y)
        assert abs(depth - reference_penetration(env.points, 0.0, x, y)) <= 2e-5, (k, depth)
        if previous is not None:
            assert abs(depth - previous) <= step * 1.001, (k, previous, depth)
        previous = depth


def test_a_ball_wider_than_a_groove_rests_on_its_edges():
    """A ball of radius r sinks r - sqrt(r^2 - (w/2)^2) into a groove of width w: 5 mm over a groove
    1 mm long and 2 mm deep, 25 um, a little more where the polyline's chords cut the groove's
    edges (one segment, ~0.1 mm, on each side: 37 um) and the rim curves away (2 um); not 2 mm."""
    r = 0.005
    env = environment("disk", (feature(90.0, 0.001, 0.002),), r)
    plain = environment("disk", (), r)
    x = 0.002  # above the groove's middle
    on_the_rim = -0.001 + 0.07 + r
    high, low = on_the_rim, on_the_rim - 0.003  # bisect the height where the ball first touches
    for _ in range(60):
        middle = 0.5 * (high + low)
        high, low = (high, middle) if env.penetration(x, middle)[0] > 0.0 else (middle, low)
    sink = on_the_rim - high
    assert abs(plain.penetration(x, on_the_rim)[0]) < 1e-9
    assert r - math.sqrt(r * r - 0.0005**2) < sink < 45e-6
    depth, nx, ny = env.penetration(x, high - 20e-6)
    assert depth > 0.0 and abs(nx) < 0.2 and ny > 0.98  # pushed back out of the groove


def slot_environment(width_m: float, tool_radius_m: float) -> PolylineEnvironment:
    """A part with a straight slot of ``width_m`` cut into its top edge (+Y), 10 mm deep, its walls at
    x = -w/2 and x = +w/2: a polygon resampled densely, counter-clockwise."""
    w, h = width_m / 2.0, 0.01
    corners = [
        (-0.05, -0.05),
        (0.05, -0.05),
        (0.05, 0.0),
        (w, 0.0),
        (w, -h),
        (-w, -h),
        (-w, 0.0),
        (-0.05, 0.0),
    ]
    closed = np.array([*corners, corners[0]])
    pieces = [
        np.linspace(a, b, max(2, int(math.dist(a, b) / 1e-4)), endpoint=False)
        for a, b in itertools.pairwise(closed)
    ]
    contact = ContactParams(0.5, 0.01, tool_radius_m, 1.0e6, 3.0e5, 200.0, 0.15)
    return PolylineEnvironment(np.vstack(pieces), contact)


def test_a_ball_between_two_walls_narrower_than_it_is_pushed_by_both():
    """A ball of 0.5 mm radius in a slot 0.9 mm wide, 5 mm down: centred, each wall presses it by
    50 um and the two forces cancel; off-centre by 20 um, the nearer wall presses 70 um and the other
    30 um, the sum 40 um's worth towards the slot's middle, on either side alike (no flip)."""
    r = 0.0005
    env = slot_environment(0.0009, r)
    k = env._k_series
    contacts = env.contacts(0.0, -0.005)
    assert len(contacts) == 2
    assert sorted(round(nx) for _, nx, _ in contacts) == [-1, 1]
    for depth, _, _ in contacts:
        assert abs(depth - 50e-6) < 1e-9
    fx, fy, _ = env.contact_force(0.0, -0.005, 0.5, 0.0, 0.0)
    assert abs(fx) < 1e-6 and abs(fy) < 1e-6
    assert abs(env.last_max_normal_force_n - k * 50e-6) < 1e-6  # each wall pressed, the sum nothing
    for x in (-2e-5, -1e-5, -1e-6, 1e-6, 1e-5, 2e-5):  # across the middle: the force goes through zero
        fx, fy, _ = env.contact_force(x, -0.005, 0.5, 0.0, 0.0)
        assert abs(fx - (-k * 2 * x)) < 1e-6 * k, (x, fx)
        assert abs(fy) < 1e-6
        assert abs(env.last_max_normal_force_n - k * (50e-6 + abs(x))) < 1e-6
    # moving along the slot: each wall's friction opposes the motion, twice the one wall's
    fx, fy, _ = env.contact_force(2e-5, -0.005, 0.5, 0.0, 0.01)
    assert fy < 0.0 and abs(fy + 0.15 * k * (70e-6 + 30e-6) * math.tanh(10.0)) < 1e-6


def test_a_ball_in_a_concave_arc_larger_than_itself_touches_once():
    """A kidney's dent is concave (curvature radius ~10 mm here); a ball of 2 mm pressed into its
    middle touches it in one place, with the single-contact model's force to the bit."""
    r = 0.002
    env = environment("kidney", (), r)
    i = int(np.argmin(env.points[:, 0]))  # the dent's middle, on -X
    (px, py), (nx, ny) = env.points[i], env.normals[i]
    for depth in (1e-5, 1e-4, 3e-4):
        for along in (-1e-3, 0.0, 1e-3):
            x, y = px + (r - depth) * nx - along * ny, py + (r - depth) * ny + along * nx
            contacts = env.contacts(x, y)
            assert len(contacts) == 1, (depth, along, contacts)
            assert contacts[0] == env.penetration(x, y)
            fn = env._k_series * contacts[0][0]
            assert abs(math.hypot(*env.contact_force(x, y, 0.5, 0.0, 0.0)[:2]) - fn) < 1e-9
            assert env.last_max_normal_force_n == fn


def test_the_notch_of_the_report_pushes_the_ball_by_both_walls_without_a_flip():
    """The reproducer: a 45-degree notch 8 mm deep and 3 mm long at 200 deg on the shipped disk, a ball
    of 0.5 mm between its walls (~0.44 mm from each). Across its midline the summed force turns
    gradually; the nearest wall's alone turned by ~170 deg in one sample."""
    overrides = [
        "task.kind=contour",
        "sim.workpiece.tool_radius_m=0.0005",
        "sim.workpiece.features=[{angle_deg=200.0,length_m=0.003,depth_m=0.008}]",
    ]
    env = workpiece_environment(load_config(None, dict(parse_override(o) for o in overrides)).sim.workpiece)
    assert isinstance(env, PolylineEnvironment)
    x0, y0 = -0.05791, -0.02285
    contacts = env.contacts(x0, y0)
    assert len(contacts) == 2 and all(d > 0.0 for d, _, _ in contacts)
    (_, ax, ay), (_, bx, by) = contacts
    across = (ax - bx, ay - by)  # from one wall's normal towards the other's: across the notch
    norm = math.hypot(*across)
    previous = None
    for s in np.linspace(-3e-5, 3e-5, 61):
        x, y = x0 + s * across[0] / norm, y0 + s * across[1] / norm
        fx, fy, _ = env.contact_force(x, y, env.contact.height_m, 0.0, 0.0)
        if previous is not None:
            assert math.hypot(fx - previous[0], fy - previous[1]) < 0.05 * env.last_max_normal_force_n + 1.0
        previous = (fx, fy)
