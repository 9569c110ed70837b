"""Remote monitoring over Zenoh (controller/monitoring/), hermetic on loopback.

Every session listens and connects on tcp/127.0.0.1 with a free port per test; multicast and
gossip scouting are off (zenoh_session.build_zenoh_config, checked below). The controller
runs as a separate process (controller.tools.sim_controller: loop, law and publisher on
the in-process simulated devices; ``cheope demo`` for the service wiring of the stop).
"""

from __future__ import annotations

import contextlib
import io
import itertools
import json
import os
import re
import selectors
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import replace

import pytest
import zenoh
from busy_machine import TOLERANT
from waiting import GENEROUS_S, wait_for_exit

from controller.config import ConfigError, load_config
from controller.core.cycle_data import CycleInputs, CycleOutputs, DriveFeedback
from controller.core.ports import CycleTiming, ForceSetpointLimit
from controller.messages import cheope_pb2 as pb
from controller.monitoring import zenoh_session
from controller.monitoring.command_gate import decide_command
from controller.monitoring.commands import RobotSelector, query_status, send_command, tool_session
from controller.monitoring.monitor_view import (
    AliveUpdate,
    EventUpdate,
    FleetView,
    MonitorClient,
    StateUpdate,
    ViewModel,
    render,
    render_fleet,
    update_to_json,
)
from controller.monitoring.publisher import MAX_COMMAND_BYTES, MonitorPublisher
from controller.monitoring.query_server import QueryLimits, TokenBucket
from controller.monitoring.zenoh_session import (
    MAX_PEER_SESSIONS,
    MAX_SESSIONS_KEY,
    MonitoringConnectionError,
    MonitorKeys,
    SessionSettings,
    build_zenoh_config,
    client_settings,
    connected,
    free_loopback_port,
    monitor_settings,
    open_tool_session,
    split_endpoints,
)
from controller.shell.service import publisher_settings

KEYS = MonitorKeys.for_robot("cheope", "test-bot")


def _env() -> dict[str, str]:
    """The environment of the processes a test starts, read when it starts them: the session's
    temporary XDG directories (tests/conftest.py) are set after this module is imported."""
    return {**os.environ, "PYTHONUNBUFFERED": "1"}


def _endpoint() -> str:
    return f"tcp/127.0.0.1:{free_loopback_port()}"


def _controller_cmd(endpoint: str, *sets: str, max_duration_s: float = 30.0) -> list[str]:
    cmd = [
        sys.executable,
        "-m",
        "controller.tools.sim_controller",
        "--max-duration",
        str(max_duration_s),
        "--set",
        f'monitoring.listen="{endpoint}"',
        "--set",
        'monitoring.robot_id="test-bot"',
        "--set",
        'monitoring.on_listen_busy="fail"',
        "--set",
        "task.path.laps=20",
        # these tests check monitoring, not timing: a loaded machine must not fault the run (SYNC watchdog, late cycles)
        *TOLERANT,
        "--set",
        "actuators.sync_watchdog_s=0.5",
    ]
    for s in sets:
        cmd += ["--set", s]
    return cmd


def _readline(proc: subprocess.Popen[str], timeout_s: float) -> str:
    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)
    try:
        if not sel.select(timeout=timeout_s):
            raise AssertionError(f"no output from the controller within {timeout_s} s")
        return proc.stdout.readline()
    finally:
        sel.close()


