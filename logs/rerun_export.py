"""``cheope replay FILE --rerun [OUT.rrd]``: a session as a Rerun recording with a ready layout.

One streaming pass over the MCAP file gathers the per-cycle signals into arrays, which are
then sent with ``send_columns`` (one Arrow chunk per entity, not one log call per cycle), on
two timelines: ``time`` (the cycle's nominal time ``t`` [s], a duration) and ``cycle``.

Entities:
- ``/world``: the robot in the base frame {0} (Z up, metres): ``axes`` (the prismatic axes
  over the stroke, static), ``sliders`` (q_j n_j), ``rods`` (slider to platform joint
  s + a_j), ``platform`` (the triangle of joints), ``tcp`` (measured, direct kinematics),
  ``tcp_trail`` (the whole measured TCP path, static), ``reference_path`` (the path points
  the setpoints aimed at, static), ``force`` (the sensor's force as an arrow at the TCP,
  ``FORCE_ARROW_M_PER_N`` metres per newton), ``workpiece`` (the simulated disk's rim and
  the expected contour, when the task is the contour task);
- ``/plots``: ``actuators/target_j`` and ``actuators/position_j`` [m], ``force/fx|fy|fz`` [N],
  ``normal_force_error`` [N] (the contour task's F_d - F_n, from the recorded task values),
  ``loop/period_us`` (between consecutive cycles on the controller's clock),
  ``loop/wake_error_us``, ``loop/step_us`` (one unit on the loop's plot: µs);
- ``/events``: the step's events as log lines.

The blueprint puts the 3D view and the event log on the left and the time series on the
right. The geometry comes from the recorded configuration (``cheope.config`` metadata).

The same conversion serves the Rerun viewer as an external importer (logs/rerun_importer.py,
``rerun-importer-cheope``): ``rerun FILE.mcap`` shows the robot beside the viewer's own MCAP
channels.
"""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from logs import messages as m
from logs.reader import LogFileError, ReadReport, iter_decoded, read_info, recorded_config_table, same_file
from logs.robot_drawing import FORCE_ARROW_M_PER_N
from logs.scene_sampler import SceneFrame, SceneSampler

SCENE_RATE_HZ = 30.0  # the robot's moving parts in a replay: smooth when scrubbing, 1/13 of 400 Hz
APP_ID = "cheope_replay"


@dataclass
class _Series:
    t: list[float] = field(default_factory=list)
    cycle: list[int] = field(default_factory=list)
    log_ns: list[int] = field(default_factory=list)
    targets: list[tuple[float, ...]] = field(default_factory=list)
    positions: list[tuple[float, ...]] = field(default_factory=list)
    tcp: list[tuple[float, float, float]] = field(default_factory=list)  # NaN when unknown
    ref: list[tuple[float, float, float]] = field(default_factory=list)
    force: list[tuple[float, float, float]] = field(default_factory=list)
    force_error: list[float] = field(default_factory=list)
    wake_us: list[float] = field(default_factory=list)
    step_us: list[float] = field(default_factory=list)
    events: list[tuple[float, int, int, str]] = field(default_factory=list)  # t, cycle, severity, text
    scene: list[SceneFrame] = field(default_factory=list)  # the robot's moving parts, decimated


@dataclass(frozen=True)
class ExportResult:
    output: Path | None  # the .rrd written, or None when streamed to a spawned viewer
    spawned: bool
    cycles: int
    entities: tuple[str, ...]
    report: ReadReport
    note: str = ""  # why no viewer was spawned, when one was asked for
    scene_left_out: str = ""  # why the robot's 3D scene is not drawn, when its record is unusable


_NAN3 = (math.nan, math.nan, math.nan)


