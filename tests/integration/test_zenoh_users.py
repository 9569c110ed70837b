"""What a plain Zenoh user gets (issue 40): the recent events when joining late, a count of the
events missed, the schema over Zenoh, and the tools scoped to this user's controllers.

Hermetic on loopback: every session listens on tcp/127.0.0.1 with a free port; the runtime
directory of announcements is the test session's own (tests/conftest.py).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from typing import Any

import zenoh
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

from controller.assembly import build_law
from controller.config import load_config
from controller.core.cycle_data import CycleInputs, CycleOutputs, DriveFeedback, Event, Severity
from controller.core.ports import CycleTiming
from controller.messages import cheope_pb2 as pb
from controller.monitoring import local_controllers
from controller.monitoring.monitor_view import (
    EventUpdate,
    MissedEventsUpdate,
    MonitorClient,
    UndecodableUpdate,
    ViewModel,
    update_to_json,
)
from controller.monitoring.publisher import MonitorPublisher
from controller.monitoring.zenoh_session import (
    EVENT_HISTORY,
    SCHEMA_ENCODING,
    MonitorKeys,
    SessionSettings,
    client_settings,
    encoding_for,
    free_loopback_port,
    monitor_settings,
    open_session,
)
from controller.shell.service import publisher_settings


def _publisher(robot_id: str = "late-bot") -> MonitorPublisher:
    cfg = load_config(
        overrides={
            "monitoring.listen": f"tcp/127.0.0.1:{free_loopback_port()}",
            "monitoring.robot_id": robot_id,
        }
    )
    return MonitorPublisher(publisher_settings(cfg), threading.Event())


OUTPUTS = CycleOutputs((0x0F,) * 3, (0.55,) * 3)
TIMING = CycleTiming(1e-5, 1e-4)


def _publish_events(pub: MonitorPublisher, texts: list[str], first_cycle: int = 0) -> None:
    state = build_law(load_config()).initial_state()
    inputs = CycleInputs(drives=(DriveFeedback(0x1237, 0.55, True),) * 3)
    for k, text in enumerate(texts, first_cycle):
        pub.on_cycle(k, k * 0.0025, inputs, state, OUTPUTS, (Event("note", Severity.INFO, text),), TIMING)


def _events(client: MonitorClient, n: int, timeout_s: float = 20.0) -> list[str]:
    got: list[str] = []
    deadline = time.monotonic() + timeout_s
    while len(got) < n and time.monotonic() < deadline:
        u = client.next_update(0.2)
        if isinstance(u, EventUpdate):
            got.append(u.msg.message)
    return got


def test_a_monitor_that_joins_late_gets_the_recent_events_then_the_new_ones():
    with _publisher() as pub:
        texts = [f"event {i}" for i in range(EVENT_HISTORY + 10)]
        _publish_events(pub, texts)  # nobody listens yet
        keys = MonitorKeys.for_robot("cheope", "*", allow_wildcard=True)
        with MonitorClient(monitor_settings(pub.listen_endpoints), keys) as client:
            history = _events(client, EVENT_HISTORY)
            assert history == texts[-EVENT_HISTORY:]  # the last ones the cache kept, in order
            _publish_events(pub, ["after joining"], first_cycle=len(texts))
            assert _events(client, 1) == ["after joining"]


def test_a_miss_is_counted_in_the_view_and_the_json_lines():
    view = ViewModel("cheope/bot")
    view.apply(MissedEventsUpdate("cheope/bot/events", 3, 1.0))
    view.apply(MissedEventsUpdate("cheope/bot/events", 2, 2.0))
    assert view.missed_events == 5 and "5 in all" in view.events[-1]
    line = json.loads(update_to_json(MissedEventsUpdate("cheope/bot/events", 3, 1.0)))
    assert line == {
        "type": "missed_events",
        "key": "cheope/bot/events",
        "received_monotonic_s": 1.0,
        "count": 3,
    }


def test_a_plain_zenoh_client_fetches_the_schema_and_decodes_the_state_with_it():
    """No project code on the client side: the FileDescriptorSet from the schema queryable builds the
    message classes, which decode the published state."""
    with _publisher("schema-bot") as pub:
        keys = pub.settings.keys
        session, _ = open_session(SessionSettings(mode="client", connect=pub.listen_endpoints))
        try:
            replies = [r.ok for r in session.get(keys.schema, timeout=5.0) if r.ok is not None]
            assert len(replies) == 1 and str(replies[0].encoding) == SCHEMA_ENCODING
            fds = descriptor_pb2.FileDescriptorSet.FromString(replies[0].payload.to_bytes())
            pool = descriptor_pool.DescriptorPool()
            for f in fds.file:
                pool.Add(f)
            state_class = message_factory.GetMessageClass(
                pool.FindMessageTypeByName("cheope.v1.MonitorState")
            )
            received: list[bytes] = []
            sub = session.declare_subscriber(keys.state, lambda s: received.append(s.payload.to_bytes()))
            state = build_law(load_config()).initial_state()
            inputs = CycleInputs(drives=(DriveFeedback(0x1237, 0.25, True),) * 3)
            try:
                deadline = time.monotonic() + 20.0
                cycle = 0
                while not received and time.monotonic() < deadline:  # until the subscription is in place
                    pub.on_cycle(cycle, 0.0, inputs, state, OUTPUTS, (), TIMING)
                    cycle += pub.settings.decimation  # the next one published too
                    time.sleep(0.05)
            finally:
                sub.undeclare()
            msg = state_class.FromString(received[0])
            assert msg.robot_id == "schema-bot" and list(msg.positions) == [0.25] * 3
            # a wildcard query is no way around the robot's id (issue 38's rule)
            assert not [r for r in session.get("cheope/*/schema", timeout=2.0) if r.ok is not None]
        finally:
            session.close()


def _tool_json(command: str) -> Any:
    """``cheope COMMAND --json`` without ``--zenoh-connect`` (this user's controllers), its answer."""
    r = subprocess.run(
        [sys.executable, "-m", "controller", command, "--json"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout)


def test_a_controller_on_two_endpoints_is_reached_through_one_and_is_the_only_one():
    """Zenoh keeps one session per peer: a tool that connected to both endpoints of one controller
    counted the second as not reached and, without an id, refused (commands.py). The tools connect
    to one endpoint of each controller."""
    first, second = (f"tcp/127.0.0.1:{free_loopback_port()}" for _ in range(2))
    cfg = load_config(overrides={"monitoring.listen": f"{first},{second}", "monitoring.robot_id": "two-ends"})
    with MonitorPublisher(publisher_settings(cfg), threading.Event()) as pub:
        assert set(pub.listen_endpoints) == {first, second}
        assert local_controllers.local_endpoints() == (pub.listen_endpoints[0],)
        assert _tool_json("status")["robot_id"] == "two-ends"


def test_tools_without_an_endpoint_find_this_users_controllers_not_the_default_port():
    """Two controllers on free ports, neither on the default 7448: `cheope list` with no --zenoh-connect
    finds both from their announcements, and nothing is left announced after they close."""
    with _publisher("mine-a") as a, _publisher("mine-b") as b:
        assert set(local_controllers.local_endpoints()) == {*a.listen_endpoints, *b.listen_endpoints}
        assert client_settings().connect == local_controllers.local_endpoints()
        assert sorted(c["robot_id"] for c in _tool_json("list")) == ["mine-a", "mine-b"]
    assert local_controllers.local_endpoints() == ()
    assert not list(local_controllers.runtime_directory().glob("*.json"))


def test_a_stale_announcement_is_dropped_and_a_shared_directory_is_not_used(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))
    d = local_controllers.runtime_directory()
    path = local_controllers.announce("ghost", ("tcp/127.0.0.1:1",))
    assert path is not None and path.parent == d and (d.stat().st_mode & 0o777) == 0o700
    gone = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True
    )
    entry = json.loads(path.read_text())
    path.write_text(json.dumps({**entry, "pid": int(gone.stdout)}))  # its process has ended
    assert local_controllers.local_endpoints() == () and not path.exists()
    d.chmod(0o777)  # anyone may write there: not trusted
    assert local_controllers.announce("other", ("tcp/127.0.0.1:2",)) is None
    d.chmod(0o700)
    assert os.environ["XDG_RUNTIME_DIR"] == str(tmp_path)