def _stop(proc: subprocess.Popen[str]) -> str:
    """SIGTERM (a controlled stop), then the rest of its stdout."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
    try:
        out, _ = proc.communicate(timeout=15)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate()
    return out


@contextmanager
def controller(endpoint: str, *sets: str, max_duration_s: float = 30.0):
    proc = subprocess.Popen(
        _controller_cmd(endpoint, *sets, max_duration_s=max_duration_s),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=_env(),
    )
    try:
        line = _readline(proc, 30.0)
        assert line.startswith("READY"), f"{line!r} {proc.stderr.read() if proc.poll() is not None else ''}"
        yield proc
    finally:
        _stop(proc)


def _final(out: str) -> dict:
    return json.loads([line for line in out.splitlines() if line.startswith("{")][-1])


def _states(client: MonitorClient, n: int, timeout_s: float = 10.0) -> list[StateUpdate]:
    got: list[StateUpdate] = []
    deadline = time.monotonic() + timeout_s
    while len(got) < n and time.monotonic() < deadline:
        u = client.next_update(0.2)
        if isinstance(u, StateUpdate):
            got.append(u)
    assert len(got) == n, f"received {len(got)} of {n} state samples in {timeout_s} s"
    return got


def _wait_mode(
    client: MonitorClient, mode: str | frozenset[str], timeout_s: float = GENEROUS_S
) -> StateUpdate:
    """The first published state sample in ``mode`` (or one of a set); fails at the deadline (the loops
    it replaces went on silently, or had no deadline at all)."""
    modes = frozenset((mode,)) if isinstance(mode, str) else mode
    deadline = time.monotonic() + timeout_s
    seen = []
    while time.monotonic() < deadline:
        u = client.next_update(0.2)
        if isinstance(u, StateUpdate):
            if u.msg.mode in modes:
                return u
            seen = [*seen[-4:], u.msg.mode]
    raise AssertionError(f"no state sample in {mode} within {timeout_s} s; the last ones: {seen}")


def _wait_alive(client: MonitorClient, alive: bool, timeout_s: float = 10.0) -> AliveUpdate:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        u = client.next_update(0.2)
        if isinstance(u, AliveUpdate) and u.alive == alive:
            return u
    raise AssertionError(f"no liveliness {'PUT' if alive else 'DELETE'} within {timeout_s} s")


# -- configuration: loopback, no scouting ---------------------------------------------------


def test_default_sessions_stay_on_loopback_with_scouting_off(cfg):
    s = publisher_settings(cfg).session
    assert s.listen == ("tcp/127.0.0.1:7448",) and s.connect == ()
    for settings in (s, monitor_settings(), client_settings()):
        conf = build_zenoh_config(settings)
        assert json.loads(conf.get_json("scouting/multicast/enabled")) is False
        assert json.loads(conf.get_json("scouting/gossip/enabled")) is False
        assert all("127.0.0.1" in e for e in json.loads(conf.get_json("listen/endpoints")))
        assert all("127.0.0.1" in e for e in json.loads(conf.get_json("connect/endpoints")))


def test_a_zenoh_file_keeps_its_settings_and_gets_the_defaults_for_the_rest(tmp_path):
    f = tmp_path / "z.json5"
    f.write_text(
        '{ mode: "peer", connect: { endpoints: ["tcp/127.0.0.1:9001"] }, '
        "scouting: { multicast: { enabled: false }, gossip: { enabled: true } } }"
    )
    conf = build_zenoh_config(
        SessionSettings(listen=("tcp/127.0.0.1:9000",), connect=("tcp/127.0.0.1:9002",), config_file=str(f))
    )
    assert json.loads(conf.get_json("connect/endpoints")) == ["tcp/127.0.0.1:9001", "tcp/127.0.0.1:9002"]
    assert json.loads(conf.get_json("listen/endpoints")) == ["tcp/127.0.0.1:9000"]  # unset in the file
    assert json.loads(conf.get_json("scouting/gossip/enabled")) is True  # the file's explicit choice
    with pytest.raises(ConfigError, match="config_file"):
        build_zenoh_config(SessionSettings(config_file=str(tmp_path / "missing.json5")))


def test_a_listening_session_takes_at_most_max_peer_sessions_and_a_file_may_say_otherwise(tmp_path):
    listening = SessionSettings(listen=("tcp/127.0.0.1:9000",))
    assert json.loads(build_zenoh_config(listening).get_json(MAX_SESSIONS_KEY)) == MAX_PEER_SESSIONS
    default = json.loads(zenoh.Config().get_json(MAX_SESSIONS_KEY))
    for tool in (monitor_settings(), client_settings()):  # they take no sessions: Zenoh's default
        assert json.loads(build_zenoh_config(tool).get_json(MAX_SESSIONS_KEY)) == default
    f = tmp_path / "z.json5"
    f.write_text("{ transport: { unicast: { max_sessions: 500 } } }")
    own = build_zenoh_config(replace(listening, config_file=str(f)))
    assert json.loads(own.get_json(MAX_SESSIONS_KEY)) == 500


def test_a_session_past_the_listening_sessions_limit_is_refused_and_the_others_stay(monkeypatch):
    monkeypatch.setattr(zenoh_session, "MAX_PEER_SESSIONS", 3)
    endpoint = _endpoint()
    server, _ = zenoh_session.open_session(SessionSettings(listen=(endpoint,)))
    clients: list[zenoh.Session] = []
    try:
        for _ in range(3):
            clients.append(open_tool_session(client_settings((endpoint,))))
        with pytest.raises(MonitoringConnectionError):
            clients.append(open_tool_session(client_settings((endpoint,), timeout_s=0.5)))
        assert [connected(c) for c in clients] == [1, 1, 1]  # the three within the limit stay
    finally:
        for c in clients:
            c.close()
        server.close()


@pytest.mark.parametrize(
    "key, value, match",
    [
        ("monitoring.robot_id", "a/b", "robot_id"),
        ("monitoring.key_prefix", "", "key_prefix"),
        ("monitoring.listen", "127.0.0.1:7448", "monitoring.listen"),
        ("monitoring.connect", "tcp/host:99999", "monitoring.connect"),
    ],
)
def test_bad_monitoring_settings_name_the_key(key, value, match):
    with pytest.raises(ConfigError, match=match):
        publisher_settings(load_config(overrides={key: value}))


def test_endpoints_split_on_commas():
    assert split_endpoints(" tcp/127.0.0.1:1, tcp/[::1]:2 ,", "k") == ("tcp/127.0.0.1:1", "tcp/[::1]:2")


# -- the command gate ------------------------------------------------------------------------


def test_stop_is_always_accepted_and_other_commands_only_when_enabled():
    limit = ForceSetpointLimit(30.0, "the task's")
    assert decide_command("stop", 0.0, False, limit).accepted
    for name in ("pause", "resume", "set_force"):
        refused = decide_command(name, 5.0, False, limit)
        assert not refused.accepted and "--allow-remote-commands" in refused.message
        assert decide_command(name, 5.0, True, limit).forward
    assert not decide_command("reboot", 0.0, True, limit).accepted


# -- the loop's side: never waits --------------------------------------------------------------


def _cycle_args(k: int):
    inputs = CycleInputs(drives=(DriveFeedback(0x1237, 0.55, True),) * 3)
    outputs = CycleOutputs((0x0F,) * 3, (0.55,) * 3)
    return k, k * 0.0025, inputs, outputs, CycleTiming(1e-5, 1e-4)


def test_on_cycle_publishes_every_nth_cycle_on_the_loops_thread(cfg):
    cfg = load_config(overrides={"monitoring.publish_rate_hz": 100.0, "monitoring.listen": _endpoint()})
    from controller.assembly import build_law

    state = build_law(cfg).initial_state()
    threads_before = {t.name for t in threading.enumerate()}
    with MonitorPublisher(publisher_settings(cfg), threading.Event()) as pub:
        # no publisher thread: only the three query servers, which sleep in Rust (query_server.py)
        added = {t.name for t in threading.enumerate()} - threads_before
        assert added == {"cheope-query-status", "cheope-query-command", "cheope-query-schema"}
        for k in range(400):
            cycle, t, inputs, outputs, timing = _cycle_args(k)
            pub.on_cycle(cycle, t, inputs, state, outputs, (), timing)
        assert pub.published_samples == 100  # every 4th of 400 cycles (400 Hz -> 100 Hz)
        assert pub.publish_errors == 0
        assert pub.commands() is None
    assert {t.name for t in threading.enumerate()} == threads_before  # the query servers ended with it


def test_the_published_loop_statistics_are_the_last_cycles_period_errors(cfg):
    """Rate, period-error percentiles and maximum over the last 1 023 periods (the publisher's ring)."""
    cfg = load_config(overrides={"monitoring.listen": _endpoint()})
    from controller.assembly import build_law

    state = build_law(cfg).initial_state()
    with MonitorPublisher(publisher_settings(cfg), threading.Event()) as pub:
        for k in range(2000):
            cycle, t, inputs, outputs, _ = _cycle_args(k)
            late_s = 1e-3 if k % 100 == 50 else 0.0  # each late wake-up: two periods 1 ms off
            pub.on_cycle(cycle, t, inputs, state, outputs, (), CycleTiming(late_s, 1e-4))
        rate, p50, p99, worst = pub._timing_statistics()
    # the window: 1 023 periods, 20 of them 1 ms off (10 late wake-ups), the rest exact
    assert rate == pytest.approx(400.0, rel=1e-3)
    assert p50 == pytest.approx(0.0, abs=1e-6)
    assert p99 == pytest.approx(1000.0, abs=1e-6) and worst == pytest.approx(1000.0, abs=1e-6)


# -- across processes ------------------------------------------------------------------------


def test_monitor_receives_decimated_state_and_events_from_another_process():
    ep = _endpoint()
    with (
        MonitorClient(monitor_settings((ep,)), KEYS) as client,
        controller(ep, "monitoring.publish_rate_hz=100.0"),
    ):
        assert _wait_alive(client, True).key == KEYS.alive
        states = _states(client, 30)
    cycles = [s.msg.cycle for s in states]
    steps = [b - a for a, b in itertools.pairwise(cycles)]
    # 400 Hz decimated to 100 Hz: every 4th cycle (5 or more only where the loop skipped a late deadline)
    assert min(steps) == 4 and steps.count(4) >= 0.8 * len(steps), steps
    last = states[-1].msg
    assert last.robot_id == "test-bot" and len(last.positions) == 3 and len(last.targets) == 3
    assert last.task == "path" and last.mode in ("HOLDING", "RUNNING")
    assert 300.0 < last.loop.achieved_rate_hz < 420.0
    latency = [s.received_monotonic_s - s.msg.cycle_monotonic_s for s in states]
    assert min(latency) > 0.0 and max(latency) < 0.5


def test_every_cycle_is_published_when_the_rate_allows_it():
    ep = _endpoint()
    rates = ("monitoring.publish_rate_hz=400.0", "loop.rate_hz=200.0")
    with MonitorClient(monitor_settings((ep,)), KEYS) as client, controller(ep, *rates):
        _wait_alive(client, True)
        cycles = [s.msg.cycle for s in _states(client, 40)]
    # 1, or more where the loop skipped late deadlines (a busy machine skips several in a row)
    assert sum(b - a == 1 for a, b in itertools.pairwise(cycles)) >= 30, cycles


def test_liveliness_goes_away_and_comes_back():
    ep = _endpoint()
    with MonitorClient(monitor_settings((ep,)), KEYS) as client:
        view = ViewModel(KEYS.prefix)
        with controller(ep):
            view.apply(_wait_alive(client, True))
            _states(client, 2)
        view.apply(_wait_alive(client, False))
        assert view.alive is False
        with controller(ep):  # the same endpoint: the monitor's session reconnects by itself
            view.apply(_wait_alive(client, True))
            _states(client, 2)
    assert view.alive is True and view.changes == 2


def test_status_queryable_answers_configuration_versions_counters_and_uptime():
    ep = _endpoint()
    with MonitorClient(monitor_settings((ep,)), KEYS) as client, controller(ep):
        _states(client, 1)  # it has cycled and published: an event, not a guessed 0.3 s
        st = query_status(client_settings((ep,)), KEYS, timeout_s=5.0)
    assert st.robot_id == "test-bot" and not st.commands_enabled
    assert list(st.listen_endpoints) == [ep]
    assert st.counters["cycles"] > 0 and st.uptime_s > 0.0
    assert json.loads(st.config_json)["monitoring"]["robot_id"] == "test-bot"
    assert any(v.startswith("eclipse-zenoh==") for v in st.versions)
    assert st.mode in ("CONFIGURING", "ENABLING", "HOLDING", "RUNNING", "STARTING")


def test_a_command_other_than_stop_is_refused_when_commands_are_disabled():
    ep = _endpoint()
    with controller(ep) as proc:
        reply = send_command(client_settings((ep,)), KEYS, "pause", timeout_s=5.0)[1]
        assert not reply.accepted and "--allow-remote-commands" in reply.message
        out = _stop(proc)
    assert not any("remote pause" in e for e in _final(out)["events"])
    assert _final(out)["publisher"]["commands_refused"] == 1


def test_an_oversized_command_is_refused_by_its_size_before_any_copy_or_parse():
    """16-MB queries to the command key, 20 a second, stalled the loop 57.6 ms (an outside tester,
    44dbcbc): each was copied and parsed under the interpreter lock. Now refused by its length,
    named; a real command after it is answered as ever."""
    ep = _endpoint()
    with controller(ep) as proc, tool_session(client_settings((ep,), timeout_s=5.0)) as session:
        for size in (MAX_COMMAND_BYTES + 1, 4_000_000):
            big = list(session.get(KEYS.command, payload=bytes(size), timeout=10.0))
            assert big and big[0].ok is not None
            message = pb.CommandReply.FromString(big[0].ok.payload.to_bytes()).message
            assert f"payload of {size} bytes; a cheope.v1.Command is at most {MAX_COMMAND_BYTES}" in message
        reply = send_command(client_settings((ep,)), KEYS, "pause", timeout_s=5.0)[1]
        assert not reply.accepted and "--allow-remote-commands" in reply.message
        out = _stop(proc)
    assert _final(out)["publisher"]["commands_refused"] == 3


def test_pause_and_resume_reach_the_law_when_enabled():
    ep = _endpoint()
    with (
        MonitorClient(monitor_settings((ep,)), KEYS) as client,
        controller(ep, "monitoring.allow_remote_commands=true") as proc,
    ):
        _wait_mode(client, "RUNNING")
        assert send_command(client_settings((ep,)), KEYS, "pause", timeout_s=5.0)[1].accepted
        _wait_mode(client, "PAUSED")
        assert send_command(client_settings((ep,)), KEYS, "resume", timeout_s=5.0)[1].accepted
        _wait_mode(client, "RUNNING")
        out = _stop(proc)
    events = _final(out)["events"]
    assert any("remote pause" in e for e in events) and any("remote resume" in e for e in events)


def test_remote_stop_brings_a_running_task_to_a_controlled_stop():
    ep = _endpoint()
    with MonitorClient(monitor_settings((ep,)), KEYS) as client, controller(ep) as proc:
        _wait_mode(client, "RUNNING")
        reply = send_command(client_settings((ep,)), KEYS, "stop", timeout_s=5.0)[1]
        assert reply.accepted
        proc.wait(timeout=10)  # it ends by itself: the stop, not our SIGTERM
        final = _final(_stop(proc))
        kinds = [u for u in iter(lambda: client.next_update(0.5), None) if isinstance(u, EventUpdate)]
    assert final["final_mode"] == "DONE"
    assert "INFO: RUNNING -> STOPPING: stop requested" in final["events"]
    assert any("STOPPING" in e.msg.message for e in kinds)  # the events went out over Zenoh too


@pytest.mark.integration
def test_cheope_stop_stops_cheope_demo_through_the_service():
    ep = _endpoint()
    demo = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "controller",
            "demo",
            "--task",
            "path",
            "--json",
            "--set",
            "task.path.laps=20",
            "--set",
            f'monitoring.listen="{ep}"',
            "--set",
            'monitoring.on_listen_busy="fail"',
            # this test starts more processes meanwhile; it checks the stop command, not timing, so the
            # drives' SYNC watchdog gets 0.5 s too (a CI run once faulted on a 50 ms gap at start)
            *TOLERANT,
            "--set",
            "actuators.sync_watchdog_s=0.5",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=_env(),
    )
    try:
        cli = [sys.executable, "-m", "controller"]
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            st = subprocess.run(
                [*cli, "status", "--json", "--zenoh-connect", ep],
                check=False,
                capture_output=True,
                text=True,
                env=_env(),
                timeout=30,
            )
            if st.returncode == 0 and json.loads(st.stdout)["mode"] == "RUNNING":
                break
            time.sleep(0.3)
            if demo.poll() is not None:
                out_, err_ = demo.communicate()
                pytest.fail(f"the demo exited {demo.returncode}: {out_[-1500:]} {err_[-1500:]}")
        else:
            pytest.fail(f"the demo never reported RUNNING: {st.stderr}")
        mon = subprocess.run(
            [*cli, "monitor", "--json", "--count", "3", "--duration", "10", "--zenoh-connect", ep],
            check=False,
            capture_output=True,
            text=True,
            env=_env(),
            timeout=30,
        )
        lines = [json.loads(line) for line in mon.stdout.splitlines()]
        seen = f"monitor stdout {mon.stdout[-1500:]!r} stderr {mon.stderr[-1500:]!r}, demo running: {demo.poll() is None}"
        assert sum(d["type"] == "state" for d in lines) == 3, seen
        assert any(d["type"] == "liveliness" and d["alive"] for d in lines), seen
        stop = subprocess.run(
            [*cli, "stop", "--zenoh-connect", ep],
            check=False,
            capture_output=True,
            text=True,
            env=_env(),
            timeout=30,
        )
        assert stop.returncode == 0 and stop.stdout.startswith("accepted"), stop.stderr
        out, err = demo.communicate(timeout=30)
    finally:
        if demo.poll() is None:
            demo.kill()
            demo.communicate()
    summary = json.loads(out)
    assert summary["final_mode"] == "DONE", err
    assert any("stop requested" in e for e in summary["events"])