def _gather(
    path: Path,
    report: ReadReport,
    progress: Callable[[int], None] | None,
    sampler: SceneSampler | None = None,
) -> _Series:
    s = _Series()
    k = 0
    for d in iter_decoded(path, (m.TOPIC_CYCLE, m.TOPIC_EVENTS), report):
        if d.topic == m.TOPIC_EVENTS:
            e = d.message
            s.events.append((e.t_s, e.cycle, int(e.severity), f"[{e.kind}] {e.message}"))
            continue
        c = d.message
        s.t.append(c.t_s)
        s.cycle.append(c.cycle)
        s.log_ns.append(d.log_time_ns)
        s.targets.append(tuple(c.outputs.targets))
        s.positions.append(tuple(x.position for x in c.inputs.drives))
        st = c.state
        s.tcp.append(tuple(st.tcp_measured_m) if len(st.tcp_measured_m) == 3 else _NAN3)
        s.ref.append(tuple(st.tcp_reference_m) if len(st.tcp_reference_m) == 3 else _NAN3)
        s.force.append(tuple(c.inputs.sensor.force_n) if c.inputs.HasField("sensor") else _NAN3)
        s.force_error.append(st.task_values.get("force_error_n", math.nan))
        s.wake_us.append(c.timing.wake_error_s * 1e6)
        s.step_us.append(c.timing.step_s * 1e6)
        if sampler is not None:
            frame = sampler.sample_parsed(c)
            if frame is not None:
                s.scene.append(frame)
        k += 1
        if progress is not None and k % 2000 == 0:
            progress(report.end_offset)
    return s


def _circle(cx: float, cy: float, z: float, r: float, n: int = 180) -> np.ndarray:
    th = np.linspace(0.0, 2.0 * np.pi, n + 1)
    return np.column_stack([cx + r * np.cos(th), cy + r * np.sin(th), np.full_like(th, z)])


def blueprint(has_force: bool, has_force_error: bool) -> Any:
    import rerun.blueprint as rrb

    plots = [rrb.TimeSeriesView(origin="/plots/actuators", name="actuators: target vs position [m]")]
    if has_force:
        plots.append(rrb.TimeSeriesView(origin="/plots/force", name="force [N]"))
    if has_force_error:
        plots.append(rrb.TimeSeriesView(origin="/plots/normal_force_error", name="normal-force error [N]"))
    plots.append(rrb.TimeSeriesView(origin="/plots/loop", name="loop timing [µs]"))
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.Spatial3DView(origin="/world", name="robot"),
                rrb.TextLogView(origin="/events", name="events"),
                row_shares=[3, 1],
            ),
            rrb.Vertical(*plots),
            column_shares=[3, 2],
        ),
        collapse_panels=True,
    )


def can_spawn_viewer() -> tuple[bool, str]:
    """Whether a viewer window can open here; the reason when not."""
    if sys.platform.startswith("linux") and not (
        os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
    ):
        return False, "no display (neither DISPLAY nor WAYLAND_DISPLAY is set)"
    return True, ""


@dataclass(frozen=True)
class StdoutStream:
    """Where an external importer sends the conversion: standard output, into the viewer's recording."""

    application_id: str = APP_ID
    recording_id: str | None = None  # the viewer's, so that its own MCAP channels join the robot


