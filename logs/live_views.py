"""Live views of a running session: a Rerun stream and a Foxglove WebSocket server, fed by the writer process.

Why in the recorder's writer process: every cycle already reaches it through the pipe
(logs/recorder.py), off the loop thread and in another process with its own GIL, so a live view
costs the loop nothing more than the recording does. The writer hands this module what it
draws for ``/scene`` anyway (logs/scene_sampler.py, ``recording.scene_rate_hz``, 20 Hz): the
robot's moving parts and the cycle they come from. Nothing here may stop the recording: a
viewer that cannot start is reported once on stderr and left out.

- Rerun (``recording.live_rerun``, ``cheope run|demo --rerun [WHERE]``): ``spawn`` starts a native
  viewer (``RecordingStream.spawn``), ``serve`` hosts a gRPC server and the web viewer for a
  browser (``serve_grpc`` + ``serve_web_viewer``), a ``rerun+http://HOST:PORT/proxy`` URL connects to
  a running viewer or server (``connect_grpc``). ``serve`` listens on all interfaces: the SDK's
  ``serve_grpc`` and ``serve_web_viewer`` take no bind address (rerun-sdk 0.41). The same entities and blueprint as
  ``cheope replay --rerun``: the robot as solids under ``/world``, the plots under ``/plots``.
- Foxglove (``recording.live_foxglove = "HOST:PORT"``, ``--foxglove [HOST:PORT]``, default
  ``127.0.0.1:8765``): foxglove-sdk's WebSocket server with the recording's own channels and
  schemas: ``/scene``, ``/cycle``, ``/tcp``, ``/tcp_reference`` and ``/joint_states`` (at the scene
  rate), ``/log``, ``/events``, and ``/can`` (the frames since its last message, at most
  ``recording.live_can_rate_hz``; 0 leaves it out); open it in Foxglove (or Lichtblick: both
  WebSocket subprotocol names are accepted, logs/foxglove_shim.py) with "Open connection" ->
  ``ws://HOST:PORT`` and the shipped layout (logs/foxglove_layout.json), which names only topics
  both the live server and a recording have. The server offers the service ``stop`` (the
  protocol's services, JSON: no request, the reply ``{"accepted", "message"}``): a controlled stop,
  the one remote command the Zenoh gate always accepts (controller/monitoring/command_gate.py); the
  writer hands it to the controller (``{"command": "stop"}`` on its standard output, logs/recorder.py).
"""

from __future__ import annotations

import ipaddress
import math
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from logs.messages import tcp_pose
from logs.robot_drawing import Primitive

if TYPE_CHECKING:
    from controller.config import Config
    from logs.scene_sampler import SceneFrame

DEFAULT_FOXGLOVE_PORT = 8765
PLOT_BATCH_FRAMES = 5  # Rerun's plots go out in batches of this many frames: 0.25 s behind at 20 Hz


# A Rerun viewer that accepts the connection and never reads held the writer's end until the
# recorder gave up on it (30 s): the run ended "DONE with its recording lost", exit 3, of a
# complete file (an outside tester's). Its last data get this long.
LIVE_FLUSH_TIMEOUT_S = 5.0


class LiveViewError(ValueError):
    """A live-view setting that cannot be used (named in the message)."""


def parse_host_port(spec: str, default_port: int = DEFAULT_FOXGLOVE_PORT) -> tuple[str, int]:
    """``HOST:PORT``, ``HOST`` or ``:PORT`` -> (host, port); the host defaults to loopback."""
    host, _, port = spec.rpartition(":") if ":" in spec else (spec, "", "")
    host = host.strip("[]") or "127.0.0.1"
    try:
        p = int(port) if port else default_port
    except ValueError:
        raise LiveViewError(
            f"recording.live_foxglove = {spec!r}: the port {port!r} is not a number"
        ) from None
    if not 0 <= p <= 65535:
        raise LiveViewError(f"recording.live_foxglove = {spec!r}: the port must be 0..65535")
    return host, p


def _warn(what: str, err: BaseException) -> None:
    print(f"live view left out: {what}: {err}", file=sys.stderr, flush=True)


