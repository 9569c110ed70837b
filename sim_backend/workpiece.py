"""Any closed planar workpiece for the contour task: a dense polyline and its contact model.

The disk of seed 001 §7 has an exact model (``contact_disk.py``); every other shape lives here
as a closed counter-clockwise polyline sampled evenly by arc length, with a normal at every
vertex taken from the shape itself. The contact is the one of the disk: with penetration d of
the tool's ball into the part and outward normal n, F_n = max(0, k d - c d_dot) with the
series stiffness of contact and sensor, and smoothed Coulomb friction along the tangent.

The penetration is the ball's true overlap with the part: its radius less the signed distance
of its centre from the nearest point of the whole boundary (negative inside), so a ball wider
than a narrow notch rests on its edges and a deep notch's far wall is met where it is. That
nearest point is found exactly every sub-step: a walk from the last nearest segment bounds
the distance, and a k-d tree of the vertices gives every segment that could be nearer (9.5 us
a call against the walk alone's 8.0 us, before the multi-contact). The walk alone stopped at a local minimum: on a
notch's far wall the tool sank 7-9 mm into steel at 0-10 N, then met 1529 N at once when the
walk restarted. Inside the boundary the normal at the nearest point is interpolated between
the two vertex normals (as a smooth surface's would be), so a dense polyline has no facets the
tool could feel; outside, it points from the nearest point to the ball's centre.

A ball may touch the boundary in several places at once: wedged in a notch narrower than itself it
presses on both walls. The force is the sum of every distinct contact's (normal force and friction
each along its own normal); the nearest point alone gave only the nearer wall's, which turned by
~170 deg in one sample as the centre crossed the notch's midline. The contacts are the local minima
of the centre's distance to the boundary, taken along the boundary, within the tool's radius; the
nearest point of the whole boundary is the deepest. One stretch the ball presses into must count
once, though a polyline's facets (a concave arc's chords, a shallow corner) give it several local
minima: a minimum is the same contact as a deeper one when both lie in one contact patch (a run of
boundary within the ball, unbroken) and their normals are within ``MERGE_ANGLE_DEG`` (45 deg) of each
other; it is dropped, the deepest kept. So a ball in a concave arc larger than itself, or in a corner
flatter than 135 deg, touches once (as the single-contact model had it, to the bit); the two walls of a
notch (normals 90-180 deg apart) are two contacts even where the ball reaches the notch's bottom and
its patches join; a ball resting on a groove's two edges (normals a few degrees apart, a gap of air
between) is two contacts. Closeness along the boundary alone would not do: a short notch's walls are
close along it. A minimum other than the nearest counts only from outside the part (the ball reaching
it through the part, say past a thin sliver's far side, would add a force from within the material).
The cost: the k-d tree is asked for the ball's disk (r) when the tool is in contact, else the walk's;
its answer, for a disk 0.3 mm wider, is kept while the tool stays within (the tool moves a fraction of
a millimetre a sub-step), and patches and merging are worked out only when two minima lie within the
ball. ``last_max_normal_force_n`` is the largest single contact's normal force of the last call: in a
wedge the sensor reads the vector sum, which may be small while each wall is pressed harder.

Shapes (``[sim.workpiece] shape``), in the workpiece's own frame before ``rotation_deg`` and
``centre_m``: ``disk`` (radius), ``ellipse`` (semi-axes ``size_m``), ``rounded_rectangle``
(half extents ``size_m``, ``corner_radius_m``), ``rounded_star`` (``lobes`` lobes of
``lobe_depth_m`` about a mean radius; concave between lobes), ``kidney`` (a disk with one
dent of ``lobe_depth_m``; concave there). Features on any shape: a ``notch`` (a recess of a
given length and depth with 45-degree walls) and a ``bump`` (a raised stretch with gentle ramps),
each placed at an angle about the centre.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from sim_backend.environment import NO_FORCE, Vector3, series_stiffness_n_m

SAMPLES = 4096  # vertices of the polyline: 0.1-0.2 mm apart on the shipped shapes
NOTCH_WALL_SLOPE = (
    1.0  # a notch's walls: 45 deg chamfers (wall length = depth), as a recess cut with a chamfer
)
MERGE_ANGLE_DEG = 45.0  # two touches of one contact patch closer in direction than this are one contact
MERGE_COS = math.cos(math.radians(MERGE_ANGLE_DEG))
QUERY_MARGIN_M = 0.3e-3  # the k-d tree asked this much wider, its answer kept while the tool stays within
BUMP_RAMP_M = 10.0e-3  # a bump's flanks: 10 mm long, as a weld seam's or a taped shim's


@dataclass(frozen=True)
class Feature:
    """A recess (``depth_m`` > 0) or a raised stretch (``depth_m`` < 0) of the boundary."""

    angle_deg: float  # where its middle is, about the workpiece's centre (before rotation)
    length_m: float  # along the boundary
    depth_m: float  # inwards; negative: outwards (a bump)
    ramp_m: float  # length of each transition


@dataclass(frozen=True)
class ShapeParams:
    shape: str
    centre_m: tuple[float, float]
    rotation_deg: float
    radius_m: float  # disk, star and kidney: the mean radius
    size_m: tuple[float, float]  # ellipse: semi-axes; rounded rectangle: half extents
    corner_radius_m: float
    lobes: int
    lobe_depth_m: float
    features: tuple[Feature, ...] = field(default=())


SHAPES = ("disk", "ellipse", "rounded_rectangle", "rounded_star", "kidney")


def _polar(radius: np.ndarray, theta: np.ndarray) -> np.ndarray:
    return np.column_stack([radius * np.cos(theta), radius * np.sin(theta)])


def _rounded_rectangle(a: float, b: float, rc: float, n: int) -> np.ndarray:
    """Counter-clockwise outline of a rectangle of half extents a, b with corners of radius rc."""
    rc = min(rc, a, b)
    pieces = []
    corners = (
        (a - rc, b - rc, 0.0),
        (-(a - rc), b - rc, 0.5 * math.pi),
        (-(a - rc), -(b - rc), math.pi),
        ((a - rc), -(b - rc), 1.5 * math.pi),
    )
    for cx, cy, start in corners:  # each corner's arc, then the straight edge to the next (resampled later)
        th = np.linspace(start, start + 0.5 * math.pi, n // 16, endpoint=True)
        pieces.append(np.column_stack([cx + rc * np.cos(th), cy + rc * np.sin(th)]))
    return np.vstack(pieces)


def _raw_outline(p: ShapeParams) -> np.ndarray:
    """A closed outline (first point not repeated), counter-clockwise, in the workpiece's frame."""
    theta = np.linspace(0.0, 2.0 * math.pi, 8 * SAMPLES, endpoint=False)
    if p.shape == "disk":
        return _polar(np.full_like(theta, p.radius_m), theta)
    if p.shape == "ellipse":
        return np.column_stack([p.size_m[0] * np.cos(theta), p.size_m[1] * np.sin(theta)])
    if p.shape == "rounded_rectangle":
        return _rounded_rectangle(p.size_m[0], p.size_m[1], p.corner_radius_m, 8 * SAMPLES)
    if p.shape == "rounded_star":
        return _polar(p.radius_m + p.lobe_depth_m * np.cos(p.lobes * theta), theta)
    if p.shape == "kidney":  # one dent on the -X side, a Gaussian in the angle
        dent = p.lobe_depth_m * np.exp(-((theta - math.pi) ** 2) / (2.0 * 0.5**2))
        return _polar(p.radius_m - dent, theta)
    raise ValueError(f"unknown workpiece shape {p.shape!r} (one of {', '.join(SHAPES)})")


