"""Which cycles are drawn, and what of them: the decimation of the 3D scene, shared by every viewer.

The loop runs at 400 Hz or more; a viewer needs ``rate_hz`` (``DEFAULT_SCENE_RATE_HZ``, 20 Hz).
``SceneSampler.sample`` takes every cycle's serialised ``cheope.v1.Cycle`` and parses only the
ones it draws (one in ``rate / rate_hz``), so the writer process pays the Protobuf parse and the
drawing at the scene rate, not the loop rate. It runs where the bytes already are, off the loop
thread: in the recorder's writer process (logs/session_writer.py) and in ``cheope replay``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from logs.robot_drawing import (
    DEFAULT_SCENE_RATE_HZ,
    DEFAULT_TRAIL_INTERVAL_S,
    TRAIL_ENTITY,
    MeasuredPose,
    Primitive,
    RobotDrawing,
    drawing_for_config,
)

if TYPE_CHECKING:
    from controller.config import Config


def pose_from_cycle(c: Any) -> MeasuredPose:
    """A parsed ``cheope.v1.Cycle`` as the drawing's ``MeasuredPose``."""
    st = c.state
    tcp = tuple(st.tcp_measured_m) if len(st.tcp_measured_m) == 3 else None
    ref = tuple(st.tcp_reference_m) if len(st.tcp_reference_m) == 3 else None
    force = (
        tuple(c.inputs.sensor.force_n)
        if c.inputs.HasField("sensor") and len(c.inputs.sensor.force_n) == 3
        else None
    )
    return MeasuredPose(
        t_s=c.t_s, q=tuple(d.position for d in c.inputs.drives), tcp_m=tcp, force_n=force, reference_m=ref
    )


@dataclass
class SceneFrame:
    t_s: float
    cycle: int
    moving: list[Primitive]
    message: Any = None  # the parsed cheope.v1.Cycle it was drawn from
    kept: frozenset[str] = frozenset()  # entities drawn before and left as they are (not cleared)
    scene_pb: bytes = b""  # its foxglove.SceneUpdate, once the writer has made it


class SceneSampler:
    """One ``SceneFrame`` per ``1 / rate_hz`` of the cycles' nominal time."""

    def __init__(
        self,
        drawing: RobotDrawing,
        rate_hz: float = DEFAULT_SCENE_RATE_HZ,
        trail_interval_s: float = DEFAULT_TRAIL_INTERVAL_S,
    ) -> None:
        if not (math.isfinite(rate_hz) and rate_hz > 0):
            raise ValueError(f"scene rate must be a positive number of Hz, got {rate_hz}")
        self.drawing = drawing
        self.interval_s = 1.0 / rate_hz
        self.trail_interval_s = trail_interval_s
        self._next_t = -math.inf
        self._next_trail_t = -math.inf
        self._fixed_sent = False
        self.moving_entities: set[str] = set()  # every moving entity drawn so far

    @classmethod
    def for_config(cls, cfg: Config, rate_hz: float = DEFAULT_SCENE_RATE_HZ) -> SceneSampler | None:
        drawing = drawing_for_config(cfg)
        return None if drawing is None else cls(drawing, rate_hz)

    def fixed_once(self) -> list[Primitive] | None:
        """The fixed parts the first time it is called, None after."""
        if self._fixed_sent:
            return None
        self._fixed_sent = True
        return self.drawing.fixed()

    def resend_fixed(self) -> None:
        """The fixed parts again at the next ``fixed_once`` (a new file of the session draws them too)."""
        self._fixed_sent = False

    def due(self, t_s: float) -> bool:
        return t_s >= self._next_t

    def sample(self, cycle_pb: bytes, t_s: float) -> SceneFrame | None:
        """The moving parts of this cycle when one is due at its time ``t_s``; None otherwise (nothing parsed)."""
        if t_s < self._next_t:
            return None
        from controller.messages import cheope_pb2 as pb

        c = pb.Cycle.FromString(cycle_pb)
        return self.sample_parsed(c)

    def sample_parsed(self, c: Any) -> SceneFrame | None:
        if c.t_s < self._next_t:
            return None
        self._next_t = (c.t_s if self._next_t == -math.inf else self._next_t) + self.interval_s
        if self._next_t <= c.t_s:  # a gap (paused recording): restart the grid here
            self._next_t = c.t_s + self.interval_s
        moving = self.drawing.moving(pose_from_cycle(c))  # every frame: the trail gains its point
        kept: frozenset[str] = frozenset()
        if TRAIL_ENTITY in self.moving_entities and c.t_s < self._next_trail_t:
            moving = [p for p in moving if p.entity != TRAIL_ENTITY]
            kept = frozenset({TRAIL_ENTITY})
        elif any(p.entity == TRAIL_ENTITY for p in moving):
            self._next_trail_t = c.t_s + self.trail_interval_s
        self.moving_entities.update(p.entity for p in moving)
        return SceneFrame(c.t_s, c.cycle, moving, c, kept=kept)
