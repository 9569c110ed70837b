"""Live views during a run: a Rerun gRPC server and a Foxglove WebSocket client receive the session as it runs.

The controller is the production loop shell, control law and recorder (whose writer process feeds
the live views) on the in-process simulated devices, paced in real time on this process's
thread; everything stays on loopback. The receivers: ``rerun --save`` (Rerun's own gRPC server,
writing what it receives to an .rrd that Rerun's reader reads back) and a WebSocket client
speaking the Foxglove protocol (``websockets``).
"""

from __future__ import annotations

import contextlib
import json
import socket
import struct
import subprocess
import threading
import time
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from waiting import GENEROUS_S, ProcessLines, wait_for_exit, wait_until

from controller.assembly import build_law
from controller.config import Config, load_config
from controller.monitoring.zenoh_session import free_loopback_port
from controller.shell.loop import CycleLoop
from drivers.pacing import DeadlineSleeper
from logs.recorder import SessionRecorder, session_metadata
from sim_backend.loopback import LoopbackExchange


def _rerun_binary() -> str:
    """The Rerun executable itself: ``.venv/bin/rerun`` is a Python wrapper that starts it as a child,
    which would outlive a terminated wrapper."""
    import rerun_cli

    return str(Path(rerun_cli.__file__).parent / "rerun")


@contextmanager
def _running_controller(cfg: Config, path: Path) -> Iterator[threading.Thread]:
    """The loop on the loopback devices in real time, recorded to ``path``; its thread while it runs."""
    law = build_law(cfg)
    exchange = LoopbackExchange(cfg, time.monotonic)
    stop = threading.Event()
    errors: list[BaseException] = []
    ended: list[str] = []
    with SessionRecorder(path, session_metadata(cfg)) as rec:
        loop = CycleLoop(
            law,
            exchange,
            cfg.period_s,
            cfg.loop.collect_fraction,
            DeadlineSleeper(0.0),
            time.monotonic,
            observers=(rec,),
            stop_event=stop,
        )

        def run() -> None:
            try:
                final, _ = loop.run(law.initial_state(), GENEROUS_S)
                ended.append(f"{final.mode.name} {final.fault_reason}")
            except BaseException as err:  # reported by the test
                errors.append(err)

        thread = threading.Thread(target=run, name="test-loop")
        thread.ended = ended  # type: ignore[attr-defined]
        thread.recorder = rec  # type: ignore[attr-defined]
        thread.start()
        try:
            yield thread
        finally:
            stop.set()
            thread.join(GENEROUS_S)
    assert not thread.is_alive() and not errors, errors


def _config(tmp_path: Path, **recording: str) -> Config:
    # The devices run in this process beside the test's own reading (Rerun's reader holds the GIL for
    # tens of ms): their SYNC watchdog and the late-cycle reaction would fault a run that only stalled.
    overrides: dict[str, object] = {
        "recording.directory": str(tmp_path),
        "task.path.laps": 20.0,
        "safety.on_late_cycles": "warn",
        "loop.max_missing_s": 0.025,
        "actuators.sync_watchdog_s": 5.0,
    }
    overrides.update({f"recording.{k}": v for k, v in recording.items()})
    return load_config(overrides=overrides)


def _rrd_entities(path: Path) -> set[str]:
    from rerun.chunk import RrdReader

    if not path.exists() or path.stat().st_size == 0:
        return set()
    try:
        with warnings.catch_warnings():  # the server's file has no footer until it ends: read by a scan
            warnings.simplefilter("ignore")
            return set(RrdReader(path).stream().collect().schema().entity_paths())
    except Exception:  # a file the server is still writing: read it again later
        return set()


def test_a_rerun_grpc_server_receives_the_robot_and_the_plots_during_the_run(tmp_path):
    port = free_loopback_port()
    rrd = tmp_path / "live.rrd"
    server = subprocess.Popen(
        [_rerun_binary(), "--bind", "127.0.0.1", "--port", str(port), "--save", str(rrd)],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
    )
    try:
        ProcessLines(server).next_matching(
            lambda line: "Listening for gRPC" in line, "the Rerun server listening"
        )
        cfg = _config(tmp_path, live_rerun=f"rerun+http://127.0.0.1:{port}/proxy")
        with _running_controller(cfg, tmp_path / "s.mcap") as loop_thread:
            wanted = {
                "/world/rods/capsules",
                "/world/sliders/boxes",
                "/world/guides/capsules",
                "/plots/actuators/position_1",
            }
            wait_until(lambda: wanted <= _rrd_entities(rrd), "the robot and the plots at the Rerun server")
            # received while the controller runs (20 laps: about 100 s)
            assert loop_thread.is_alive(), loop_thread.ended  # type: ignore[attr-defined]
    finally:
        server.terminate()
        wait_for_exit(server.pid, "the Rerun server")
        server.wait()