def _resample(points: np.ndarray, n: int) -> np.ndarray:
    """``n`` points evenly spaced by arc length along the closed polyline ``points``."""
    closed = np.vstack([points, points[:1]])
    seg = np.hypot(*np.diff(closed, axis=0).T)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    target = np.linspace(0.0, s[-1], n, endpoint=False)
    return np.column_stack([np.interp(target, s, closed[:, 0]), np.interp(target, s, closed[:, 1])])


def _vertex_normals(points: np.ndarray) -> np.ndarray:
    """Outward unit normals of a counter-clockwise closed polyline: the central difference turned by -90 deg."""
    tangent = np.roll(points, -1, axis=0) - np.roll(points, 1, axis=0)
    normal = np.column_stack([tangent[:, 1], -tangent[:, 0]])
    result: np.ndarray = normal / np.hypot(normal[:, 0], normal[:, 1])[:, None]
    return result


def _plateau(distance: np.ndarray, half_length: float, ramp: float) -> np.ndarray:
    """1 within ``half_length - ramp`` of the middle, 0 beyond ``half_length``, a cosine between."""
    inner = max(half_length - ramp, 0.0)
    x = np.clip((np.abs(distance) - inner) / max(half_length - inner, 1e-12), 0.0, 1.0)
    result: np.ndarray = 0.5 * (1.0 + np.cos(math.pi * x))
    return result


