"""Live views during a run: a Rerun gRPC server and a Foxglove WebSocket client receive the session as it runs.

The controller is the production loop shell, control law and recorder (whose writer process feeds
the live views) on the in-process simulated devices, paced in real time on this process's
thread; everything stays on loopback. The receivers: ``rerun --save`` (Rerun's own gRPC server,
writing what it receives to an .rrd that Rerun's reader reads back) and a WebSocket client
speaking the Foxglove protocol (``websockets``).
"""

from __future__ import annotations

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
        loop = CycleLoop(law, exchange, cfg.period_s, cfg.loop.collect_fraction, DeadlineSleeper(0.0),
                         time.monotonic, observers=(rec,), stop_event=stop)

        def run() -> None:
            try:
                final, _ = loop.run(law.initial_state(), GENEROUS_S)
                ended.append(f"{final.mode.name} {final.fault_reason}")
            except BaseException as err:  # noqa: BLE001 - reported by the test
                errors.append(err)

        thread = threading.Thread(target=run, name="test-loop")
        thread.ended = ended  # type: ignore[attr-defined]
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
    overrides: dict[str, object] = {"recording.directory": str(tmp_path), "task.path.laps": 20.0,
                                    "safety.on_late_cycles": "warn", "loop.max_missing_cycles": 10,
                                    "sim.drive.sync_timeout_s": 5.0}
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
    except Exception:  # noqa: BLE001 - a file the server is still writing: read it again later
        return set()


def test_a_rerun_grpc_server_receives_the_robot_and_the_plots_during_the_run(tmp_path):
    port = free_loopback_port()
    rrd = tmp_path / "live.rrd"
    server = subprocess.Popen([_rerun_binary(), "--bind", "127.0.0.1", "--port", str(port),
                               "--save", str(rrd)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        ProcessLines(server).next_matching(lambda line: "Listening for gRPC" in line, "the Rerun server listening")
        cfg = _config(tmp_path, live_rerun=f"rerun+http://127.0.0.1:{port}/proxy")
        with _running_controller(cfg, tmp_path / "s.mcap") as loop_thread:
            wanted = {"/world/rods/capsules", "/world/sliders/boxes", "/world/guides/capsules",
                      "/plots/actuators/position_1"}
            wait_until(lambda: wanted <= _rrd_entities(rrd), "the robot and the plots at the Rerun server")
            # received while the controller runs (20 laps: about 100 s)
            assert loop_thread.is_alive(), loop_thread.ended  # type: ignore[attr-defined]
    finally:
        server.terminate()
        wait_for_exit(server.pid, "the Rerun server")
        server.wait()


def _foxglove_messages(port: int, topics: tuple[str, ...], count: int) -> dict[str, list[bytes]]:
    """Subscribe to ``topics`` and collect ``count`` messages of each (Foxglove WebSocket protocol)."""
    from websockets.sync.client import connect

    got: dict[str, list[bytes]] = {t: [] for t in topics}
    with connect(f"ws://127.0.0.1:{port}", subprotocols=["foxglove.sdk.v1", "foxglove.websocket.v1"],
                 open_timeout=GENEROUS_S, max_size=None) as ws:
        by_sub: dict[int, str] = {}
        deadline = time.monotonic() + GENEROUS_S
        while any(len(v) < count for v in got.values()):
            assert time.monotonic() < deadline, {k: len(v) for k, v in got.items()}
            msg = ws.recv(timeout=GENEROUS_S)
            if isinstance(msg, str):
                op = json.loads(msg)
                if op.get("op") == "advertise":
                    subs = []
                    for ch in op["channels"]:
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
    return got


def test_a_foxglove_websocket_client_receives_the_cycle_and_the_scene_during_the_run(tmp_path):
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

    from controller.messages import cheope_pb2 as pb

    port = free_loopback_port()
    cfg = _config(tmp_path, live_foxglove=f"127.0.0.1:{port}")
    with _running_controller(cfg, tmp_path / "s.mcap") as loop_thread:
        def server_up() -> bool:
            try:
                with socket.create_connection(("127.0.0.1", port), timeout=1.0):
                    return True
            except OSError:
                return False

        wait_until(server_up, "the Foxglove server listening")
        got = _foxglove_messages(port, ("/cycle", "/scene"), count=5)
        assert loop_thread.is_alive(), loop_thread.ended  # type: ignore[attr-defined]
    cycles = [pb.Cycle.FromString(b) for b in got["/cycle"]]
    assert all(len(c.inputs.drives) == 3 for c in cycles)
    assert len({c.cycle for c in cycles}) == len(cycles)  # successive cycles, not one repeated
    ids = {e.id for b in got["/scene"] for e in SceneUpdate.FromString(b).entities}
    assert {"rods", "sliders", "platform"} <= ids


@pytest.mark.parametrize(("spec", "message"), [("127.0.0.1:http", "is not a number"), (":70000", "0..65535")])
def test_a_bad_foxglove_address_is_named(spec, message):
    from logs.live_views import LiveViewError, parse_host_port

    with pytest.raises(LiveViewError, match=message):
        parse_host_port(spec)