@contextmanager
def _silent_server() -> Iterator[int]:
    """A TCP server on loopback that accepts and never reads (a hung viewer); its port."""
    listener = socket.socket()
    listener.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    listener.bind(("127.0.0.1", 0))
    listener.listen(8)
    listener.settimeout(0.1)  # the thread looks for the end this often (a closed socket wakes no accept)
    held: list[socket.socket] = []
    done = threading.Event()

    def accept() -> None:
        while not done.is_set():
            with contextlib.suppress(TimeoutError):
                held.append(listener.accept()[0])

    thread = threading.Thread(target=accept, name="silent-server", daemon=True)
    thread.start()
    try:
        yield listener.getsockname()[1]
    finally:
        done.set()
        thread.join(GENEROUS_S)
        listener.close()
        for conn in held:
            conn.close()


def test_a_rerun_viewer_that_takes_no_data_costs_the_recording_nothing(tmp_path):
    """A viewer that accepted the connection and never read held the writer's end until the
    recorder gave up on it: the run ended "DONE with its recording lost" (exit 3) of a complete
    file (an outside tester's). Now its last data get ``LIVE_FLUSH_TIMEOUT_S``, the writer answers,
    and the recording is whole."""
    from logs.reader import read_info

    with _silent_server() as port:
        cfg = _config(tmp_path, live_rerun=f"rerun+http://127.0.0.1:{port}/proxy")
        with _running_controller(cfg, tmp_path / "s.mcap") as loop_thread:
            rec = loop_thread.recorder  # type: ignore[attr-defined]
            wait_until(lambda: rec.queued > 800, "two seconds of cycles handed to the writer")
    assert rec.error == "", rec.error
    assert rec.written == read_info(tmp_path / "s.mcap").messages > 800


def _foxglove_messages(
    port: int, topics: tuple[str, ...], enough: dict[str, int], subprotocol: str = "foxglove.websocket.v1"
) -> tuple[set[str], dict[str, list[bytes]]]:
    """Subscribe to ``topics`` and collect messages until each topic has ``enough[topic]`` (Foxglove
    WebSocket protocol, offering only ``subprotocol``); the topics advertised and the messages."""
    from websockets.sync.client import connect

    got: dict[str, list[bytes]] = {t: [] for t in topics}
    advertised: set[str] = set()
    with connect(
        f"ws://127.0.0.1:{port}", subprotocols=[subprotocol], open_timeout=GENEROUS_S, max_size=None
    ) as ws:
        assert ws.subprotocol == subprotocol
        by_sub: dict[int, str] = {}
        deadline = time.monotonic() + GENEROUS_S
        while any(len(got[t]) < n for t, n in enough.items()):
            assert time.monotonic() < deadline, {k: len(v) for k, v in got.items()}
            msg = ws.recv(timeout=GENEROUS_S)
            if isinstance(msg, str):
                op = json.loads(msg)
                if op.get("op") == "advertise":
                    subs = []
                    for ch in op["channels"]:
                        advertised.add(ch["topic"])
                        if ch["topic"] in topics:
                            sub_id = len(by_sub) + 1
                            by_sub[sub_id] = ch["topic"]
                            subs.append({"id": sub_id, "channelId": ch["id"]})
                    if subs:
                        ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
            elif msg[0] == 1:  # MessageData: opcode, subscription id (u32), log time (u64), payload
                (sub_id,) = struct.unpack_from("<I", msg, 1)
                topic = by_sub.get(sub_id)
                if topic is not None:
                    got[topic].append(bytes(msg[13:]))
    return advertised, got


def _server_up(port: int) -> bool:
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=1.0):
            return True
    except OSError:
        return False