def _apply_feature(points: np.ndarray, f: Feature) -> np.ndarray:
    closed = np.vstack([points, points[:1]])
    s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(closed, axis=0).T))])[:-1]
    perimeter = s[-1] + float(np.hypot(*(points[0] - points[-1])))
    angles = np.arctan2(points[:, 1], points[:, 0])
    middle = int(np.argmin(np.abs((angles - math.radians(f.angle_deg) + math.pi) % (2 * math.pi) - math.pi)))
    along = (s - s[middle] + perimeter / 2) % perimeter - perimeter / 2
    weight = _plateau(along, f.length_m / 2.0, f.ramp_m)
    result: np.ndarray = points - (f.depth_m * weight)[:, None] * _vertex_normals(points)
    return result


def outline(p: ShapeParams, n: int = SAMPLES) -> np.ndarray:
    """The workpiece's boundary in the base frame's XY: ``n`` points, counter-clockwise, evenly spaced."""
    pts = _resample(_raw_outline(p), n)
    for f in p.features:
        pts = _resample(_apply_feature(pts, f), n)
    c, s = math.cos(math.radians(p.rotation_deg)), math.sin(math.radians(p.rotation_deg))
    rotated = pts @ np.array([[c, s], [-s, c]])
    result: np.ndarray = rotated + np.asarray(p.centre_m)
    return result


@dataclass(frozen=True)
class ContactParams:
    height_m: float
    thickness_m: float
    tool_radius_m: float
    contact_stiffness_n_m: float
    sensor_stiffness_n_m: float
    contact_damping_n_s_m: float
    friction_coefficient: float
    friction_velocity_m_s: float = 1e-3


def _unit_right(dx: float, dy: float) -> tuple[float, float]:
    """The unit vector of (dx, dy) turned by -90 deg: a counter-clockwise boundary's outward normal."""
    length = math.hypot(dx, dy) or 1.0
    return dy / length, -dx / length