def export(
    path: str | Path,
    out: str | Path | None = None,
    spawn: bool = False,
    progress: Callable[[int], None] | None = None,
    stdout: StdoutStream | None = None,
) -> ExportResult:
    """Convert ``path`` to Rerun: into ``out`` (.rrd), to a spawned viewer when ``spawn``, or to
    standard output as ``stdout`` says (the viewer's importer).

    With ``spawn`` and no display (or a viewer that fails to start), the recording goes to
    ``out`` or, without one, to ``FILE.rrd`` beside the MCAP file; ``ExportResult.note`` says why.
    """
    import rerun as rr

    path = Path(path)
    if out is not None and same_file(path, Path(out)):
        raise LogFileError(f"--rerun {out}: is the recording itself")
    report = ReadReport(path)
    cfg, scene_left_out = _config(leading_metadata(path))
    sampler = None if cfg is None else SceneSampler.for_config(cfg, SCENE_RATE_HZ)
    s = _gather(path, report, progress, sampler)
    if m.META_CONFIG not in report.metadata:
        report.metadata.update(read_info(path).metadata)
    if not s.t:
        raise LogFileError(f"{path} holds no readable control cycles ({report.status()})")
    force = np.array(s.force, dtype=float)
    has_force = bool(np.isfinite(force).any())
    force_err = np.array(s.force_error, dtype=float)
    has_force_error = bool(np.isfinite(force_err).any())
    bp = blueprint(has_force, has_force_error)

    if stdout is not None:
        rec = rr.RecordingStream(stdout.application_id, recording_id=stdout.recording_id or path.stem)
        rec.stdout(default_blueprint=bp)
        entities = _send(rec, s, sampler, force, force_err, has_force, has_force_error)
        rec.flush()
        return ExportResult(None, False, len(s.t), tuple(entities), report, scene_left_out=scene_left_out)
    rec = rr.RecordingStream(APP_ID, recording_id=f"{path.stem}")
    spawned, note, output = False, "", None
    if spawn:
        ok, note = can_spawn_viewer()
        if ok:
            try:
                rec.spawn(default_blueprint=bp)
                spawned = True
            except Exception as err:  # any failure to start the viewer: fall back to a file
                note = f"the viewer did not start: {err}"
    if not spawned:
        output = Path(out) if out is not None else path.with_suffix(".rrd")
        rec.save(output, default_blueprint=bp)
    entities = _send(rec, s, sampler, force, force_err, has_force, has_force_error)
    rec.flush()
    rec.disconnect()
    return ExportResult(output, spawned, len(s.t), tuple(entities), report, note, scene_left_out)


def leading_metadata(path: Path) -> ReadReport:
    """The metadata the recorder writes before any message (the configuration), without reading on."""
    from logs.reader import iter_messages

    report = ReadReport(path)
    for _ in iter_messages(path, report):
        break
    return report


# A cheope.config record that holds no configuration table, or one this version does not load (an
# older file's), leaves the robot's 3D scene out, and the conversion says so in one line naming the
# file and the record (the callers put it on stderr). It does not refuse: the plots, the TCP trail
# and the events come from the /cycle and /events messages alone, and a recording whose record is
# damaged is one to look at. Before, the scene was left out without a word (an outside tester's
# finding). A file without the record says nothing: it has no robot to draw.
def _config(report: ReadReport) -> tuple[Any, str]:
    """The recorded configuration, or None and why the scene is left out ("" without a record)."""
    from controller.config import ConfigError, recorded_config_from_dict

    try:
        table = recorded_config_table(report)  # a LogFileError names the file and the record
        return (None, "") if table is None else (recorded_config_from_dict(table), "")
    except LogFileError as err:
        return None, f"{err}: written without the robot's 3D scene"
    except ConfigError as err:
        return None, (
            f"{report.path}: metadata record {m.META_CONFIG}: {err}: written without the robot's 3D scene"
        )