def test_a_legacy_foxglove_client_receives_every_topic_of_the_layout_and_the_fixed_scene_during_the_run(
    tmp_path,
):
    """A client offering only ``foxglove.websocket.v1`` (older Foxglove, Lichtblick), joining after the start."""
    from foxglove_layout_paths import named_topics, plot_paths, resolve
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

    from controller.messages import cheope_pb2 as pb

    port = free_loopback_port()
    cfg = _config(tmp_path, live_foxglove=f"127.0.0.1:{port}")
    with _running_controller(cfg, tmp_path / "s.mcap") as loop_thread:
        wait_until(lambda: _server_up(port), "the Foxglove server listening")
        topics = tuple(sorted(named_topics()))
        advertised, got = _foxglove_messages(port, topics, {"/cycle": 5, "/scene": 5, "/tcp_reference": 1})
        assert loop_thread.is_alive(), loop_thread.ended  # type: ignore[attr-defined]
    assert set(topics) <= advertised
    cycles = [pb.Cycle.FromString(b) for b in got["/cycle"]]
    assert all(len(c.inputs.drives) == 3 for c in cycles)
    assert len({c.cycle for c in cycles}) == len(cycles)  # successive cycles, not one repeated
    ids = {e.id for b in got["/scene"] for e in SceneUpdate.FromString(b).entities}
    assert {"rods", "sliders", "platform"} <= ids
    assert {"base", "guides"} <= ids  # the fixed parts, drawn before this client subscribed
    for paths in plot_paths():  # each plot of the layout has a series in what the live server sends
        assert any(resolve(c, p) is not None for c in cycles for p in paths), paths


def _scene_bytes(entity: str) -> bytes:
    from logs.foxglove_scene import scene_update
    from logs.robot_drawing import Primitive, Shape

    return scene_update(
        [Primitive(entity, Shape.SPHERE, (1.0, 1.0, 1.0, 1.0), radius_m=0.01)], 1
    ).SerializeToString()


@pytest.mark.parametrize("subprotocol", ["foxglove.websocket.v1", "foxglove.sdk.v1"])
def test_a_client_joining_after_the_fixed_scene_was_sent_gets_it_when_it_subscribes(subprotocol):
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

    from logs.live_views import FoxgloveLive

    live = FoxgloveLive(f"127.0.0.1:{free_loopback_port()}")
    try:
        live.fixed(_scene_bytes("base"), 1)  # sent once, before any client is there
        live.log("/scene", _scene_bytes("rods"), 2)
        _, got = _foxglove_messages(live.port, ("/scene",), {"/scene": 1}, subprotocol)
    finally:
        live.close()
    (first,) = got["/scene"]
    assert [e.id for e in SceneUpdate.FromString(first).entities] == ["base"]


def test_a_client_offering_no_foxglove_subprotocol_is_refused(monkeypatch):
    import logging

    from websockets.exceptions import InvalidStatus
    from websockets.sync.client import connect

    from logs.live_views import FoxgloveLive

    # the SDK logs the refusal through Python's logging from its own thread, which would leave a
    # threading._DummyThread for that thread behind (the leak check counts it)
    monkeypatch.setattr(logging.getLogger("foxglove.websocket.server"), "disabled", True)
    live = FoxgloveLive(f"127.0.0.1:{free_loopback_port()}")
    try:
        with pytest.raises(InvalidStatus, match="400"):
            connect(f"ws://127.0.0.1:{live.port}", subprotocols=["mqtt"], open_timeout=GENEROUS_S)
    finally:
        live.close()


@pytest.mark.parametrize(("spec", "message"), [("127.0.0.1:http", "is not a number"), (":70000", "0..65535")])
def test_a_bad_foxglove_address_is_named(spec, message):
    from logs.live_views import LiveViewError, parse_host_port

    with pytest.raises(LiveViewError, match=message):
        parse_host_port(spec)


def test_the_live_server_sends_events_and_joint_states_as_recorded(tmp_path):
    """The channels a recording has beside the layout's: /events and /joint_states (by the robot's joint
    names, with velocities), live."""
    from foxglove_schemas_protobuf.JointStates_pb2 import JointStates

    port = free_loopback_port()
    cfg = _config(tmp_path, live_foxglove=f"127.0.0.1:{port}")
    with _running_controller(cfg, tmp_path / "s.mcap") as loop_thread:
        wait_until(lambda: _server_up(port), "the Foxglove server listening")
        topics = ("/events", "/can", "/joint_states")
        advertised, got = _foxglove_messages(port, topics, {"/joint_states": 3})
        assert loop_thread.is_alive(), loop_thread.ended  # type: ignore[attr-defined]
    assert set(topics) <= advertised
    joints = [JointStates.FromString(b) for b in got["/joint_states"]]
    assert all([j.name for j in js.joints] == ["slider_1", "slider_2", "slider_3"] for js in joints)
    assert any(all(j.HasField("velocity") for j in js.joints) for js in joints[1:])


