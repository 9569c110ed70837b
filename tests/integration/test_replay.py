"""Replay: bit-exact verification through the step, and frames back onto a bus."""

from __future__ import annotations

import json
import random
import subprocess
import sys
import textwrap
import threading
from pathlib import Path

import can
import pytest
from test_recording import record_session

from controller.cli import main
from controller.config import load_config
from drivers.bus import parse_bus_spec
from logs.recorder import SessionRecorder, session_metadata
from logs.replay_bus import replay_to_bus
from logs.replay_verify import verify

DATA = Path(__file__).resolve().parents[1] / "data"
REPO = DATA.parent.parent


@pytest.mark.parametrize("name", ["path_quarter_lap.mcap", "contour_contact.mcap"])
def test_the_committed_sessions_still_replay_bit_for_bit(name):
    """The regression test of the control law (regenerate with tests/data/regenerate.py)."""
    result = verify(DATA / name)
    assert result.ok, result.summary()
    assert result.cycles_checked > 500 and not result.problems


def test_a_fresh_recording_verifies(tmp_path):
    path = tmp_path / "s.mcap"
    _, _, stats, _, _, _ = record_session(path)
    result = verify(path)
    assert result.ok and result.cycles_checked == stats.cycles, result.summary()


def test_a_changed_gain_is_reported_at_the_first_divergence(tmp_path, capsys):
    path = tmp_path / "s.mcap"
    record_session(path)
    result = verify(path, {"actuators.max_jerk_m_s3": 400.0})
    assert not result.ok
    d = result.divergence
    assert d.field.startswith(("outputs.targets", "state.setpoint"))
    assert d.recorded != d.recomputed
    assert d.cycle == result.cycles_checked  # every cycle before it was identical (cycles count from 0)
    assert main(["replay", str(path), "--verify", "--set", "actuators.max_jerk_m_s3=400.0"]) == 1
    out = capsys.readouterr().out
    assert out.startswith("DIVERGES") and f"cycle {d.cycle}" in out and d.field in out
    assert main(["replay", str(path), "--verify", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["ok"] is True


def test_verify_stops_at_a_recorder_drop(tmp_path):
    path = tmp_path / "s.mcap"
    _, _, _, trace, _, _ = record_session(tmp_path / "ref.mcap", max_s=0.5, frames=False)
    rec = SessionRecorder(
        path, session_metadata(load_config(overrides={"task.path.laps": 0.1, "task.path.ramp_s": 0.1}))
    )
    with rec:
        for k, row in enumerate(trace.rows):
            if k == 50:
                rec._cycle_calls += 1  # what a full queue does: the call index moves on, nothing is queued,
                rec._lost(1)  # the loss is counted
                continue
            rec.on_cycle(*row, timing=_Timing())
    result = verify(path)
    assert result.cycles_checked == 50 and result.cycles_recorded == len(trace.rows) - 1
    assert not result.ok and result.divergence is None
    assert any("1 cycle(s) dropped by the recorder before cycle 51" in p for p in result.problems)
    assert f"50 of the {len(trace.rows) - 1} readable cycle(s)" in result.summary()


class _Timing:
    wake_error_s = 0.0
    step_s = 0.0


def test_verify_of_a_truncated_file_checks_what_is_there_and_exits_non_zero(tmp_path, capsys):
    src = DATA / "path_quarter_lap.mcap"
    path = tmp_path / "t.mcap"
    data = src.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    result = verify(path)
    # what is there is verified, and the check says it could not verify the whole session
    assert not result.ok and result.divergence is None and 100 < result.cycles_checked < 821
    assert any(p.startswith("truncated") for p in result.problems)
    assert main(["replay", str(path), "--verify"]) == 3
    out = capsys.readouterr().out
    assert (
        out.startswith(f"PARTLY VERIFIED: the {result.cycles_checked} readable cycle(s) (cycles 0..")
        and "truncated" in out
    )


_RECEIVER = textwrap.dedent("""
    import sys, time, json
    sys.path.insert(0, {repo!r})
    from drivers.bus import open_bus, parse_bus_spec
    with open_bus(parse_bus_spec("udp_multicast", udp_port={port})) as bus:
        print("ready", flush=True)
        got = []
        idle_until = time.monotonic() + 20.0
        while time.monotonic() < idle_until:
            msg = bus.recv(timeout=0.5)
            if msg is None:
                if got:
                    break
                continue
            got.append([msg.arbitration_id, msg.data.hex(), msg.timestamp])
            idle_until = time.monotonic() + 1.0
    print(json.dumps(got), flush=True)
""")


def test_replay_onto_a_bus_is_received_by_another_process_with_the_timing(tmp_path, capsys):
    path = tmp_path / "s.mcap"
    _, _, _, _, sent, _ = record_session(path, max_s=0.6)
    # the recording: per cycle one outgoing 0x201 and one incoming 0x181 frame, each sent once
    expected = [(arb, data.hex()) for _, _, arb, data in sent]
    port = random.randint(20000, 60000)
    proc = subprocess.Popen(
        [sys.executable, "-c", _RECEIVER.format(repo=str(REPO), port=port)], stdout=subprocess.PIPE, text=True
    )
    try:
        assert proc.stdout.readline().strip() == "ready"
        # no device here: the check for live ones would put its probe before the recorded frames
        result = replay_to_bus(
            path, parse_bus_spec("udp_multicast", udp_port=port), speed=2.0, live_devices=True
        )
        out, _ = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    got = json.loads(out.strip().splitlines()[-1])
    assert result.frames_sent == len(expected) and result.send_errors == 0
    assert [(a, d) for a, d, _ in got] == expected
    # timing: the recorded span, halved by --speed 2
    recorded_span = sent[-1][1] - sent[0][1]
    received_span = got[-1][2] - got[0][2]
    assert received_span == pytest.approx(recorded_span / 2.0, rel=0.15)


def test_replay_sends_every_recorded_frame_once_whatever_its_direction(tmp_path):
    """The recording holds each frame once (drivers/frame_tap.py): nothing is guessed away, not even
    an incoming frame with the COB-ID of one the controller sends (a foreign SYNC)."""
    path = tmp_path / "e.mcap"
    with SessionRecorder(path, session_metadata(load_config()), clock=lambda: 0.0) as rec:
        tx = can.Message(arbitration_id=0x80, data=b"", is_extended_id=False)
        rx = can.Message(arbitration_id=0x181, data=b"\x01", is_extended_id=False)
        for k in range(5):
            rec.on_frame(True, k * 1e-3, tx)
            rec.on_frame(False, k * 1e-3 + 2e-4, rx)
        rec.on_frame(False, 5e-3, tx)  # another node's SYNC
    bus = can.Bus(interface="virtual", channel="replay-once", receive_own_messages=False)
    listener = can.Bus(interface="virtual", channel="replay-once")
    try:
        result = replay_to_bus(
            path, parse_bus_spec("virtual:replay-once"), speed=10.0, bus=bus, live_devices=True
        )
        got = []
        while (msg := listener.recv(timeout=0.2)) is not None:
            got.append(msg.arbitration_id)
    finally:
        bus.shutdown()
        listener.shutdown()
    assert result.frames_sent == 11
    assert got == [0x80, 0x181] * 5 + [0x80]


def test_a_stop_ends_a_replay_in_a_long_pause_between_frames(tmp_path):
    """``--speed 1e-9`` turned the 1 ms between two frames into 11 days, and SIGTERM or Ctrl-C
    (the stop event) was read only after that sleep: the replay waits on the stop now."""
    path = tmp_path / "pause.mcap"
    with SessionRecorder(path, session_metadata(load_config()), clock=lambda: 0.0) as rec:
        sync = can.Message(arbitration_id=0x80, data=b"", is_extended_id=False)
        rec.on_frame(True, 0.0, sync)
        rec.on_frame(True, 1e-3, sync)
    stop = threading.Event()
    bus = can.Bus(interface="virtual", channel="replay-pause", receive_own_messages=False)
    listener = can.Bus(interface="virtual", channel="replay-pause")
    results = []
    replay = threading.Thread(
        target=lambda: results.append(
            replay_to_bus(
                path,
                parse_bus_spec("virtual:replay-pause"),
                speed=1e-9,
                stop_event=stop,
                bus=bus,
                live_devices=True,
            )
        ),
        daemon=True,  # a replay that ignored the stop must not keep the test process alive
    )
    try:
        replay.start()
        assert listener.recv(timeout=30.0) is not None  # the first frame went: the pause has begun
        stop.set()
        replay.join(timeout=30.0)
        assert not replay.is_alive()
    finally:
        stop.set()
        replay.join(timeout=30.0)
        bus.shutdown()
        listener.shutdown()
    assert results[0].frames_sent == 1


def test_a_bad_set_in_a_verify_is_blamed_on_the_set_not_the_recording(tmp_path, capsys):
    path = tmp_path / "s.mcap"
    record_session(path, max_s=0.1)
    assert main(["replay", str(path), "--verify", "--set", "bogus=1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "with --set bogus: unknown key(s) bogus" in err
    assert "does not load any more" not in err


def test_a_bad_rate_in_a_verify_of_an_older_recording_is_named_as_itself(capsys):
    """The committed recordings predate actuators.extrapolation_s, which their loading derives from
    the rate: --set loop.rate_hz=nan was blamed on "actuators.extrapolation_s = nan" (an outside
    tester's)."""
    recorded = Path(__file__).resolve().parents[1] / "data" / "path_quarter_lap.mcap"
    assert main(["replay", str(recorded), "--verify", "--set", "loop.rate_hz=nan"]) == 2
    err = capsys.readouterr().err
    assert "loop.rate_hz = nan: must be finite" in err and "extrapolation_s" not in err


def test_replay_cli_errors_are_one_line(tmp_path, capsys):
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"\x89MCAP0\r\n")
    assert main(["replay", str(bad), "--verify"]) == 3  # not a divergence, but nothing verified either
    assert capsys.readouterr().out.startswith("NOT VERIFIED: nothing verified")
    assert main(["replay", str(tmp_path / "nope.mcap"), "--verify"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "cannot read" in err