def test_status_without_a_controller_ends_with_one_clear_line():
    ep = _endpoint()
    r = subprocess.run(
        [sys.executable, "-m", "controller", "status", "--zenoh-connect", ep, "--timeout", "1"],
        check=False,
        capture_output=True,
        text=True,
        env=_env(),
        timeout=30,
    )
    assert r.returncode == 2
    assert r.stderr.count("\n") == 1 and ep in r.stderr and r.stderr.startswith("cheope status: error:")
    with pytest.raises(MonitoringConnectionError, match=re.escape("127.0.0.1")):
        query_status(client_settings((ep,)), KEYS, timeout_s=1.0)


def test_a_tool_started_before_the_controller_listens_connects_within_its_timeout():
    """A Zenoh client tries once by default: ``cheope status`` beside a busy listener failed at once
    (1 of 30 concurrent calls beside 12 monitors, an outside tester). It retries until its timeout."""
    ep = _endpoint()
    listening = threading.Event()

    def listen_late() -> None:
        time.sleep(0.3)  # the tool is opening meanwhile: its first attempt finds nobody
        conf = build_zenoh_config(SessionSettings(mode="peer", listen=(ep,), connect=()))
        with zenoh.open(conf):
            listening.set()
            done.wait(GENEROUS_S)

    done = threading.Event()
    listener = threading.Thread(target=listen_late, daemon=True)
    listener.start()
    try:
        session = open_tool_session(client_settings((ep,), timeout_s=GENEROUS_S))
        try:
            assert listening.is_set() and connected(session) == 1
        finally:
            session.close()
    finally:
        done.set()
        listener.join(GENEROUS_S)