def test_the_live_servers_stop_service_answers_and_reaches_the_writers_callback():
    """The Foxglove protocol's service call (binary: opcode 2 with the service and call ids, the
    encoding, the payload) reaches ``on_stop``; its answer comes back as the JSON reply."""
    from websockets.sync.client import connect

    from logs.live_views import FoxgloveLive

    calls: list[int] = []

    def on_stop() -> tuple[bool, str]:
        calls.append(1)
        return True, "stop requested"

    live = FoxgloveLive(f"127.0.0.1:{free_loopback_port()}", on_stop)
    try:
        with connect(
            f"ws://127.0.0.1:{live.port}", subprotocols=["foxglove.websocket.v1"], open_timeout=GENEROUS_S
        ) as ws:
            deadline = time.monotonic() + GENEROUS_S
            services: dict[str, int] = {}
            while "stop" not in services:
                assert time.monotonic() < deadline
                msg = ws.recv(timeout=GENEROUS_S)
                if isinstance(msg, str) and json.loads(msg).get("op") == "advertiseServices":
                    services.update({s["name"]: s["id"] for s in json.loads(msg)["services"]})
            encoding = b"json"
            ws.send(struct.pack("<BIII", 2, services["stop"], 7, len(encoding)) + encoding + b"{}")
            while True:
                assert time.monotonic() < deadline
                msg = ws.recv(timeout=GENEROUS_S)
                if isinstance(msg, bytes) and msg[0] == 3:  # ServiceCallResponse
                    service_id, call_id, n = struct.unpack_from("<III", msg, 1)
                    reply = json.loads(msg[13 + n :])
                    break
    finally:
        live.close()
    assert (service_id, call_id, calls) == (services["stop"], 7, [1])
    assert reply == {"accepted": True, "message": "stop requested"}


def test_a_stop_from_the_live_view_reaches_the_recorders_owner(tmp_path):
    """The writer's ``{"command": "stop"}`` line: the recorder calls ``on_remote_stop`` (the service: its
    stop event), on the loop's thread, at its next look at the writer's notices."""
    rec = SessionRecorder(tmp_path / "x.mcap", session_metadata(load_config()))
    stops: list[int] = []
    rec.on_remote_stop = lambda: stops.append(1)
    rec._note({"command": "stop"})
    rec._note({"file": str(tmp_path / "y.mcap")})
    assert stops == [1]


def test_the_live_can_channel_carries_every_frame_at_its_rate(tmp_path):
    """The writer's /can live: the frames since its last message, at most recording.live_can_rate_hz
    (2 Hz here) of the session's time, none twice, none lost between messages."""
    from controller.messages import cheope_pb2 as pb
    from logs.messages import cycle_values_of_pb
    from logs.session_writer import CYCLE, SessionWriter

    port = free_loopback_port()
    cfg = _config(tmp_path, live_foxglove=f"127.0.0.1:{port}", live_can_rate_hz=2.0)
    meta = session_metadata(cfg)
    writer = SessionWriter(
        {
            "path": str(tmp_path / "w.mcap"),
            "metadata": meta,
            "clock_offset_ns": 10**18,
            "chunk_size_bytes": 1 << 20,
            "flush_interval_s": 2.0,
            "compression": "zstd",
        }
    )
    got: dict[str, list[bytes]] = {}
    client = threading.Thread(
        target=lambda: got.update(_foxglove_messages(writer.live.foxglove.port, ("/can",), {"/can": 3})[1])
    )
    try:
        client.start()
        time.sleep(1.0)  # the client subscribes (nothing says when, in the protocol)
        k = 0
        while client.is_alive() and k < 20000:
            t = k * 0.0025
            frames = [(True, 100.0 + t, 0x80, b"", False, False, 0, False, False, False, False)]
            writer.write(
                (
                    CYCLE,
                    0,
                    frames,
                    k,
                    t,
                    100.0 + t,
                    k,
                    cycle_values_of_pb(pb.Cycle(cycle=k, t_s=t)),
                    (),
                    None,
                    None,
                )
            )
            k += 1
            if k % 40 == 0:
                time.sleep(0.01)
    finally:
        client.join(GENEROUS_S)
        writer.finish(k, 0)
        writer.live.close()
    batches = [pb.CanFrames.FromString(b) for b in got["/can"]]
    times = [f.unix_time_ns for b in batches for f in b.frames]
    assert len(batches) >= 3 and times == sorted(set(times))
    assert all(len(b.frames) >= 150 for b in batches[1:])  # half a second of 400 Hz cycles each
    steps = [times[i + 1] - times[i] for i in range(len(times) - 1)]
    assert max(steps) <= 2_500_001  # consecutive cycles: no frame lost between two messages