def test_the_event_publisher_still_serves_a_plain_zenoh_subscriber():
    with _publisher("plain-bot") as pub:
        session, _ = open_session(SessionSettings(mode="client", connect=pub.listen_endpoints))
        got: list[zenoh.Sample] = []
        sub = session.declare_subscriber(pub.settings.keys.events, got.append)
        try:
            deadline = time.monotonic() + 20.0
            k = 0
            while not got and time.monotonic() < deadline:
                _publish_events(pub, ["hello"], first_cycle=k)
                k += 1
                time.sleep(0.1)
        finally:
            sub.undeclare()
            session.close()
        assert got and str(got[0].encoding).endswith("cheope.v1.Event")


def test_a_hostile_peer_neither_breaks_the_tools_nor_passes_for_another_robot():
    """A peer beside a real controller: a liveliness token no controller declares, a robot whose
    status names another robot and whose mode carries terminal escapes, and a state sample of
    100 kB. Before (an outside tester's findings): `cheope list` and `stop --all` ended on the
    token's id for every robot, `cheope status` showed the impostor's status, its ESC reached
    the terminal, and the monitor's queue grew without a bound."""
    with _publisher("real-bot") as pub:
        peer_at = f"tcp/127.0.0.1:{free_loopback_port()}"  # peers do not route for each other: the monitor asks both
        peer, _ = open_session(SessionSettings(mode="peer", listen=(peer_at,), connect=pub.listen_endpoints))
        impostor = pb.Status(robot_id="real-bot", mode="PWNED\x1b[2J").SerializeToString()
        try:
            tokens = [peer.liveliness().declare_token(k) for k in ("cheope/*/alive", "cheope/fake/alive")]
            served = peer.declare_queryable(
                "cheope/fake/status", lambda q: q.reply(q.key_expr, impostor), complete=True
            )
            both = ("--zenoh-connect", pub.listen_endpoints[0])
            listed = subprocess.run(
                [sys.executable, "-m", "controller", "list", "--json", *both],
                capture_output=True, text=True, timeout=60, check=False,
            )  # fmt: skip
            assert listed.returncode == 0, listed.stderr
            rows = {c["robot_id"]: c for c in json.loads(listed.stdout)}
            assert sorted(rows) == ["fake", "real-bot"]  # the wildcard token names no robot
            assert rows["fake"]["mode"] == "" and rows["real-bot"]["mode"] != ""  # the impostor's not shown
            status = subprocess.run(
                [sys.executable, "-m", "controller", "status", "--robot-id", "fake", *both],
                capture_output=True, text=True, timeout=60, check=False,
            )  # fmt: skip
            assert status.returncode != 0 and "the status of robot 'real-bot', not 'fake'" in status.stderr
            assert "\x1b" not in status.stdout + status.stderr
            keys = MonitorKeys.for_robot("cheope", "*", allow_wildcard=True)
            with MonitorClient(monitor_settings((*pub.listen_endpoints, peer_at)), keys) as client:
                deadline = time.monotonic() + 20.0
                seen: list[object] = []
                while time.monotonic() < deadline and not any(isinstance(u, UndecodableUpdate) for u in seen):
                    peer.put("cheope/fake/state", bytes(100_000))
                    seen += [u for u in iter(lambda: client.next_update(0.05), None)]
            big = [u for u in seen if isinstance(u, UndecodableUpdate)]
            assert big and big[0].reason == "100000 bytes: larger than any cheope.v1 state or event"
        finally:
            for entity in (*tokens, served):
                entity.undeclare()
            peer.close()


def test_a_command_query_that_says_it_carries_another_message_is_refused():
    """A Status whose robot_id is "stop" parses as a Command named "stop" (field 1 both): sent as
    a Status, it stopped the robot (an outside tester's finding). The encoding a query states is
    checked; a payload without one is read as a Command, as before."""
    with _publisher("typed-bot") as pub:
        keys = pub.settings.keys
        session, _ = open_session(SessionSettings(mode="client", connect=pub.listen_endpoints))
        try:

            def ask(payload: bytes, encoding: object = None) -> pb.CommandReply:
                options = {"encoding": encoding} if encoding is not None else {}
                replies = [r.ok for r in session.get(keys.command, payload=payload, timeout=10.0, **options)]
                assert len(replies) == 1 and replies[0] is not None
                return pb.CommandReply.FromString(replies[0].payload.to_bytes())

            status = pb.Status(robot_id="stop").SerializeToString()
            refused = ask(status, encoding_for("Status"))
            assert not refused.accepted and "cheope.v1.Status, not a cheope.v1.Command" in refused.message
            assert not pub.stop_event.is_set()
            assert ask(pb.Command(name="stop").SerializeToString(), encoding_for("Command")).accepted
            assert pub.stop_event.is_set()
        finally:
            session.close()