class PolylineEnvironment:
    """Contact of the tool's ball with a closed planar polyline workpiece (see the module's text)."""

    def __init__(self, points_m: np.ndarray, contact: ContactParams) -> None:
        self.points = np.asarray(points_m, dtype=float)
        self.normals = _vertex_normals(self.points)
        self.contact = contact
        self._k_series = series_stiffness_n_m(contact.contact_stiffness_n_m, contact.sensor_stiffness_n_m)
        self._xy = [(float(x), float(y)) for x, y in self.points]
        self._nxy = [(float(x), float(y)) for x, y in self.normals]
        self._n = len(self._xy)
        self._tree = cKDTree(self.points)
        self._hint: int | None = None
        self._near: tuple[float, float, float, list[tuple[int, float, float]]] = (math.inf, math.inf, 0.0, [])
        self._seg: list[tuple[float, float, float]] = []  # each segment i -> i+1: dx, dy, squared length
        for (ax, ay), (bx, by) in zip(self._xy, self._xy[1:] + self._xy[:1], strict=True):
            dx, dy = bx - ax, by - ay
            self._seg.append((dx, dy, dx * dx + dy * dy))
        self.last_max_normal_force_n = 0.0  # the largest single contact's normal force of the last call
        edges = np.roll(self.points, -1, axis=0) - self.points
        # a segment nearer than the nearest vertex has an end within sqrt(d^2 + (L/2)^2) of the tool
        self._half_edge2 = 0.25 * float(np.max(edges[:, 0] ** 2 + edges[:, 1] ** 2))
        centre = self.points.mean(axis=0)
        self._centre = (float(centre[0]), float(centre[1]))
        self._max_radius = float(np.max(np.hypot(*(self.points - centre).T)))

    def contour_points(self, n: int = 360) -> np.ndarray:
        """The boundary (for plots and viewers), closed, at the workpiece's height."""
        idx = np.linspace(0, self._n, n, endpoint=False).astype(int)
        pts = np.vstack([self.points[idx], self.points[:1]])
        return np.column_stack([pts, np.full(len(pts), self.contact.height_m)])

    def _segment(self, i: int, x: float, y: float) -> tuple[float, float, float, float]:
        """Squared distance to segment i -> i+1, the parameter along it, and the nearest point."""
        ax, ay = self._xy[i]
        bx, by = self._xy[(i + 1) % self._n]
        dx, dy = bx - ax, by - ay
        length2 = dx * dx + dy * dy
        t = min(max(((x - ax) * dx + (y - ay) * dy) / length2, 0.0), 1.0) if length2 > 0.0 else 0.0
        px, py = ax + t * dx, ay + t * dy
        return (x - px) ** 2 + (y - py) ** 2, t, px, py

    def _walk(self, x: float, y: float) -> float:
        """A distance to the boundary no shorter than the true one, cheaply: walk downhill from the
        last nearest segment (the tool moves a fraction of a segment per sub-step) to a local minimum."""
        if self._hint is None:
            d2 = (self.points[:, 0] - x) ** 2 + (self.points[:, 1] - y) ** 2
            self._hint = int(np.argmin(d2))
        hint = self._hint
        best = self._segment(hint, x, y)[0]
        for step in (1, -1):
            while True:
                j = (hint + step) % self._n
                d = self._segment(j, x, y)[0]
                if d >= best:
                    break
                hint, best = j, d
        return math.sqrt(best)

    def _candidates(
        self, x: float, y: float
    ) -> tuple[list[tuple[int, float, float, float, float]], int, int]:
        """Every segment that could be the nearest to the point (x, y) or lie within the tool's ball of
        radius r, in order along the boundary, each once: its index, squared distance, parameter and
        nearest point; the position of the nearest among them; and how many local minima of the
        distance along the boundary lie within the ball (an overcount where the list wraps past vertex
        0). Exact: only the segments with an end within sqrt(D^2 + (L/2)^2) of the point can be nearer
        than D (Pythagoras at the foot of the perpendicular; L the longest segment), found in a k-d tree.
        D is r when a segment lies within the ball (the tool in contact: then the nearest is within r
        too); else the distance of a walk's local minimum, which bounds the nearest's. The walk alone
        stopped on a notch's far wall, a local minimum (an outside tester's 1529 N in a 1-mm notch)."""
        r = self.contact.tool_radius_m
        if r > 0.0:
            found, best, minima = self._gather(x, y, r)
            if found and found[best][1] < r * r:
                return found, best, minima
        return self._gather(x, y, self._walk(x, y))

    def _near_vertices(self, x: float, y: float, reach: float) -> list[int]:
        """The vertices within ``reach`` of (x, y), in order: from the k-d tree, asked for a wider disk
        once and that answer kept while the disk asked for lies within it (the tool moves a fraction of
        a millimetre between the tree's queries; the answer is the same set either way)."""
        cx, cy, cached_reach, cached = self._near
        reach2 = reach * reach
        if math.hypot(x - cx, y - cy) + reach > cached_reach:
            wide = reach + QUERY_MARGIN_M
            xy = self._xy
            cached = [(j, *xy[j]) for j in self._tree.query_ball_point((x, y), wide, return_sorted=True)]
            self._near = (x, y, wide, cached)
        return [j for j, vx, vy in cached if (vx - x) ** 2 + (vy - y) ** 2 <= reach2]

    def _gather(
        self, x: float, y: float, bound: float
    ) -> tuple[list[tuple[int, float, float, float, float]], int, int]:
        """The segments that could be within ``bound`` of (x, y), the nearest's position among them and
        the local minima within the ball (see ``_candidates``)."""
        reach = math.sqrt(bound * bound + self._half_edge2) * (1.0 + 1e-9) + 1e-12
        n, xy, seg, r2 = self._n, self._xy, self._seg, self.contact.tool_radius_m**2
        found: list[tuple[int, float, float, float, float]] = []
        best, best_d2, last = 0, math.inf, -2
        minima, falling, last_d2 = 0, False, math.inf
        for j in self._near_vertices(x, y, reach):
            for i in (j - 1, j):  # the segments on either side of the vertex, each once (-1: the last)
                if i <= last:
                    continue
                k = i % n
                ax, ay = xy[k]
                dx, dy, length2 = seg[k]
                t = min(max(((x - ax) * dx + (y - ay) * dy) / length2, 0.0), 1.0) if length2 > 0.0 else 0.0
                px, py = ax + t * dx, ay + t * dy
                d2 = (x - px) ** 2 + (y - py) ** 2
                if d2 < best_d2:
                    best, best_d2 = len(found), d2
                found.append((k, d2, t, px, py))
                # the last segment a local minimum within the ball? (lower than both neighbours)
                if i == last + 1:
                    if falling and d2 >= last_d2 and last_d2 < r2:
                        minima += 1
                    falling = d2 < last_d2
                else:
                    if falling and last_d2 < r2:
                        minima += 1
                    falling = True
                last, last_d2 = i, d2
        if falling and last_d2 < r2:
            minima += 1
        if len(found) > 1 and found[0][0] == n - 1 and found[-1][0] == n - 1:
            found.pop()  # the last segment, met from both of its ends (vertex 0 and vertex n - 1)
        if found:
            self._hint = found[best][0]
        return found, best, minima

    def _inside(self, i: int, t: float, x: float, y: float, px: float, py: float) -> bool:
        """Whether (x, y) is inside the part, from its nearest point on segment i: left of the segment
        when that point is within it (counter-clockwise boundary); at a vertex, behind the sum of its
        two segments' outward normals (exact for a polygon: Baerentzen and Aanaes' pseudo-normal)."""
        if 0.0 < t < 1.0:
            ax, ay = self._xy[i]
            bx, by = self._xy[(i + 1) % self._n]
            return (bx - ax) * (y - ay) - (by - ay) * (x - ax) > 0.0
        v = (i + 1) % self._n if t >= 1.0 else i
        (ax, ay), (vx, vy), (bx, by) = self._xy[v - 1], self._xy[v], self._xy[(v + 1) % self._n]
        nx, ny = _unit_right(vx - ax, vy - ay)
        mx, my = _unit_right(bx - vx, by - vy)
        return (x - px) * (nx + mx) + (y - py) * (ny + my) < 0.0

    def _depth(
        self, i: int, d2: float, t: float, px: float, py: float, x: float, y: float
    ) -> tuple[float, float, float]:
        """How deep the ball reaches past the boundary at its nearest point (px, py) on segment i, and the
        outward unit normal there (see ``penetration``)."""
        distance = math.sqrt(d2)
        if not self._inside(i, t, x, y, px, py) and distance > 1e-9:
            return self.contact.tool_radius_m - distance, (x - px) / distance, (y - py) / distance
        (n0x, n0y), (n1x, n1y) = self._nxy[i], self._nxy[(i + 1) % self._n]
        nx, ny = n0x + t * (n1x - n0x), n0y + t * (n1y - n0y)
        norm = math.hypot(nx, ny) or 1.0
        return self.contact.tool_radius_m + distance, nx / norm, ny / norm

    def contacts(self, x_m: float, y_m: float) -> list[tuple[float, float, float]]:
        """Every distinct contact of the tool's ball with the part (see the module's text): its depth [m]
        and outward unit normal, the deepest first. The first is the nearest point of the whole boundary
        (``penetration``), given even when the ball is apart from the part (depth <= 0); the others are
        further local minima of the distance along the boundary, within the ball, reached from outside
        the part, and each in another contact patch than every deeper one or turned from it by more
        than ``MERGE_ANGLE_DEG``."""
        found, best, minima = self._candidates(x_m, y_m)
        nearest = self._depth(*found[best], x_m, y_m)
        if minima < 2:
            return [nearest]  # one local minimum within the ball at most: the nearest point's
        r2 = self.contact.tool_radius_m**2
        n, m = self._n, len(found)
        close = [k for k, f in enumerate(found) if f[1] < r2]
        # the contact patches: runs of adjacent segments within the ball (the first may go on from the last)
        patch, label = [0] * m, 0
        for k in range(m):
            g, h = found[k - 1], found[k]
            if not (h[1] < r2 and g[1] < r2 and (h[0] - g[0]) % n == 1):
                label += 1
            patch[k] = label
        if label and patch[0] == 0:  # no break between the last and the first: one patch
            patch = [0 if p == label else p for p in patch]
        others = []
        for k in close:
            g, h, q = found[k - 1], found[k], found[(k + 1) % m]
            before = g[1] if (h[0] - g[0]) % n == 1 else math.inf
            after = q[1] if (q[0] - h[0]) % n == 1 else math.inf
            if k != best and h[1] < before and h[1] <= after:
                others.append(k)
        if not others:
            return [nearest]
        others.sort(key=lambda k: found[k][1])
        kept = [(nearest, patch[best] if found[best][1] < r2 else -1)]
        for k in others:
            i, d2, t, px, py = found[k]
            if self._inside(i, t, x_m, y_m, px, py):
                continue  # reached only through the part: the nearest point already says how deep it is
            distance = math.sqrt(d2)
            if distance <= 1e-9:
                continue
            nx, ny = (x_m - px) / distance, (y_m - py) / distance
            if any(p == patch[k] and nx * c[1] + ny * c[2] > MERGE_COS for c, p in kept):
                continue  # the same contact as a deeper one: a concave stretch, a polyline's facets
            kept.append(((self.contact.tool_radius_m - distance, nx, ny), patch[k]))
        return [c for c, _ in kept]

    def penetration(self, x_m: float, y_m: float) -> tuple[float, float, float]:
        """How deep the tool's ball reaches into the part [m] (<= 0: apart), and the outward unit
        normal it is pushed along, at the nearest point of the whole boundary (the deepest contact).
        The depth is the tool radius less the signed distance of its centre from the boundary (negative
        inside): the true overlap of a ball and the profile, continuous as the tool moves. Outside, the
        normal points from the nearest boundary point to the centre (a ball on a corner is pushed away
        from the corner); inside, it is the boundary's normal there, interpolated between the vertices'
        as a smooth surface's would be (no facets to feel)."""
        found, best, _ = self._candidates(x_m, y_m)
        return self._depth(*found[best], x_m, y_m)

    def contact_force(self, x_m: float, y_m: float, z_m: float, vx_m_s: float, vy_m_s: float) -> Vector3:
        c = self.contact
        self.last_max_normal_force_n = 0.0
        if abs(z_m - c.height_m) > c.thickness_m / 2 + c.tool_radius_m:
            return NO_FORCE
        if (
            math.hypot(x_m - self._centre[0], y_m - self._centre[1])
            > self._max_radius + c.tool_radius_m + 1e-3
        ):
            return NO_FORCE  # far outside: no search
        fx = fy = most = 0.0
        for penetration, nx, ny in self.contacts(x_m, y_m):
            if penetration <= 0.0:
                continue
            fn = self._k_series * penetration - c.contact_damping_n_s_m * (vx_m_s * nx + vy_m_s * ny)
            if fn <= 0.0:
                continue
            tx, ty = -ny, nx
            friction = (
                -c.friction_coefficient
                * fn
                * math.tanh((vx_m_s * tx + vy_m_s * ty) / c.friction_velocity_m_s)
            )
            fx, fy, most = fx + fn * nx + friction * tx, fy + fn * ny + friction * ty, max(most, fn)
        self.last_max_normal_force_n = most
        if most == 0.0:
            return NO_FORCE
        return (fx, fy, 0.0)