def test_only_a_client_with_a_timeout_is_given_one():
    tool = build_zenoh_config(client_settings((_endpoint(),), timeout_s=2.0))
    assert json.loads(tool.get_json("connect/timeout_ms")) == 2000
    forever = build_zenoh_config(SessionSettings(mode="client", listen=(), connect=(_endpoint(),)))
    # not set: Zenoh's own for a client (try once), never -1 (wait at open for ever)
    assert json.loads(forever.get_json("connect/timeout_ms")) is None


# -- the view --------------------------------------------------------------------------------


def test_view_renders_state_alarms_events_and_liveliness():
    msg = pb.MonitorState(
        robot_id="r",
        cycle=12,
        t_s=0.03,
        mode="RUNNING",
        task="path",
        task_phase="TRACKING",
        targets=[0.5, 0.6, 0.7],
        positions=[0.5001, 0.6, 0.7],
        tcp_m=[0.0, 0.01, 0.5],
        force_n=[0.1, 0.2, 9.5],
        alarms=["drive 2: no TPDO for 1 cycle(s)"],
    )
    view = ViewModel("cheope/r")
    view.apply(AliveUpdate("cheope/r/alive", True, 1.0))
    view.apply(StateUpdate("cheope/r/state", msg, 1.1))
    view.apply(EventUpdate("cheope/r/events", pb.Event(t_s=0.02, severity=pb.WARNING, message="late"), 1.1))
    view.apply(AliveUpdate("cheope/r/alive", False, 1.2))
    from rich.console import Console

    buf = io.StringIO()
    Console(file=buf, width=120).print(render(view, 1.5))
    text = buf.getvalue()
    for expected in (
        "RUNNING",
        "TRACKING",
        "drive 2: no TPDO",
        "+9.500 N",
        "controller gone",
        "WARNING",
        "gone",
    ):
        assert expected in text, expected
    line = json.loads(update_to_json(StateUpdate("cheope/r/state", msg, 1.1)))
    assert line["type"] == "state" and line["cycle"] == 12 and line["force_n"] == [0.1, 0.2, 9.5]


