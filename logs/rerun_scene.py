"""A robot drawing (``logs/robot_drawing.py``) as Rerun archetypes: solid capsules, cylinders, boxes, spheres.

Each drawing entity goes under ``/world/<entity>``, one child per shape (``capsules``,
``cylinders``, ``boxes``, ``spheres``, ``lines``, ``arrows``) because two archetypes of one entity
would share their components. ``RerunScene.log_moving`` clears the children a frame no longer
draws (the force arrow without a force), so the viewer does not keep a stale part.
Used by ``cheope replay --rerun`` and by the live stream of the writer process.
"""

from __future__ import annotations

import math
from collections import defaultdict
from typing import Any

from logs.foxglove_scene import quaternion_from_to
from logs.robot_drawing import Primitive, Shape

WORLD = "/world"
_Z: tuple[float, float, float] = (0.0, 0.0, 1.0)
_CHILD = {
    Shape.CAPSULE: "capsules",
    Shape.CYLINDER: "cylinders",
    Shape.BOX: "boxes",
    Shape.SPHERE: "spheres",
    Shape.LINE: "lines",
    Shape.ARROW: "arrows",
}


def _rgba(p: Primitive) -> list[int]:
    return [round(255 * x) for x in p.color]


def _labels(parts: list[Primitive]) -> dict[str, Any]:
    labels = [p.label for p in parts]
    return {"labels": labels, "show_labels": False} if any(labels) else {}


def archetypes(primitives: list[Primitive]) -> dict[str, Any]:
    """Entity path -> one Rerun archetype, for the given primitives."""
    import rerun as rr

    groups: dict[tuple[str, Shape], list[Primitive]] = defaultdict(list)
    for p in primitives:
        groups[(p.entity, p.shape)].append(p)
    out: dict[str, Any] = {}
    for (entity, shape), parts in groups.items():
        path = f"{WORLD}/{entity}/{_CHILD[shape]}"
        colors = [_rgba(p) for p in parts]
        if shape == Shape.CAPSULE:
            d = [(p.end[0] - p.start[0], p.end[1] - p.start[1], p.end[2] - p.start[2]) for p in parts]
            out[path] = rr.Capsules3D(  # plain floats: numpy's per-call overhead dominates for 3-vectors
                lengths=[math.hypot(*v) for v in d],
                radii=[p.radius_m for p in parts],
                translations=[p.start for p in parts],
                quaternions=[rr.Quaternion(xyzw=quaternion_from_to(_Z, v)) for v in d],
                colors=colors,
                fill_mode="solid",
                **_labels(parts),
            )
        elif shape == Shape.CYLINDER:
            out[path] = rr.Cylinders3D(
                lengths=[p.length_m for p in parts],
                radii=[p.radius_m for p in parts],
                centers=[p.start for p in parts],
                quaternions=[rr.Quaternion(xyzw=quaternion_from_to(_Z, p.end)) for p in parts],
                colors=colors,
                fill_mode="solid",
                **_labels(parts),
            )
        elif shape == Shape.BOX:
            out[path] = rr.Boxes3D(
                half_sizes=[(p.width_m / 2, p.width_m / 2, p.length_m / 2) for p in parts],
                centers=[p.start for p in parts],
                quaternions=[rr.Quaternion(xyzw=quaternion_from_to(_Z, p.end)) for p in parts],
                colors=colors,
                fill_mode="solid",
                **_labels(parts),
            )
        elif shape == Shape.SPHERE:
            out[path] = rr.Ellipsoids3D(
                half_sizes=[(p.radius_m,) * 3 for p in parts],
                centers=[p.start for p in parts],
                colors=colors,
                fill_mode="solid",
                **_labels(parts),
            )
        elif shape == Shape.LINE:
            out[path] = rr.LineStrips3D(
                [list(p.points) for p in parts],
                radii=[p.radius_m for p in parts],
                colors=colors,
                **_labels(parts),
            )
        elif shape == Shape.ARROW:
            vectors = [(p.end[0] - p.start[0], p.end[1] - p.start[1], p.end[2] - p.start[2]) for p in parts]
            if all(math.isfinite(x) for v in vectors for x in v):
                out[path] = rr.Arrows3D(
                    origins=[p.start for p in parts],
                    vectors=vectors,
                    radii=[p.radius_m for p in parts],
                    colors=colors,
                    **_labels(parts),
                )
    return out


class RerunScene:
    """Logs a drawing's fixed parts (static) and moving frames to one recording stream."""

    def __init__(self, rec: Any) -> None:
        self.rec = rec
        self._moving_paths: set[str] = set()

    def log_fixed(self, primitives: list[Primitive]) -> list[str]:
        import rerun as rr

        self.rec.log(WORLD, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        arch = archetypes(primitives)
        for path, a in arch.items():
            self.rec.log(path, a, static=True)
        return sorted(arch)

    def log_moving(self, primitives: list[Primitive], kept: frozenset[str] = frozenset()) -> list[str]:
        """At the stream's current time; returns the paths drawn. The entities in ``kept`` stay as
        they were drawn last (``SceneFrame.kept``: the trail between its redraws)."""
        import rerun as rr

        arch = archetypes(primitives)
        for path, a in arch.items():
            self.rec.log(path, a)
        kept_paths = {p for p in self._moving_paths for e in kept if p.startswith(f"{WORLD}/{e}/")}
        for gone in self._moving_paths - set(arch) - kept_paths:
            self.rec.log(gone, rr.Clear(recursive=False))
        self._moving_paths |= set(arch)
        return sorted(arch)
