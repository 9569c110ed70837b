"""The robot in 3D in the recording: ``/scene`` decodes with the Foxglove schemas and draws each robot.

Each robot's session is recorded by the production recorder (its writer process) from the
in-process simulated devices in simulated time; the ``/scene`` channel is read back with the
``mcap`` reader and decoded with ``foxglove_schemas_protobuf``'s ``SceneUpdate``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader

from controller.assembly import build_law
from controller.config import Config, load_config
from controller.robot_registry import robot_entry
from controller.shell.loop import CycleLoop, SimulatedTime
from logs import messages as m
from logs.recorder import SessionRecorder, session_metadata
from sim_backend.loopback import LoopbackExchange

FIXED = {"cheope": {"base", "guides"}, "uru": {"base", "motors"}, "nspu": {"base"}}
MOVING = {
    "cheope": {"sliders", "rods", "platform", "tool", "force"},
    "uru": {"proximal_links", "distal_links", "joints", "platform", "tool"},
    "nspu": {"legs", "platform", "tool"},
}


def _record(path: Path, cfg: Config, max_s: float) -> None:
    clock = SimulatedTime()
    law = build_law(cfg)
    exchange = LoopbackExchange(cfg, clock.clock)
    with SessionRecorder(
        path, session_metadata(cfg), clock=clock.clock, phase_name=law.task.phase_name, lossless=True
    ) as rec:
        loop = CycleLoop(
            law, exchange, cfg.period_s, cfg.loop.collect_fraction, clock, clock.clock, observers=(rec,)
        )
        loop.run(law.initial_state(), max_s)


@dataclass(frozen=True)
class Logged:
    log_time_ns: int
    message: Any  # a decoded SceneUpdate or Cycle


def _scene(path: Path) -> tuple[str, list[Any], list[Any]]:
    """(schema name, the SceneUpdates in order, the /cycle messages) of a recording."""
    schema, updates, cycles = _logged(path)
    return schema, [u.message for u in updates], [c.message for c in cycles]


def _logged(path: Path) -> tuple[str, list[Logged], list[Logged]]:
    """The same with each message's MCAP log time."""
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

    from controller.messages import cheope_pb2 as pb

    updates: list[Logged] = []
    cycles: list[Logged] = []
    schema = ""
    with path.open("rb") as f:
        for sch, channel, message in make_reader(f).iter_messages(topics=[m.TOPIC_SCENE, m.TOPIC_CYCLE]):
            if channel.topic == m.TOPIC_SCENE:
                schema = sch.name
                updates.append(Logged(message.log_time, SceneUpdate.FromString(message.data)))
            else:
                cycles.append(Logged(message.log_time, pb.Cycle.FromString(message.data)))
    return schema, updates, cycles


def _config(kind: str, overrides: dict[str, object] | None = None) -> Config:
    entry = robot_entry(kind)
    assert entry.config_file is not None
    return load_config(entry.config_file, overrides=overrides)


def _length(cylinder: object) -> float:
    return float(cylinder.size.z)


@pytest.mark.parametrize("kind", ["cheope", "uru", "nspu"])
def test_the_scene_decodes_with_the_foxglove_schema_and_holds_each_robots_parts(tmp_path, kind):
    cfg = _config(kind)
    path = tmp_path / f"{kind}.mcap"
    _record(path, cfg, 1.5)
    schema, updates, cycles = _scene(path)
    assert schema == "foxglove.SceneUpdate"
    first = {e.id for e in updates[0].entities}
    assert FIXED[kind] <= first, first
    assert all(e.frame_id == "base" for u in updates for e in u.entities)
    moving = [u for u in updates[1:]]
    drawn = {
        e.id
        for u in moving
        for e in u.entities
        if len(e.cylinders) + len(e.spheres) + len(e.cubes) + len(e.arrows)
    }
    assert MOVING[kind] <= drawn, drawn
    # decimated: one update per 1/20 s of the cycles' time, not one per cycle
    span_s = cycles[-1].t_s - cycles[0].t_s
    assert abs(len(moving) - span_s * cfg.recording.scene_rate_hz) <= 2, (len(moving), span_s)
    assert len(moving) < len(cycles) / 10
    # the fixed parts go out once
    assert sum(1 for u in updates for e in u.entities if e.id == "base") == 1


def _entity(update: object, name: str) -> object:
    return next(e for e in update.entities if e.id == name)