def test_a_peers_text_is_shown_as_it_is_and_an_unknown_severity_by_its_number():
    """Rich markup in a peer's mode, alarm or event ("[/bold]") raised MarkupError and ended
    ``cheope monitor``; an event severity this build does not know raised ValueError."""
    from rich.console import Console

    msg = pb.MonitorState(robot_id="r[/]", mode="[/bold]", task="[red]x", alarms=["[/] alarm"])
    view = ViewModel("cheope/r[/]")
    view.apply(StateUpdate("cheope/r/state", msg, 1.1))
    view.apply(EventUpdate("cheope/r/events", pb.Event(t_s=0.02, severity=99, message="[/] closing"), 1.1))
    fleet = FleetView("cheope")
    fleet.apply(StateUpdate("cheope/a[b]/state", msg, 1.1))
    fleet.apply(StateUpdate("cheope/b/state", msg, 1.1))
    buf = io.StringIO()
    Console(file=buf, width=160).print(render(view, 1.5))
    Console(file=buf, width=160).print(render_fleet(fleet, 1.5))
    text = buf.getvalue()
    for expected in ("[/bold]", "[red]x", "[/] alarm", "severity 99", "[/] closing", "a[b]"):
        assert expected in text, expected


# -- many robots: ids, cheope list, a router -------------------------------------------------


def _cheope(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "controller", *args],
        check=False,
        capture_output=True,
        text=True,
        env=_env(),
        timeout=60,
    )


def _json(r: subprocess.CompletedProcess[str]):
    assert r.returncode == 0 and r.stdout, f"exit {r.returncode}: {r.stderr}"
    return json.loads(r.stdout)


def _connect(*endpoints: str) -> list[str]:
    return [a for e in endpoints for a in ("--zenoh-connect", e)]


def test_a_default_robot_id_is_the_host_and_a_suffix_and_differs_between_controllers():
    a, b = (publisher_settings(load_config()) for _ in range(2))
    host = socket.gethostname().split(".")[0]
    assert a.robot_id_is_default and a.robot_id.rsplit("-", 1)[0] == re.sub(r"[^A-Za-z0-9_.\-]+", "-", host)
    assert re.fullmatch(r"[0-9a-f]{4}", a.robot_id.rsplit("-", 1)[1])
    assert (
        a.keys.prefix == f"cheope/{a.robot_id}"
        and json.loads(a.config_json)["monitoring"]["robot_id"] == a.robot_id
    )
    assert a.robot_id != b.robot_id or a.robot_id != publisher_settings(load_config()).robot_id
    assert not publisher_settings(load_config(overrides={"monitoring.robot_id": "r1"})).robot_id_is_default