def _send(
    rec: Any,
    s: _Series,
    sampler: SceneSampler | None,
    force: np.ndarray,
    force_err: np.ndarray,
    has_force: bool,
    has_force_error: bool,
) -> list[str]:
    import rerun as rr

    t = np.asarray(s.t, dtype=float)
    cyc = np.asarray(s.cycle, dtype=np.int64)
    entities: list[str] = []

    def idx(mask: np.ndarray | None = None) -> list[Any]:
        tt, cc = (t, cyc) if mask is None else (t[mask], cyc[mask])
        return [rr.TimeColumn("time", duration=tt), rr.TimeColumn("cycle", sequence=cc)]

    def scalars(entity: str, values: np.ndarray) -> None:
        mask = np.isfinite(values)
        if mask.any():
            rec.send_columns(entity, indexes=idx(mask), columns=rr.Scalars.columns(scalars=values[mask]))
            entities.append(entity)

    targets = np.array(s.targets, dtype=float)
    positions = np.array(s.positions, dtype=float)
    for j in range(targets.shape[1]):
        scalars(f"/plots/actuators/target_{j + 1}", targets[:, j])
        scalars(f"/plots/actuators/position_{j + 1}", positions[:, j])
    if has_force:
        for j, name in enumerate(("fx", "fy", "fz")):
            scalars(f"/plots/force/{name}", force[:, j])
    if has_force_error:
        scalars("/plots/normal_force_error", force_err)
    log_ns = np.asarray(s.log_ns, dtype=np.int64)
    if len(log_ns) > 1:
        period = np.concatenate([[math.nan], np.diff(log_ns) * 1e-3])
        scalars("/plots/loop/period_us", period)
    scalars("/plots/loop/wake_error_us", np.asarray(s.wake_us))
    scalars("/plots/loop/step_us", np.asarray(s.step_us))

    tcp = np.array(s.tcp, dtype=float)
    known = np.isfinite(tcp).all(axis=1)
    if known.any():
        rec.send_columns(
            "/world/tcp",
            indexes=idx(known),
            columns=rr.Points3D.columns(positions=tcp[known], radii=np.full(int(known.sum()), 0.004)),
        )
        rec.log(
            "/world/tcp_trail",
            rr.LineStrips3D([tcp[known]], radii=0.0008, colors=[[80, 160, 255]]),
            static=True,
        )
        entities += ["/world/tcp", "/world/tcp_trail"]
    ref = np.array(s.ref, dtype=float)
    on_path = np.isfinite(ref).all(axis=1)
    if on_path.any():
        rec.log(
            "/world/reference_path",
            rr.Points3D(
                ref[on_path][:: max(1, int(on_path.sum()) // 2000)], radii=0.0006, colors=[[255, 200, 0]]
            ),
            static=True,
        )
        entities.append("/world/reference_path")
    if has_force and known.any():
        ok = known & np.isfinite(force).all(axis=1)
        rec.send_columns(
            "/world/force",
            indexes=idx(ok),
            columns=rr.Arrows3D.columns(origins=tcp[ok], vectors=force[ok] * FORCE_ARROW_M_PER_N),
        )
        entities.append("/world/force")
    if sampler is not None:
        entities += _send_scene(rec, sampler, s.scene)
    if s.events:
        colors = {0: [200, 200, 200], 1: [255, 200, 0], 2: [255, 80, 80]}
        levels = {0: "INFO", 1: "WARN", 2: "ERROR"}
        for te, ce, sev, text in s.events:
            rec.set_time("time", duration=te)
            rec.set_time("cycle", sequence=ce)
            rec.log("/events", rr.TextLog(text, level=levels.get(sev, "INFO"), color=colors.get(sev)))
        rec.reset_time()
        entities.append("/events")
    return entities


# Drawn at the full cycle rate by _send (from the recorded arrays), not by the decimated drawing.
_FULL_RATE_ENTITIES = ("force", "reference_path")


def _send_scene(rec: Any, sampler: SceneSampler, frames: list[SceneFrame]) -> list[str]:
    """The robot as solid primitives (logs/robot_drawing.py): the fixed parts static, the moving per frame."""
    import rerun as rr

    from logs.rerun_scene import RerunScene

    scene = RerunScene(rec)
    drawn = set(scene.log_fixed(sampler.drawing.fixed()))
    for f in frames:
        rec.set_time("time", duration=f.t_s)
        rec.set_time("cycle", sequence=f.cycle)
        drawn.update(scene.log_moving([p for p in f.moving if p.entity not in _FULL_RATE_ENTITIES]))
    rec.reset_time()
    if not drawn:
        rec.log("/world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    return sorted(drawn)