def test_cheopes_rods_keep_their_length_and_start_at_the_sliders(tmp_path):
    cfg = _config("cheope")
    rod_m = cfg.robot.model("cheope").rod_length_m
    path = tmp_path / "c.mcap"
    _record(path, cfg, 1.5)
    _, updates, _ = _scene(path)
    last = updates[-1]
    rods = _entity(last, "rods")
    assert len(rods.cylinders) == 3
    for c in rods.cylinders:
        assert _length(c) == pytest.approx(rod_m, abs=1e-6)
    sliders = _entity(last, "sliders")
    assert len(sliders.cubes) == 3


def test_uru_links_have_the_configured_lengths(tmp_path):
    cfg = _config("uru")
    u = cfg.robot.model("uru")
    path = tmp_path / "u.mcap"
    _record(path, cfg, 1.5)
    _, updates, _ = _scene(path)
    last = updates[-1]
    prox = [_length(c) for c in _entity(last, "proximal_links").cylinders]
    dist = [_length(c) for c in _entity(last, "distal_links").cylinders]
    assert prox == pytest.approx(list(u.proximal_lengths_m), abs=1e-6)
    assert dist == pytest.approx(list(u.distal_lengths_m), abs=1e-6)


def test_nspu_legs_are_drawn_at_the_measured_leg_lengths(tmp_path):
    cfg = _config("nspu")
    path = tmp_path / "n.mcap"
    _record(path, cfg, 1.5)
    _, updates, cycles = _logged(path)
    by_time = {c.log_time_ns: c.message for c in cycles}
    compared = 0
    for u in updates[1:]:
        legs = [_length(c) for c in _entity(u.message, "legs").cylinders]
        measured = [d.position for d in by_time[u.log_time_ns].inputs.drives]
        assert all(math.isfinite(x) for x in legs) and len(legs) == 3
        # the pose integrated from the start pose through the drawn leg lengths meets them
        assert legs == pytest.approx(measured, abs=1e-3)
        compared += 1
    assert compared > 20


def test_the_contour_session_draws_the_workpiece_where_the_simulator_has_it(tmp_path):
    cfg = _config("cheope", {"task.kind": "contour"})
    path = tmp_path / "k.mcap"
    _record(path, cfg, 0.5)
    _, updates, _ = _scene(path)
    disk = _entity(updates[0], "workpiece/disk")
    d = cfg.sim.workpiece
    (c,) = disk.cylinders
    assert (c.pose.position.x, c.pose.position.y, c.pose.position.z) == pytest.approx(
        (d.centre_m[0], d.centre_m[1], d.height_m)
    )
    assert c.size.x == pytest.approx(2 * d.radius_m)
    assert "workpiece/expected_contour" in {e.id for e in updates[0].entities}


def test_the_reference_trail_is_redrawn_twice_a_second_and_never_cleared_between(tmp_path):
    """The trail is the one growing part (600 points): redrawn with the other moving parts at
    20 Hz it made most of /scene's bytes. Between its redraws the updates leave it out, so
    Foxglove keeps the last line instead of clearing it."""
    from logs.robot_drawing import DEFAULT_TRAIL_INTERVAL_S, TRAIL_ENTITY

    cfg = _config("cheope")
    path = tmp_path / "trail.mcap"
    _record(path, cfg, 3.0)
    _, updates, _ = _logged(path)
    moving = updates[1:]
    with_trail = [u for u in moving if any(e.id == TRAIL_ENTITY for e in u.message.entities)]
    # never an empty trail entity: that would clear the line in the viewer
    assert all(len(_entity(u.message, TRAIL_ENTITY).lines) == 1 for u in with_trail)
    span_s = (moving[-1].log_time_ns - moving[0].log_time_ns) / 1e9
    assert len(with_trail) <= span_s / DEFAULT_TRAIL_INTERVAL_S + 2, (len(with_trail), span_s)
    assert len(with_trail) >= span_s / DEFAULT_TRAIL_INTERVAL_S - 2, (len(with_trail), span_s)
    assert len(moving) > 4 * len(with_trail)  # the rest of the robot keeps the scene rate
    lengths = [len(_entity(u.message, TRAIL_ENTITY).lines[0].points) for u in with_trail]
    assert lengths == sorted(lengths) and lengths[-1] > lengths[0]  # the line grows between redraws