def _second_controller(endpoint: str, *sets: str) -> subprocess.CompletedProcess[str]:
    """A controller started beside a running one, to its end (10 s at most, if it is not refused)."""
    return subprocess.run(
        _controller_cmd(endpoint, *sets, max_duration_s=10.0),
        check=False,
        capture_output=True,
        text=True,
        env=_env(),
        timeout=60,
    )


def test_a_robot_id_already_live_refuses_the_start():
    ep_a, ep_b = _endpoint(), _endpoint()
    with controller(ep_a, 'monitoring.robot_id="dup"'):
        second = _second_controller(ep_b, 'monitoring.robot_id="dup"', f'monitoring.connect="{ep_a}"')
        assert second.returncode == 2, second.stdout + second.stderr
        assert "monitoring.robot_id = 'dup' is taken" in second.stderr and second.stderr.count("\n") == 1
        assert not second.stdout.startswith("READY")
        listed = _json(_cheope("list", "--json", *_connect(ep_a)))
    assert [c["robot_id"] for c in listed] == ["dup"]  # the first one went on


def test_a_robot_id_live_on_this_machine_refuses_the_start_without_connecting_to_it():
    """Both only listen (the default): no liveliness query of the second reaches the first, and
    before the announcements were asked it took the first one's id and answered its `cheope stop`."""
    ep_a, ep_b = _endpoint(), _endpoint()
    with controller(ep_a, 'monitoring.robot_id="twin"') as first:
        second = _second_controller(ep_b, 'monitoring.robot_id="twin"')
        assert second.returncode == 2, second.stdout + second.stderr
        assert f"the controller of process {first.pid} on this machine announces it" in second.stderr
        assert second.stderr.count("\n") == 1 and not second.stdout.startswith("READY")
        listed = _json(_cheope("list", "--json", *_connect(ep_a)))
    assert [c["robot_id"] for c in listed] == ["twin"]  # the first one went on


def test_a_drawn_robot_id_that_is_taken_is_drawn_again():
    ep = _endpoint()
    with controller(ep, 'monitoring.robot_id="bot-a"'):
        settings = publisher_settings(
            load_config(overrides={"monitoring.listen": _endpoint(), "monitoring.connect": ep})
        )
        taken = replace(settings, robot_id="bot-a", keys=MonitorKeys.for_robot("cheope", "bot-a"))
        with MonitorPublisher(taken, threading.Event()) as pub:
            assert (
                pub.settings.robot_id != "bot-a"
                and pub.settings.keys.prefix == f"cheope/{pub.settings.robot_id}"
            )
            both = _connect(ep, *pub.listen_endpoints)  # peers do not route for each other: ask both
            ids = [c["robot_id"] for c in _json(_cheope("list", "--json", *both))]
        assert sorted(ids) == sorted(["bot-a", pub.settings.robot_id])


def test_cheope_list_shows_two_controllers_and_the_tools_address_them_by_id():
    ep_a, ep_b = _endpoint(), _endpoint()
    with (
        controller(ep_a, 'monitoring.robot_id="bot-a"', max_duration_s=120.0),
        controller(ep_b, 'monitoring.robot_id="bot-b"', max_duration_s=120.0) as proc_b,
    ):
        # the tools go on once connected to both; on a busy machine that took longer than their
        # default 2 s, and a tool that reached one of two names no robot (commands.py). 20 s: within
        # _cheope's 60 s, and no longer than needed when both answer
        both = [*_connect(ep_a, ep_b), "--timeout", "20"]
        listed = _cheope("list", "--json", *both)
        assert listed.returncode == 0, listed.stderr
        rows = {c["robot_id"]: c for c in json.loads(listed.stdout)}
        assert sorted(rows) == ["bot-a", "bot-b"]
        assert rows["bot-a"]["listen_endpoints"] == [ep_a] and rows["bot-b"]["listen_endpoints"] == [ep_b]
        assert all(r["task"] == "path" and r["mode"] and r["uptime_s"] > 0 for r in rows.values())
        table = _cheope("list", *both).stdout.splitlines()
        assert table[0].startswith("robot id") and [line.split()[0] for line in table[1:]] == [
            "bot-a",
            "bot-b",
        ]
        ambiguous = _cheope("status", *both)
        assert ambiguous.returncode == 2 and ambiguous.stderr.count("\n") == 1
        assert (
            "2 controllers reachable (bot-a, bot-b)" in ambiguous.stderr and "--robot-id" in ambiguous.stderr
        )
        st = _json(_cheope("status", "--json", "--robot-id", "bot-b", *both))
        assert st["robot_id"] == "bot-b"
        stop = _cheope("stop", "--robot-id", "bot-b", *both)
        assert stop.returncode == 0 and stop.stdout.startswith("accepted by bot-b:"), stop.stderr
        wait_for_exit(proc_b.pid, "bot-b's controller after cheope stop")
        only_a = _json(_cheope("list", "--json", *_connect(ep_a, ep_b)))  # bot-b's endpoint: no wait
        assert [c["robot_id"] for c in only_a] == ["bot-a"]  # bot-a was not stopped
        # bot-b's endpoint answers no more: without an id the tool cannot tell an ended controller
        # from a stopped or slow one (commands.py), so it names none; given bot-a's endpoint alone,
        # bot-a is the only one
        partial = _cheope("status", *_connect(ep_a, ep_b))
        assert partial.returncode == 2 and "reached 1 of the 2 endpoints given" in partial.stderr
        one = _json(_cheope("status", "--json", *_connect(ep_a)))
        assert one["robot_id"] == "bot-a"


