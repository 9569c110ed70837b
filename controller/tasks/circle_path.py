"""A circle in a plane parallel to XY, travelled with a smooth speed profile.

The tangential speed ramps from 0 to ``speed`` over ``ramp_s`` with the cycloidal profile
v(tau) = V (x - sin(2 pi x) / (2 pi)), x = tau / T_ramp, whose acceleration
V / T (1 - cos(2 pi x)) is zero at both ends (finite jerk), stays at V, and ramps down the
same way. Each ramp covers V T / 2 of arc.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property
from typing import Protocol

import numpy as np


@dataclass(frozen=True)
class CirclePath:
    center_m: tuple[float, float, float]
    radius_m: float
    speed_m_s: float
    laps: float
    ramp_s: float
    start_angle_rad: float = 0.0

    def __post_init__(self) -> None:
        if self.arc_length_m < self.speed_m_s * self.ramp_s:
            raise ValueError(
                f"circle of {self.laps} laps ({self.arc_length_m:.3f} m) is shorter than its two speed ramps "
                f"({self.speed_m_s * self.ramp_s:.3f} m at {self.speed_m_s} m/s over {self.ramp_s} s each)"
            )

    # computed once: the path task asks for them several times a cycle
    @cached_property
    def arc_length_m(self) -> float:
        return 2.0 * math.pi * self.radius_m * self.laps

    @cached_property
    def duration_s(self) -> float:
        v, tr = self.speed_m_s, self.ramp_s
        return (self.arc_length_m - v * tr) / v + 2.0 * tr

    def _arc(self, tau: float) -> tuple[float, float, float]:
        """Arc length [m], speed [m/s] and tangential acceleration [m/s^2] at time ``tau``."""
        v, tr, total = self.speed_m_s, self.ramp_s, self.duration_s
        if tau <= 0.0:
            return 0.0, 0.0, 0.0
        if tau >= total:
            return self.arc_length_m, 0.0, 0.0
        two_pi = 2.0 * math.pi
        if tr > 0.0 and tau < tr:
            x = tau / tr
            s = v * tr * (x * x / 2.0 + (math.cos(two_pi * x) - 1.0) / (two_pi * two_pi))
            return s, v * (x - math.sin(two_pi * x) / two_pi), v / tr * (1.0 - math.cos(two_pi * x))
        if tr > 0.0 and tau > total - tr:
            s_end, speed, acc = self._arc(total - tau)
            return self.arc_length_m - s_end, speed, -acc
        return v * tr / 2.0 + v * (tau - tr), v, 0.0

    def position(self, tau: float) -> tuple[float, float, float]:
        """``sample``'s position in floats: the path task's every cycle (three samples, 10 us each in
        numpy against under 1 us here, issue 37). The same operations on the same doubles as
        ``sample``'s, element by element: the same position, bit for bit (a test holds it)."""
        s = self._arc(tau)[0]
        r = self.radius_m
        th = self.start_angle_rad + s / r
        cx, cy, cz = self.center_m
        return (float(cx) + r * math.cos(th), float(cy) + r * math.sin(th), float(cz) + r * 0.0)

    def sample(self, tau: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Position [m], velocity [m/s] and acceleration [m/s^2] at time ``tau`` from the start."""
        s, ds, dds = self._arc(tau)
        r = self.radius_m
        th = self.start_angle_rad + s / r
        c, sn = math.cos(th), math.sin(th)
        radial = np.array([c, sn, 0.0])
        tangent = np.array([-sn, c, 0.0])
        pos = np.asarray(self.center_m, dtype=float) + r * radial
        vel = ds * tangent
        acc = dds * tangent - (ds * ds / r) * radial
        return pos, vel, acc

    def points(self, n: int) -> np.ndarray:
        """``n`` positions evenly spread in time, for checks before the start."""
        return np.array([self.sample(t)[0] for t in np.linspace(0.0, self.duration_s, n)])


# -- a circle in any plane, with CirclePath's timing ----------------------------------------


class PlanarPath(Protocol):
    """A path in a plane parallel to XY around ``center_m`` (``CirclePath``)."""

    @property
    def center_m(self) -> tuple[float, float, float]: ...

    @property
    def duration_s(self) -> float: ...

    def sample(self, tau: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...


@dataclass(frozen=True)
class TiltedCirclePath:
    """``CirclePath`` (a circle parallel to XY) rotated into the plane normal to ``normal``.

    The in-plane axes: e_a = (n x z) / |n x z| (for n = (1, 1, 1)/sqrt(3): e_a = (1, -1, 0)/sqrt(2)),
    e_b = n x e_a; with ``start_angle_rad = 0`` the samples coincide with the 3-URU's
    ``uru.default_path`` (seed 003), the first robot to run a tilted circle.
    """

    base: PlanarPath  # a CirclePath
    normal: tuple[float, float, float]
    _rot: np.ndarray = field(init=False, repr=False, compare=False)  # in-plane axes and normal, columns

    def __post_init__(self) -> None:
        n = np.asarray(self.normal, float)
        n = n / np.linalg.norm(n)
        e_a = np.cross(n, [0.0, 0.0, 1.0])
        if np.linalg.norm(e_a) < 1e-9:  # normal along z: the base circle itself
            rot = np.eye(3)
        else:
            e_a = e_a / np.linalg.norm(e_a)  # (1, -1, 0)/sqrt(2) for n = (1, 1, 1)/sqrt(3)
            rot = np.column_stack([e_a, np.cross(n, e_a), n])
        rot.setflags(write=False)
        object.__setattr__(self, "_rot", rot)

    @property
    def duration_s(self) -> float:
        return self.base.duration_s

    def sample(self, tau: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        pos, vel, acc = self.base.sample(tau)
        c = np.asarray(self.base.center_m, float)
        rot = self._rot
        return c + rot @ (pos - c), rot @ vel, rot @ acc

    def points(self, n: int) -> np.ndarray:
        return np.array([self.sample(t)[0] for t in np.linspace(0.0, self.duration_s, n)])