class RerunLive:
    def __init__(self, where: str, cfg: Config, has_force_error: bool) -> None:
        import rerun as rr

        from logs.rerun_export import blueprint
        from logs.rerun_scene import RerunScene

        self.rec = rr.RecordingStream("cheope_live")
        bp = blueprint(has_force=True, has_force_error=has_force_error)
        self.where = where
        if where == "spawn":
            from logs.rerun_export import can_spawn_viewer

            ok, why = can_spawn_viewer()
            if not ok:
                raise LiveViewError(
                    f"cannot spawn a Rerun viewer: {why}; --rerun serve hosts a web viewer instead"
                )
            # the viewer executable is installed beside this interpreter (the venv's bin), which
            # need not be on PATH when cheope was started by its full path
            os.environ["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"
            self.rec.spawn(default_blueprint=bp)
        elif where == "serve":
            url = self.rec.serve_grpc(default_blueprint=bp)
            rr.serve_web_viewer(open_browser=False, connect_to=url)
            print(
                f"live Rerun: gRPC {url}; web viewer on http://127.0.0.1:9090 (both listen on every "
                "interface: rerun-sdk takes no bind address)",
                file=sys.stderr,
                flush=True,
            )
        elif where.startswith("rerun+http"):
            self.rec.connect_grpc(where, default_blueprint=bp)
        else:
            raise LiveViewError(
                f"recording.live_rerun = {where!r}: use spawn, serve or a rerun+http://HOST:PORT/proxy URL"
            )
        self.scene = RerunScene(self.rec)
        self.rr = rr
        self._plot_rows: list[tuple[float, int, dict[str, float]]] = []

    def fixed(self, primitives: list[Primitive]) -> None:
        self.scene.log_fixed(primitives)

    def frame(self, f: SceneFrame, cycle: Any) -> None:
        rec = self.rec
        rec.set_time("time", duration=f.t_s)
        rec.set_time("cycle", sequence=f.cycle)
        self.scene.log_moving(f.moving, f.kept)
        values: dict[str, float] = {}
        for j, d in enumerate(cycle.inputs.drives):
            values[f"/plots/actuators/position_{j + 1}"] = d.position
        for j, x in enumerate(cycle.outputs.targets):
            values[f"/plots/actuators/target_{j + 1}"] = x
        if cycle.inputs.HasField("sensor"):
            for name, v in zip(("fx", "fy", "fz"), cycle.inputs.sensor.force_n, strict=True):
                values[f"/plots/force/{name}"] = v
        fe = cycle.state.task_values.get("force_error_n")
        if fe is not None and math.isfinite(fe):
            values["/plots/normal_force_error"] = fe
        values["/plots/loop/step_us"] = cycle.timing.step_s * 1e6
        values["/plots/loop/wake_error_us"] = cycle.timing.wake_error_s * 1e6
        self._plot_rows.append((f.t_s, f.cycle, values))
        if len(self._plot_rows) >= PLOT_BATCH_FRAMES:
            self._send_plots()

    def _send_plots(self) -> None:
        """The buffered plot values, one ``send_columns`` per series: a log call per value per frame cost
        most of the live stream's time (tests/tools/bench_live_views.py)."""
        rr = self.rr
        series: dict[str, tuple[list[float], list[int], list[float]]] = {}
        for t, c, values in self._plot_rows:
            for path, v in values.items():
                ts, cs, vs = series.setdefault(path, ([], [], []))
                ts.append(t)
                cs.append(c)
                vs.append(v)
        for path, (ts, cs, vs) in series.items():
            self.rec.send_columns(
                path,
                indexes=[rr.TimeColumn("time", duration=ts), rr.TimeColumn("cycle", sequence=cs)],
                columns=rr.Scalars.columns(scalars=vs),
            )
        self._plot_rows.clear()

    def event(self, t_s: float, cycle: int, severity: int, text: str) -> None:
        self.rec.set_time("time", duration=t_s)
        self.rec.set_time("cycle", sequence=cycle)
        self.rec.log("/events", self.rr.TextLog(text, level={0: "INFO", 1: "WARN"}.get(severity, "ERROR")))

    def close(self) -> None:
        """The last plots sent; raises when the viewer does not take them within
        ``LIVE_FLUSH_TIMEOUT_S`` (then the connection is left: rerun's disconnect and its exit
        handler would wait for that viewer as long as it hangs)."""
        self._send_plots()
        self.rec.flush(timeout_sec=LIVE_FLUSH_TIMEOUT_S)
        self.rec.disconnect()


class FoxgloveLive:
    """foxglove-sdk's WebSocket server behind the subprotocol shim; messages are the recording's own Protobuf bytes.

    Clients offering either ``foxglove.sdk.v1`` or ``foxglove.websocket.v1`` connect (logs/foxglove_shim.py).
    The fixed parts of the robot go out once, as in the recording, and again whenever a client
    subscribes to ``/scene``: a client that joins late gets the base, the guides and the workpiece
    at once (the SDK keeps no history; the SDK's one sink is every client, so the others get the
    same entities again, which replace themselves).
    """

    TOPICS = ("/scene", "/cycle", "/tcp", "/tcp_reference", "/log", "/events", "/can", "/joint_states")

    def __init__(self, spec: str, on_stop: Callable[[], tuple[bool, str]] | None = None) -> None:
        import foxglove
        from foxglove.websocket import Capability, ChannelView, Client, ServerListener
        from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
        from foxglove_schemas_protobuf.JointStates_pb2 import JointStates
        from foxglove_schemas_protobuf.Log_pb2 import Log
        from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
        from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
        from mcap_protobuf.schema import build_file_descriptor_set

        from controller.messages import cheope_pb2 as pb
        from logs.foxglove_shim import SubprotocolShim

        host, port = parse_host_port(spec)
        if not _is_loopback_host(host):
            # no authentication on the WebSocket: whoever reaches the port sees the live state and
            # may call the stop service (an outside tester's finding: accepted without a word)
            print(
                f"live Foxglove: listening on {host}, beyond this machine: anyone who reaches port "
                f"{port} sees the live state and can call its stop service",
                file=sys.stderr,
                flush=True,
            )
        self.context = foxglove.Context()
        self.channels: dict[str, Any] = {}
        for topic, cls in zip(
            self.TOPICS,
            (SceneUpdate, pb.Cycle, FrameTransform, PoseInFrame, Log, pb.Event, pb.CanFrames, JointStates),
            strict=True,
        ):
            schema = foxglove.Schema(
                name=cls.DESCRIPTOR.full_name,
                encoding="protobuf",
                data=build_file_descriptor_set(cls).SerializeToString(),
            )
            self.channels[topic] = foxglove.Channel(
                topic, schema=schema, message_encoding="protobuf", context=self.context
            )
        self._fixed: tuple[bytes, int] | None = None  # the fixed scene and its log time, once drawn
        live = self

        class Listener(ServerListener):
            def on_subscribe(self, client: Client, channel: ChannelView) -> None:  # on the SDK's thread
                fixed = live._fixed
                if channel.topic == "/scene" and fixed is not None:
                    live.channels["/scene"].log(fixed[0], log_time=fixed[1])

        services = [] if on_stop is None else [_stop_service(on_stop)]
        self.server = foxglove.start_server(
            name="cheope",
            host="127.0.0.1",
            port=0,
            context=self.context,
            server_listener=Listener(),
            capabilities=[Capability.Services] if services else None,
            supported_encodings=["json"] if services else None,
            services=services or None,
        )
        try:
            self.shim = SubprotocolShim(host, port, self.server.port)
        except OSError:
            self.server.stop()
            raise
        self.port = self.shim.port
        print(f"live Foxglove: ws://{host}:{self.port}", file=sys.stderr, flush=True)

    def fixed(self, scene_pb: bytes, unix_ns: int) -> None:
        self._fixed = (scene_pb, unix_ns)
        self.log("/scene", scene_pb, unix_ns)

    def log(self, topic: str, data: bytes, unix_ns: int) -> None:
        self.channels[topic].log(data, log_time=unix_ns)

    def close(self) -> None:
        self.shim.close()
        self.server.stop()


STOP_REPLY_SCHEMA = {
    "type": "object",
    "properties": {"accepted": {"type": "boolean"}, "message": {"type": "string"}},
}


def _stop_service(on_stop: Callable[[], tuple[bool, str]]) -> Any:
    """The Foxglove protocol's service ``stop``: no request, a JSON reply (the SDK's thread calls it)."""
    import json

    import foxglove

    def handle(_request: Any) -> bytes:
        accepted, message = on_stop()
        return json.dumps({"accepted": accepted, "message": message}).encode()

    reply = foxglove.MessageSchema(
        encoding="json",
        schema=foxglove.Schema(
            name="cheope.StopReply", encoding="jsonschema", data=json.dumps(STOP_REPLY_SCHEMA).encode()
        ),
    )
    return foxglove.Service(
        "stop", schema=foxglove.ServiceSchema("cheope.Stop", response=reply), handler=handle
    )


class LiveViews:
    """The configured live views; each call reaches every view that started."""

    def __init__(self, cfg: Config, on_stop: Callable[[], tuple[bool, str]] | None = None) -> None:
        from controller.tasks.registry import task_entry

        r = cfg.recording
        self.rerun: RerunLive | None = None
        self.foxglove: FoxgloveLive | None = None
        if r.live_rerun:
            try:
                # a task that controls a force reports its error (task_values["force_error_n"])
                self.rerun = RerunLive(r.live_rerun, cfg, task_entry(cfg.task.kind).uses_force_sensor)
            except Exception as err:  # a viewer that cannot start never stops the recording
                _warn(f"Rerun ({r.live_rerun})", err)
        if r.live_foxglove:
            try:
                self.foxglove = FoxgloveLive(r.live_foxglove, on_stop)
            except Exception as err:  # as above
                _warn(f"Foxglove ({r.live_foxglove})", err)

    @property
    def active(self) -> bool:
        return self.rerun is not None or self.foxglove is not None

    def fixed(self, primitives: list[Primitive], scene_pb: bytes, unix_ns: int) -> None:
        if self.rerun is not None:
            self.rerun.fixed(primitives)
        if self.foxglove is not None:
            self.foxglove.fixed(scene_pb, unix_ns)

    def frame(
        self, f: SceneFrame, cycle: Any, cycle_pb: bytes, scene_pb: bytes, tcp_pb: bytes | None, unix_ns: int
    ) -> None:
        if self.rerun is not None:
            self.rerun.frame(f, cycle)
        if self.foxglove is not None:
            self.foxglove.log("/scene", scene_pb, unix_ns)
            self.foxglove.log("/cycle", cycle_pb, unix_ns)
            if tcp_pb is not None:
                self.foxglove.log("/tcp", tcp_pb, unix_ns)
            reference = cycle.state.tcp_reference_m
            if len(reference) == 3:  # the recording's /tcp_reference, at the scene rate
                self.foxglove.log(
                    "/tcp_reference",
                    tcp_pose(unix_ns, (reference[0], reference[1], reference[2])).SerializeToString(),
                    unix_ns,
                )

    def event(
        self, t_s: float, cycle: int, severity: int, text: str, log_pb: bytes, event_pb: bytes, unix_ns: int
    ) -> None:
        if self.rerun is not None:
            self.rerun.event(t_s, cycle, severity, text)
        if self.foxglove is not None:
            self.foxglove.log("/log", log_pb, unix_ns)
            self.foxglove.log("/events", event_pb, unix_ns)

    def can(self, can_pb: bytes, unix_ns: int) -> None:
        """``/can`` live: one message of the frames since the last (the writer decides when, by rate)."""
        if self.foxglove is not None:
            self.foxglove.log("/can", can_pb, unix_ns)

    def joint_states(self, joints_pb: bytes, unix_ns: int) -> None:
        if self.foxglove is not None:
            self.foxglove.log("/joint_states", joints_pb, unix_ns)

    def close(self) -> bool:
        """Each view closed; False when one failed (a viewer that takes no data: the process had
        better end without the views' exit handlers, logs/session_writer.py)."""
        clean = True
        for view in (self.rerun, self.foxglove):
            if view is not None:
                try:
                    view.close()
                except Exception as err:  # closing a viewer never fails the recording
                    _warn("closing", err)
                    clean = False
        return clean


def _is_loopback_host(host: str) -> bool:
    """``localhost`` or a loopback address; an empty host or a name is taken as beyond this machine."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False