@contextmanager
def _two_publishers(allow_remote_commands: bool = True):
    """Two robots' publishers in this process (bot-a, bot-b), each on its own loopback endpoint."""
    pubs, events = [], []
    with contextlib.ExitStack() as stack:
        for robot_id in ("bot-a", "bot-b"):
            cfg = load_config(
                overrides={
                    "monitoring.listen": _endpoint(),
                    "monitoring.robot_id": robot_id,
                    "monitoring.allow_remote_commands": allow_remote_commands,
                }
            )
            events.append(threading.Event())
            pubs.append(stack.enter_context(MonitorPublisher(publisher_settings(cfg), events[-1])))
        yield pubs, events


def test_without_an_id_a_tool_that_did_not_reach_every_endpoint_given_addresses_no_robot():
    """A tool given two controllers' endpoints that reached only one (the other's process stopped, or
    slower to answer than the open's wait on a busy machine) took it for the only one and sent it the
    command meant for "the only controller". Now it refuses and names what it did not reach; by id it
    goes through."""
    with _two_publishers() as (pubs, events):
        (ep_a,) = pubs[0].listen_endpoints
        nobody = _endpoint()  # a free loopback port: nothing answers there, as a stopped process
        partial = client_settings((ep_a, nobody), timeout_s=1.0)
        for ask in (
            lambda: query_status(partial, RobotSelector(), timeout_s=1.0),
            lambda: send_command(partial, RobotSelector(), "pause", timeout_s=1.0),
        ):
            with pytest.raises(MonitoringConnectionError) as refused:
                ask()
            text = str(refused.value)
            assert "reached 1 of the 2 endpoints given" in text and nobody in text and "--robot-id" in text
        assert all(p.commands() is None for p in pubs) and not any(e.is_set() for e in events)
        robot, reply = send_command(partial, RobotSelector(robot_id="bot-a"), "pause", timeout_s=5.0)
        assert robot == "bot-a" and reply.accepted, reply.message
        assert pubs[0].commands() == ("pause", 0.0) and pubs[1].commands() is None
        whole = client_settings(tuple(e for p in pubs for e in p.listen_endpoints), timeout_s=5.0)
        with pytest.raises(
            MonitoringConnectionError, match=re.escape("2 controllers reachable (bot-a, bot-b)")
        ):
            query_status(whole, RobotSelector(), timeout_s=5.0)


def test_a_wildcard_key_is_refused_by_every_robot_and_moves_none():
    """Issue 38: one get on cheope/*/command with a stop put two robots into STOPPING."""
    with _two_publishers() as (pubs, events):
        endpoints = tuple(e for p in pubs for e in p.listen_endpoints)
        with tool_session(client_settings(endpoints)) as session:
            for key in ("cheope/*/command", "cheope/**", "**/command"):
                for name in ("stop", "pause", "set_force"):
                    payload = pb.Command(name=name, value=5.0).SerializeToString()
                    replies = list(session.get(key, payload=payload, timeout=5.0))
                    answers = [pb.CommandReply.FromString(r.ok.payload.to_bytes()) for r in replies if r.ok]
                    assert len(answers) == 2 and not any(a.accepted for a in answers), (key, answers)
                    assert all("names one robot by its id, without wildcards" in a.message for a in answers)
            status = [r for r in session.get("cheope/*/status", timeout=5.0)]
            assert len(status) == 2 and all(r.err is not None for r in status)
            assert b"without wildcards" in status[0].err.payload.to_bytes()
            assert not any(e.is_set() for e in events) and all(p.commands() is None for p in pubs)
            exact = pb.Command(name="stop").SerializeToString()
            (reply,) = [r for r in session.get("cheope/bot-a/command", payload=exact, timeout=5.0) if r.ok]
            assert pb.CommandReply.FromString(reply.ok.payload.to_bytes()).accepted
        assert [e.is_set() for e in events] == [True, False]
        assert [p.commands_refused for p in pubs] == [9, 9]


def test_cheope_stop_all_stops_each_robot_by_its_own_id_and_robot_id_takes_no_wildcard():
    with _two_publishers(allow_remote_commands=False) as (pubs, events):
        endpoints = [e for p in pubs for e in p.listen_endpoints]
        wildcard = _cheope("stop", "--robot-id", "*", *_connect(*endpoints))
        assert wildcard.returncode == 2 and "no wildcard" in wildcard.stderr and "--all" in wildcard.stderr
        assert not any(e.is_set() for e in events)
        everyone = _cheope("stop", "--all", *_connect(*endpoints))
        assert everyone.returncode == 0, everyone.stderr
        assert sorted(line.split(":")[0] for line in everyone.stdout.splitlines()) == [
            "accepted by bot-a",
            "accepted by bot-b",
        ]
        assert all(e.is_set() for e in events)


@contextmanager
def _peer_answering(endpoint: str, status: bytes, command_reply: bytes) -> Iterator[None]:
    """A Zenoh peer on ``endpoint`` that looks like controller "fake" and answers its status and
    command queries with the given bytes, whatever they are."""
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("listen/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(conf)
    try:
        token = session.liveliness().declare_token("cheope/fake/alive")
        q1 = session.declare_queryable("cheope/fake/status", lambda q: q.reply("cheope/fake/status", status))
        q2 = session.declare_queryable(
            "cheope/fake/command", lambda q: q.reply("cheope/fake/command", command_reply)
        )
        yield
        for entity in (q1, q2, token):
            entity.undeclare()
    finally:
        session.close()


@pytest.mark.parametrize(
    ("status", "reply", "said"),
    [
        (b"\xff\xff\xff", b"\xff\xff\xff", "3 bytes that are no cheope.v1."),
        (pb.Status(robot_id="fake", config_json="[]").SerializeToString(), b"", "a JSON list, not an object"),
        (pb.Status(robot_id="fake", config_json="nope").SerializeToString(), b"", "config_json is not JSON"),
    ],
    ids=["no-protobuf", "config-a-list", "config-not-json"],
)
def test_a_peer_answering_nonsense_gets_one_line_naming_it_not_a_traceback(status, reply, said):
    """Before: protobuf's DecodeError or an AttributeError ended cheope list/status/stop with a traceback."""
    ep = _endpoint()
    with _peer_answering(ep, status, reply):
        listed = _cheope("list", "--json", *_connect(ep))
        shown = _cheope("status", "--robot-id", "fake", *_connect(ep))
        stopped = _cheope("stop", "--robot-id", "fake", *_connect(ep))
    assert listed.returncode == 0, listed.stderr
    assert [r["robot_id"] for r in json.loads(listed.stdout)] == ["fake"]  # listed, without details
    assert shown.returncode == 2 and "Traceback" not in shown.stderr and said in shown.stderr, shown.stderr
    assert shown.stderr.count("\n") == 1 and "cheope/fake/status" in shown.stderr  # one line naming the key
    if reply:
        assert stopped.returncode == 2 and "Traceback" not in stopped.stderr, stopped.stderr
        assert "cheope/fake/command" in stopped.stderr and "no cheope.v1.CommandReply" in stopped.stderr


def test_tools_that_find_nothing_say_so_in_one_line():
    ep = _endpoint()
    listed = _cheope("list", *_connect(ep))
    status = _cheope("status", *_connect(ep))
    assert (
        listed.returncode == status.returncode == 2 and listed.stdout == ""
    )  # one answer for "no controller"
    assert listed.stderr.count("\n") == 1 and listed.stderr.startswith("cheope list: no controller found")
    assert ep in listed.stderr
    mon = _cheope("monitor", "--json", "--duration", "1", *_connect(ep))
    assert mon.returncode == 0 and mon.stdout == ""
    assert mon.stderr.count("\n") == 1 and mon.stderr.startswith("cheope monitor: ") and ep in mon.stderr
    stop = _cheope("stop", *_connect(ep))
    assert stop.returncode == 2 and stop.stderr.count("\n") == 1 and ep in stop.stderr


def test_three_controllers_monitored_from_one_place_through_a_router():
    router_ep = _endpoint()
    router = subprocess.Popen(
        [sys.executable, "-m", "controller", "router", "--listen", router_ep],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=_env(),
    )
    try:
        assert _readline(router, 30.0).startswith(f"READY {router_ep}")
        ids = ("bot-1", "bot-2", "bot-3")
        with contextlib.ExitStack() as stack:
            for rid in ids:  # each listens nowhere and connects only to the router
                stack.enter_context(
                    controller(
                        "",
                        f'monitoring.robot_id="{rid}"',
                        f'monitoring.connect="{router_ep}"',
                        'monitoring.mode="client"',
                        "loop.rate_hz=100.0",
                        "monitoring.publish_rate_hz=10.0",
                        max_duration_s=120.0,
                    )
                )
            listed = _cheope("list", "--json", *_connect(router_ep))
            assert sorted(c["robot_id"] for c in _json(listed)) == list(ids)
            mon = _cheope("monitor", "--json", "--count", "30", "--duration", "30", *_connect(router_ep))
            states = [d for d in map(json.loads, mon.stdout.splitlines()) if d["type"] == "state"]
            assert {d["robot_id"] for d in states} == set(ids), mon.stderr
    finally:
        router.send_signal(signal.SIGTERM)
        router.communicate(timeout=30)
    assert router.returncode == 0


def test_cheope_command_reset_brings_a_controller_out_of_fault():
    ep = _endpoint()
    sets = (
        "monitoring.allow_remote_commands=true",
        "loop.stay_in_fault=true",
        'sim.faults=["drive_fault:2@0.5+0.2"]',
    )
    with MonitorClient(monitor_settings((ep,)), KEYS) as client, controller(ep, *sets):
        _wait_mode(client, "FAULT")
        reset = _cheope("command", "reset", "--robot-id", "test-bot", *_connect(ep))
        assert reset.returncode == 0 and reset.stdout.startswith("accepted by test-bot: reset accepted"), (
            reset.stderr
        )
        # Out of FAULT, which only a reset does here (the injected fault is one-shot and the loop stays in
        # FAULT otherwise). Not the ENABLING sample itself: ENABLING lasts a few cycles, and samples go out
        # with congestion control DROP (controller/monitoring/publisher.py); a CI run once saw none of
        # ENABLING and only the later DONE.
        _wait_mode(client, frozenset({"ENABLING", "HOLDING", "RUNNING", "STOPPING", "DONE"}))


def test_a_token_bucket_answers_its_burst_then_at_its_rate():
    now = [0.0]
    slept: list[float] = []

    def sleep(s: float) -> None:
        slept.append(s)
        now[0] += s

    bucket = TokenBucket(rate_hz=20.0, burst=5, clock=lambda: now[0], sleep=sleep)
    for _ in range(5):
        bucket.wait()
    assert slept == []  # the burst goes back to back
    for _ in range(20):
        bucket.wait()
    assert len(slept) == 20 and now[0] == pytest.approx(1.0)  # then one every 1/20 s
    now[0] += 10.0  # a long pause refills to the burst, not beyond
    for _ in range(6):
        bucket.wait()
    assert len(slept) == 21
    with pytest.raises(ValueError, match="rate_hz"):
        QueryLimits(rate_hz=0.0)
