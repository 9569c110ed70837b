"""Session recording (logs/recorder.py), reading damaged files (logs/reader.py) and recovery."""

from __future__ import annotations

import contextlib
import itertools
import json
import os
import signal
import subprocess
import sys
import textwrap
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import can
import pytest
from controller_on_the_bus import (
    ControllerOnTheBus,
    child_running,
    controller_beside_simulator,
    run_sets,
    wait_until_drive_1_moves,
)
from waiting import GENEROUS_S, ProcessLines, wait_for_exit, wait_until

from controller.assembly import build_law
from controller.cli import main
from controller.config import config_from_dict, load_config
from controller.core.controller_state import Mode
from controller.shell.loop import CycleLoop, SimulatedTime
from logs import messages as m
from logs.reader import LogFileError, info_dict, iter_decoded, read_info
from logs.recorder import SessionRecorder, open_session_file, session_metadata
from logs.recovery import recover
from sim_backend.loopback import LoopbackExchange

REPO = Path(__file__).resolve().parents[2]
SHORT = {"task.path.laps": 0.1, "task.path.ramp_s": 0.1}


@dataclass
class Trace:
    rows: list = field(default_factory=list)

    def on_cycle(self, cycle, t, inputs, state, outputs, events, timing):
        self.rows.append((cycle, t, inputs, state, outputs, events))


def record_session(path: Path, overrides=SHORT, max_s: float = 10.0, frames: bool = True, **kw):
    """A deterministic simulated session; with ``frames`` a fake frame stream through the sink too.

    Lossless: simulated time runs far faster than the writer, and no deadline is at stake.
    """
    kw.setdefault("lossless", True)
    cfg = load_config(overrides=overrides)
    clock = SimulatedTime()
    law = build_law(cfg)
    ex = LoopbackExchange(cfg, clock.clock)
    trace = Trace()
    sent: list[tuple[bool, float, int, bytes]] = []
    with SessionRecorder(
        path, session_metadata(cfg), clock=clock.clock, phase_name=law.task.phase_name, **kw
    ) as rec:
        out_msg = can.Message(arbitration_id=0x201, data=bytearray(8), is_extended_id=False)

        class Sink:  # rewrites one preallocated outgoing message, as drivers/cyclic_exchange.py does
            def on_cycle(self, cycle, t, inputs, state, outputs, events, timing):
                if not frames:
                    return
                out_msg.data[0:4] = cycle.to_bytes(4, "little")
                rec.on_frame(True, clock.now_s, out_msg)
                sent.append((True, clock.now_s, 0x201, bytes(out_msg.data)))
                rx = can.Message(arbitration_id=0x181, data=bytes([cycle & 0xFF, 1, 2]), is_extended_id=False)
                rec.on_frame(False, clock.now_s + 1e-4, rx)
                sent.append((False, clock.now_s + 1e-4, 0x181, bytes(rx.data)))

        loop = CycleLoop(
            law,
            ex,
            cfg.period_s,
            cfg.loop.collect_fraction,
            clock,
            clock.clock,
            observers=(trace, rec, Sink()),
        )
        final, stats = loop.run(law.initial_state(), max_s)
    return cfg, final, stats, trace, sent, rec


def test_round_trip_counts_and_contents_match(tmp_path):
    path = tmp_path / "s.mcap"
    cfg, final, stats, trace, sent, rec = record_session(path)
    assert final.mode == Mode.DONE
    assert rec.dropped == 0 and rec.error == ""
    report = read_info(path)
    assert report.complete and not report.problems
    assert report.message_counts[m.TOPIC_CYCLE] == stats.cycles == len(trace.rows)
    # the frames before each cycle in one /can message, not one per frame (the frames a cycle's
    # observer sends go with the next cycle, the last ones in a batch of their own at close)
    assert report.message_counts[m.TOPIC_CAN] == len(trace.rows) == len(sent) // 2
    n_events = sum(len(r[5]) for r in trace.rows)
    assert report.message_counts[m.TOPIC_EVENTS] == report.message_counts[m.TOPIC_LOG] == n_events == 5
    # every cycle's TCP is in /cycle; the viewers' /tcp follows the 3D scene's rate, exactly
    tcp_times = [
        d.message.timestamp.seconds * 10**9 + d.message.timestamp.nanos
        for d in iter_decoded(path, [m.TOPIC_TCP])
    ]
    cycle_times = {d.log_time_ns: d.message for d in iter_decoded(path, [m.TOPIC_CYCLE])}
    assert set(tcp_times) <= set(cycle_times)
    gaps_s = [(b - a) * 1e-9 for a, b in itertools.pairwise(tcp_times)]
    interval_s = 1.0 / cfg.recording.scene_rate_hz
    # on the cycles' grid: a cycle early or late, as rounding of the times places it
    assert gaps_s and all(abs(g - interval_s) <= cfg.period_s + 1e-9 for g in gaps_s)

    cycles = [d for d in iter_decoded(path, [m.TOPIC_CYCLE])]
    for d, (cycle, t, inputs, state, outputs, _) in zip(cycles, trace.rows, strict=True):
        c = d.message
        assert (c.cycle, c.t_s) == (cycle, t)
        assert m.inputs_from_pb(c.inputs) == inputs  # exact doubles
        assert (
            tuple(c.outputs.targets) == outputs.targets
            and tuple(c.outputs.controlwords) == outputs.controlwords
        )
        assert c.state.mode == state.mode.name
        assert tuple(c.state.setpoint_velocity) == state.setpoint.velocity
    assert [d.sequence for d in cycles] == list(range(len(cycles)))
    offset = int(report.metadata[m.META_SESSION]["clock_offset_ns"])
    frames = [
        (f.message.outgoing, f.message.unix_time_ns, f.message.arbitration_id, f.message.data)
        for f in iter_decoded(path, [m.TOPIC_CAN])
    ]
    # the preallocated outgoing message was copied, not referenced; each time the monotonic one on the wall clock
    assert frames == [(o, round(t * 1e9) + offset, i, d) for o, t, i, d in sent]
    events = [d.message for d in iter_decoded(path, [m.TOPIC_EVENTS])]
    assert [e.message for e in events] == [e.message for r in trace.rows for e in r[5]]
    # the configuration in the metadata rebuilds the same Config
    assert config_from_dict(json.loads(report.metadata[m.META_CONFIG]["json"])) == cfg
    assert report.metadata[m.META_VERSIONS]["mcap"]
    assert report.metadata[m.META_RECORDING]["dropped"] == "0"
    assert 0.1 < report.duration_s < 10.0


def test_log_time_is_the_controller_clock_on_the_wall_clock(tmp_path):
    path = tmp_path / "s.mcap"
    *_, sent, _ = record_session(path, max_s=0.3)
    offset = int(read_info(path).metadata[m.META_SESSION]["clock_offset_ns"])
    frames = list(iter_decoded(path, [m.TOPIC_CAN]))
    assert [d.log_time_ns for d in frames] == [round(t * 1e9) + offset for _, t, _, _ in sent]
    assert all(d.log_time_ns == d.message.unix_time_ns for d in frames)
    assert abs(offset - time.time_ns()) < 60e9  # simulated clock starts at 0: offset ~ now


def test_a_full_queue_drops_counts_and_records_the_drop_without_blocking(tmp_path):
    path = tmp_path / "d.mcap"
    cfg = load_config()
    rec = SessionRecorder(path, session_metadata(cfg), buffer_bytes=4096)
    _, _, _, trace, _, _ = record_session(tmp_path / "ref.mcap", max_s=0.5, frames=False)
    with rec:
        # the writer stops reading altogether: a write that waited for it would never return
        # (a mean time per call, asserted before, flaked on a busy machine: 61 us against 50)
        os.kill(rec._proc.pid, signal.SIGSTOP)
        try:
            for _ in range(20):
                for row in trace.rows:
                    rec.on_cycle(*row, timing=m.pb.CycleTiming())  # timing values are irrelevant here
        finally:
            os.kill(rec._proc.pid, signal.SIGCONT)
    calls = 20 * len(trace.rows)
    assert rec.dropped > 0 and rec.queued + rec.dropped == calls
    report = read_info(path)
    assert report.metadata[m.META_RECORDING]["dropped"] == str(rec.dropped)
    drops = [d.message for d in iter_decoded(path, [m.TOPIC_EVENTS]) if d.message.kind == "recorder_drop"]
    assert drops and "dropped" in drops[0].message
    totals = [int(e.message.split("(")[-1].split()[0]) for e in drops]
    assert totals[-1] == rec.dropped


_RECORDING_CONTROLLER = textwrap.dedent("""
    import os, sys, time
    sys.path.insert(0, {repo!r})
    from controller.config import load_config
    from controller.shell.loop import CycleLoop
    from drivers.pacing import DeadlineSleeper
    from controller.assembly import build_law
    from sim_backend.loopback import LoopbackExchange
    from logs.recorder import SessionRecorder, session_metadata
    cfg = load_config(overrides={{"task.path.laps": 5.0}})
    law = build_law(cfg)
    ex = LoopbackExchange(cfg, time.monotonic)
    rec = SessionRecorder({path!r}, session_metadata(cfg), chunk_size_bytes=8192, flush_interval_s=0.1)
    rec.start()
    writer = rec._proc
    print("WRITER", writer.pid, flush=True)

    class Progress:  # tells the test what it waits for, instead of the test guessing with sleeps
        calls, grown, writer_gone_at = 0, False, None
        def on_cycle(self, cycle, t, inputs, state, outputs, events, timing):
            self.calls += 1  # cycles run (the cycle index skips missed deadlines)
            if self.calls % 20:
                return
            if not self.grown and os.path.exists({path!r}) and os.path.getsize({path!r}) >= 60_000:
                self.grown = True
                print("GROWN", cycle, flush=True)
            if self.writer_gone_at is None and writer.poll() is not None:
                self.writer_gone_at = self.calls
                print("WRITER_GONE", cycle, flush=True)
            elif self.writer_gone_at is not None and self.calls == self.writer_gone_at + 100:
                print("STILL_CYCLING", cycle, flush=True)

    loop = CycleLoop(law, ex, cfg.period_s, 0.6, DeadlineSleeper(3e-4), time.monotonic, observers=(rec, Progress()))
    loop.run(law.initial_state(), 60.0)
""")


def _start_recording_controller(path: Path) -> tuple[subprocess.Popen, int, ProcessLines]:
    """A controller recording in real time, once its file has grown past 60 kB; its writer's pid; its output."""
    # stderr is shared with the writer process (it inherits it): the tests read what both said
    proc = subprocess.Popen(
        [sys.executable, "-c", _RECORDING_CONTROLLER.format(repo=str(REPO), path=str(path))],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    lines = ProcessLines(proc)
    try:
        writer_pid = int(
            lines.next_matching(lambda line: line.startswith("WRITER "), "the writer's pid").split()[1]
        )
        lines.next_matching(lambda line: line.startswith("GROWN "), "the recording growing past 60 kB")
    except AssertionError:
        proc.kill()
        proc.wait()
        proc.stdout.close()
        proc.stderr.close()
        raise
    return proc, writer_pid, lines


def test_sigkill_of_the_controller_still_leaves_a_complete_file(tmp_path):
    path = tmp_path / "killed.mcap"
    proc, writer_pid, _ = _start_recording_controller(path)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    proc.stdout.close()
    wait_for_exit(
        writer_pid, "the writer process ending after its controller"
    )  # it sees the end of its input
    said = proc.stderr.read()  # the writer's end of the pipe is closed now: this returns
    proc.stderr.close()
    assert "Traceback" not in said and "BrokenPipeError" not in said, said  # its reply had no reader
    report = read_info(path)
    assert report.complete and not report.problems
    assert report.message_counts[m.TOPIC_CYCLE] > 100
    assert "without END" in report.metadata[m.META_RECORDING]["ended"]


def test_sigkill_of_the_writer_leaves_a_readable_file_and_recover_completes_it(tmp_path, capsys):
    path = tmp_path / "killed.mcap"
    proc, writer_pid, lines = _start_recording_controller(path)
    try:
        os.kill(writer_pid, signal.SIGKILL)
        lines.next_matching(
            lambda line: line.startswith("WRITER_GONE "), "the controller noticing its writer gone"
        )
        lines.next_matching(
            lambda line: line.startswith("STILL_CYCLING "), "100 more cycles without the writer"
        )
        assert proc.poll() is None, "the controller must go on without its writer"
    finally:
        proc.kill()
        proc.wait()
        proc.stdout.close()
        proc.stderr.close()
    report = read_info(path)
    assert not report.complete
    assert any(p.startswith("truncated") for p in report.problems)
    assert report.chunks >= 2 and report.message_counts[m.TOPIC_CYCLE] > 100
    assert m.META_CONFIG in report.metadata  # written first, so it survives
    result = recover(path)
    assert result.output == tmp_path / "killed.recovered.mcap"
    assert result.messages_saved == report.messages
    fixed = read_info(result.output)
    assert fixed.complete and not fixed.problems
    assert fixed.message_counts == report.message_counts
    assert fixed.metadata[m.META_CONFIG] == report.metadata[m.META_CONFIG]
    # the mcap library's own indexed reader accepts the recovered file
    from mcap.reader import make_reader

    with open(result.output, "rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary is not None and summary.statistics.message_count == result.messages_saved
    # and the CLI says how many it saved
    assert main(["logs", "recover", str(path), "-o", str(tmp_path / "cli.mcap")]) == 0
    assert f"recovered {result.messages_saved} messages" in capsys.readouterr().out


@pytest.fixture(scope="module")
def session_bytes(tmp_path_factory) -> bytes:
    path = tmp_path_factory.mktemp("s") / "s.mcap"
    record_session(path, chunk_size_bytes=4096)
    return path.read_bytes()


@pytest.mark.parametrize("fraction", [0.0, 0.001, 0.3, 0.5, 0.77, 0.999])
def test_a_truncated_file_reads_what_is_there_without_raising(tmp_path, session_bytes, fraction):
    path = tmp_path / "t.mcap"
    path.write_bytes(session_bytes[: 8 + int(fraction * (len(session_bytes) - 8))])
    report = read_info(path)
    assert not report.complete and report.problems
    full = read_info_bytes(tmp_path, session_bytes)
    assert report.messages <= full.messages
    if fraction >= 0.5:
        assert report.message_counts[m.TOPIC_CYCLE] > 0.3 * full.message_counts[m.TOPIC_CYCLE]


def read_info_bytes(tmp_path: Path, data: bytes):
    p = tmp_path / "full.mcap"
    p.write_bytes(data)
    return read_info(p)


def _compressed_data_offset(data: bytes) -> int:
    """Where the compressed records of the middle chunk start (MCAP spec, Chunk record)."""
    import io

    from mcap.reader import make_reader

    index = sorted(
        make_reader(io.BytesIO(data)).get_summary().chunk_indexes, key=lambda c: c.chunk_start_offset
    )
    c = index[len(index) // 2]
    # opcode, record length, start and end time, uncompressed size, CRC, compression string, records length
    return c.chunk_start_offset + 1 + 8 + 8 + 8 + 8 + 4 + 4 + len(c.compression) + 8


def test_a_corrupted_chunk_is_skipped_and_the_rest_is_read(tmp_path, session_bytes):
    full = read_info_bytes(tmp_path, session_bytes)
    data = bytearray(session_bytes)
    mid = _compressed_data_offset(session_bytes) + 16
    data[mid : mid + 64] = bytes(b ^ 0xA5 for b in data[mid : mid + 64])  # inside a chunk's compressed data
    path = tmp_path / "c.mcap"
    path.write_bytes(data)
    report = read_info(path)
    assert report.damaged_chunks == 1
    assert report.complete  # the rest, up to the footer, was read
    assert 0.8 * full.messages < report.messages < full.messages
    assert any("damaged chunk" in p for p in report.problems)


def test_a_damaged_record_header_resumes_at_the_next_chunk(tmp_path, session_bytes):
    full = read_info_bytes(tmp_path, session_bytes)
    data = bytearray(session_bytes)
    # find a chunk record (opcode 0x06) past the first third, and destroy its header
    offsets = []
    pos = 8
    import struct

    while pos < len(data):
        op, length = struct.unpack_from("<BQ", data, pos)
        if op == 0x06 and pos > len(data) // 3:
            offsets.append(pos)
            break
        pos += 9 + length
    data[offsets[0] : offsets[0] + 9] = b"\xff" * 9
    path = tmp_path / "h.mcap"
    path.write_bytes(data)
    report = read_info(path)
    assert any("damaged record header" in p and "resumed" in p for p in report.problems)
    assert 0.7 * full.messages < report.messages < full.messages


def test_not_an_mcap_file_is_one_clear_error(tmp_path, capsys):
    path = tmp_path / "x.mcap"
    path.write_text("hello")
    with pytest.raises(LogFileError, match="not an MCAP file"):
        read_info(path)
    assert main(["logs", "info", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not an MCAP file" in err
    assert main(["logs", "info", str(tmp_path / "missing.mcap")]) == 2
    assert "cannot read" in capsys.readouterr().err


def test_logs_info_cli_lists_channels_counts_and_metadata(tmp_path, session_bytes, capsys):
    """A truncated file: what is there, what is wrong, and exit 1 (a damaged file is not a success)."""
    path = tmp_path / "i.mcap"
    path.write_bytes(session_bytes[: len(session_bytes) // 2])
    assert main(["logs", "info", str(path)]) == 1
    out = capsys.readouterr().out
    assert "truncated" in out and "/cycle" in out and "cheope.v1.Cycle" in out and "cheope.config.json" in out
    assert main(["logs", "info", "--json", str(path)]) == 1
    info = json.loads(capsys.readouterr().out)
    assert info["complete"] is False and info["channels"]["/cycle"]["count"] > 0


def test_logs_info_reads_a_finished_file_from_its_summary_alone(tmp_path, session_bytes, capsys, monkeypatch):
    """The same report as the walk through every chunk, without reading a chunk (the walk is
    made to fail); --check walks it and finds a chunk damaged under an intact summary."""
    import logs.reader

    path = tmp_path / "s.mcap"
    path.write_bytes(session_bytes)
    walked = info_dict(read_info(path))
    from logs.reader import read_info_from_summary

    # the same report, save that it says its chunks were not checked
    assert walked.pop("chunks_checked") is True
    walked_unchecked = {**walked, "chunks_checked": False}
    assert info_dict(read_info_from_summary(path)) == walked_unchecked

    def no_walk(*_a, **_k):
        raise AssertionError("logs info walked the chunks of a file with a summary")

    with monkeypatch.context() as mp:
        mp.setattr(logs.reader, "iter_messages", no_walk)
        assert main(["logs", "info", "--json", str(path)]) == 0
    assert json.loads(capsys.readouterr().out) == walked_unchecked
    data = bytearray(session_bytes)
    mid = _compressed_data_offset(session_bytes) + 16
    data[mid : mid + 64] = bytes(b ^ 0xA5 for b in data[mid : mid + 64])
    path.write_bytes(data)
    assert main(["logs", "info", str(path)]) == 0  # the summary is intact: nothing is read to doubt it
    # ... and it does not call the file sound: it says its chunks were not checked
    assert "chunks not checked (--check" in capsys.readouterr().out
    assert main(["logs", "info", "--check", str(path)]) == 1
    assert "damaged chunk" in capsys.readouterr().out


def test_a_recover_that_recovers_nothing_fails_and_leaves_no_file(tmp_path, session_bytes, capsys):
    path = tmp_path / "empty.mcap"
    path.write_bytes(session_bytes[:8] + b"\xff" * 100)  # the magic bytes, then nothing readable
    out = tmp_path / "out.mcap"
    assert main(["logs", "recover", str(path), "-o", str(out)]) == 1
    err = capsys.readouterr().err
    assert "nothing recovered" in err and err.count("\n") == 1
    assert not out.exists()


def test_session_files_get_timestamped_unique_names(tmp_path):
    p1, f1 = open_session_file(tmp_path / "a" / "b")
    p2, f2 = open_session_file(tmp_path / "a" / "b")
    f1.close(), f2.close()
    assert p1 != p2 and p1.parent == tmp_path / "a" / "b" and p1.name.startswith("cheope-")
    assert p1.suffix == p2.suffix == ".mcap"


def test_a_generic_protobuf_reader_decodes_every_can_frame_from_the_embedded_schema(tmp_path):
    """mcap + mcap-protobuf-support, no project code: the schema in the file is enough to get each
    frame's time, direction, id, data and flags."""
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    path = tmp_path / "g.mcap"
    *_, sent, _ = record_session(path, max_s=0.3)
    offset = int(read_info(path).metadata[m.META_SESSION]["clock_offset_ns"])
    with path.open("rb") as f:
        decoded = [
            (frame.outgoing, frame.unix_time_ns, frame.arbitration_id, frame.data, frame.is_extended_id)
            for schema, _, _, msg in make_reader(
                f, decoder_factories=[DecoderFactory()]
            ).iter_decoded_messages(topics=[m.TOPIC_CAN])
            for frame in msg.frames
            if schema is not None and schema.name == "cheope.v1.CanFrames"
        ]
    assert decoded == [(o, round(t * 1e9) + offset, i, d, False) for o, t, i, d in sent]


def test_rerun_reads_the_mcap_file_directly_and_decodes_the_protobuf_channels(tmp_path):
    from rerun.chunk import McapReader

    path = tmp_path / "r.mcap"
    record_session(path, max_s=0.5)
    store = McapReader(path).stream().collect()
    summary = store.summary()
    assert "cheope.v1.Cycle:message" in summary  # our schema, decoded by reflection
    assert "cheope.v1.CanFrames:message" in summary
    # each CAN frame a struct of its own fields (not an opaque blob): id and data per frame
    can_rows = [
        frame
        for chunk in store.stream()
        if chunk.entity_path == m.TOPIC_CAN and not chunk.is_static
        for row in chunk.to_record_batch().column("cheope.v1.CanFrames:message").to_pylist()
        for message in row
        for frame in message["frames"]
    ]
    ours = [d.message for d in iter_decoded(path, [m.TOPIC_CAN])]
    assert [(f["unix_time_ns"], f["arbitration_id"], f["data"], f["outgoing"]) for f in can_rows] == [
        (f.unix_time_ns, f.arbitration_id, f.data, f.outgoing) for f in ours
    ]
    assert "Transform3D:translation" in summary  # foxglove.FrameTransform -> Transform3D
    assert "TextLog:text" in summary  # foxglove.Log -> TextLog
    assert "cheope.config" in summary  # the metadata


def test_a_large_buffer_queues_every_cycle_and_frame(tmp_path):
    """Nothing dropped while the writer keeps up. The cost per call is printed, not asserted:
    timing belongs in `cheope bench` (observers_us), not in a test on a shared 2-core machine."""
    _, _, _, trace, _, _ = record_session(tmp_path / "ref.mcap", max_s=0.5, frames=False)
    rec = SessionRecorder(tmp_path / "p.mcap", session_metadata(load_config()), buffer_bytes=64 << 20)
    timing = m.pb.CycleTiming()
    msg = can.Message(arbitration_id=0x201, data=bytearray(8), is_extended_id=False)
    with rec:
        per_call = []
        for row in trace.rows * 3:
            t0 = time.perf_counter_ns()
            rec.on_cycle(*row, timing=timing)
            rec.on_frame(True, 0.0, msg)
            per_call.append(time.perf_counter_ns() - t0)
    per_call.sort()
    median_us = per_call[len(per_call) // 2] / 1000
    print(
        f"recorder on_cycle + on_frame: median {median_us:.1f} us, p99 "
        f"{per_call[int(0.99 * len(per_call))] / 1000:.1f} us over {len(per_call)} calls"
    )
    assert rec.dropped == 0 and rec.queued == len(per_call) * 2  # a cycle and a frame per call


def test_a_recording_that_cannot_be_created_is_one_clear_error_before_the_run(tmp_path):
    from logs.recorder import RecordingError

    path = tmp_path / "no-such-dir" / "s.mcap"
    rec = SessionRecorder(path, session_metadata(load_config()))
    with pytest.raises(
        RecordingError, match=r"cannot create the recording .*no-such-dir/s\.mcap: No such file"
    ):
        rec.start()
    assert rec._proc is None  # the writer process is gone


def test_the_writer_process_ends_with_its_recorder(tmp_path):
    rec = SessionRecorder(tmp_path / "s.mcap", session_metadata(load_config()))
    rec.start()
    proc = rec._proc
    rec.close()
    assert proc.poll() == 0 and rec.error == "" and rec.written == 0
    assert read_info(tmp_path / "s.mcap").complete


def test_a_full_disk_is_named_as_such_not_as_the_pipe_it_broke(tmp_path):
    """The writer that cannot write (here its file size limit, as a full disk: ENOSPC or EFBIG) says
    why before it stops reading: the recorder's error, which the run summary shows, names the
    write that failed, not "stopped reading: Broken pipe"."""
    import resource

    _, _, _, trace, _, _ = record_session(tmp_path / "ref.mcap", max_s=0.5, frames=False)
    # chunks of 4 kB: several are whole inside the 32 kB, however fast the messages come. The
    # default closes a chunk every 2 s, and a first chunk larger than the 32 kB leaves nothing
    # readable: a CI rehearsal met 0 messages in its 32 kB (not met again in 10 runs, alone or
    # beside two CPU hogs)
    rec = SessionRecorder(
        tmp_path / "s.mcap", session_metadata(load_config()), buffer_bytes=4096, chunk_size_bytes=4096
    )
    rec.start()
    resource.prlimit(rec._proc.pid, resource.RLIMIT_FSIZE, (32_768, 32_768))  # Python ignores SIGXFSZ
    wait_until(
        lambda: [rec.on_cycle(*row, timing=m.pb.CycleTiming()) for row in trace.rows] and rec.error,
        "the recorder's error",
    )
    rec.close()
    assert "File too large" in rec.error and "Broken pipe" not in rec.error, rec.error
    assert read_info(tmp_path / "s.mcap").messages > 0  # what was written before stays readable


def test_a_writer_that_takes_nothing_while_items_drop_is_gone_by_the_policy(tmp_path, monkeypatch):
    """An outside tester stopped the writer 30 s (a hung disk): 40 % of the run was dropped, no
    error, exit 0, and a writer stopped at the end held the exit 259 s. Now a writer that takes
    no data while the backlog overflows for ``WRITER_STALL_S`` is gone: the policy is called once,
    the items in the backlog count as lost, and the close does not wait its full timeout."""
    from logs import recorder

    monkeypatch.setattr(recorder, "WRITER_STALL_S", 0.3)
    _, _, _, trace, _, _ = record_session(tmp_path / "ref.mcap", max_s=0.5, frames=False)
    failures: list[str] = []
    rec = SessionRecorder(
        tmp_path / "s.mcap", session_metadata(load_config()), buffer_bytes=4096, on_failure=failures.append
    )
    rec.start()
    pid = rec._proc.pid
    os.kill(pid, signal.SIGSTOP)
    try:
        rows = itertools.cycle(trace.rows)
        wait_until(
            lambda: rec.on_cycle(*next(rows), timing=m.pb.CycleTiming()) or failures, "the policy's call"
        )
        assert failures == [rec.error] and "took no data for 0.3 s while the backlog was full" in rec.error
        assert rec.dropped > 0 and rec.first_lost_cycle is not None
        for _ in range(50):  # the rest is lost at once, the policy not called again
            rec.on_cycle(*next(rows), timing=m.pb.CycleTiming())
        assert len(failures) == 1
        closing = threading.Thread(target=rec.close, name="close-with-a-stalled-writer", daemon=True)
        closing.start()
        closing.join(GENEROUS_S)  # its answer is waited for STALLED_WRITER_ANSWER_S, not 120 s
        assert not closing.is_alive(), f"close() still waiting for a stalled writer after {GENEROUS_S} s"
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGCONT)
    assert rec.queued + rec.dropped == rec._cycle_calls  # every item handed over or counted as lost


def test_a_writer_that_stops_reading_blocks_neither_the_loop_nor_the_exit(tmp_path, monkeypatch):
    from logs import recorder

    monkeypatch.setattr(recorder, "WRITER_FINISH_TIMEOUT_S", 1.0)
    _, _, _, trace, _, _ = record_session(tmp_path / "ref.mcap", max_s=0.5, frames=False)
    rec = SessionRecorder(tmp_path / "s.mcap", session_metadata(load_config()), buffer_bytes=4096)
    rec.start()
    pid = rec._proc.pid
    os.kill(pid, signal.SIGSTOP)  # a writer stuck on a dead disk
    try:
        for _ in range(5):  # returns at all: a write that waited for the stopped writer never would
            for row in trace.rows:
                rec.on_cycle(*row, timing=m.pb.CycleTiming())
        assert rec.dropped > 0
        closing = threading.Thread(target=rec.close, name="close-with-a-stopped-writer", daemon=True)
        closing.start()
        closing.join(GENEROUS_S)  # returns at all: a close that waited for the stopped writer never would
        assert not closing.is_alive(), f"close() still waiting for a stopped writer after {GENEROUS_S} s"
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGCONT)
    assert "took no data" in rec.error or "timed out" in rec.error
    assert rec._proc is None
    assert rec.written is None  # it never answered: unknown, not 0 (the file holds what it wrote)


def _writer_once_driving(run: ControllerOnTheBus) -> int:
    """The pid of the recording's writer of the controller ``run``, once its drive 1 moves."""
    writer: int = wait_until(
        lambda: child_running(run.process.pid, "logs.session_writer"), "the recording's writer process"
    )
    wait_until_drive_1_moves(run.bus, run.process)
    return writer


def _summary_at_its_end(proc: subprocess.Popen[str], lines: ProcessLines, returncode: int) -> dict:
    """The JSON summary of the controller ``proc``, once it ended with ``returncode`` and its output
    with it."""
    wait_for_exit(proc.pid, "the controller ending")
    proc.wait()
    with pytest.raises(AssertionError, match="ended its output"):
        lines.next_matching(lambda line: False, "the rest of the output")
    assert proc.returncode == returncode, lines.lines[-20:]
    summary: dict = json.loads(next(line for line in lines.lines if line.startswith("{")))
    return summary


@pytest.mark.integration
@pytest.mark.parametrize("policy", ["stop", "warn"])
def test_a_killed_writer_ends_the_run_by_the_recording_policy(tmp_path, policy):
    """recording.on_failure: "stop" ends the run through STOPPING (DONE, exit 3: the recording was
    lost), "warn" drives on unrecorded until told to stop (then DONE, exit 3); the summary names
    what was lost."""
    sets = run_sets(
        tmp_path,
        "--set",
        f'recording.on_failure="{policy}"',
        "--set",
        "loop.max_missing_s=0.25",
        "--set",
        "safety.sensor_stale_s=0.25",
    )
    with controller_beside_simulator(sets, stderr=subprocess.STDOUT) as run:
        proc = run.process
        lines = ProcessLines(proc)
        writer = _writer_once_driving(run)
        os.kill(writer, signal.SIGKILL)
        lines.next_matching(lambda line: "recording lost" in line and policy in line, "the policy's warning")
        if policy == "warn":
            wait_until_drive_1_moves(run.bus, proc)  # still driving, unrecorded
            proc.send_signal(signal.SIGTERM)
        summary = _summary_at_its_end(proc, lines, returncode=3)
    assert summary["final_mode"] == "DONE", summary["fault_reason"]
    rec = summary["recording"]
    assert rec["on_failure"] == policy and "stopped reading" in rec["error"]
    assert rec["lost"].startswith("every cycle and frame from cycle ") and rec["dropped"] > 0
    assert not any("Traceback" in line for line in lines.lines)


@pytest.mark.integration
def test_a_sigterm_to_the_writer_loses_nothing(tmp_path):
    """A SIGTERM that reaches the writer too (sent to the controller's process group: GNU timeout,
    `kill -TERM -- -PGID`, systemd's default KillMode) leaves it writing until the controller,
    stopped by the same signal, closes the pipe: DONE, exit 0, the recording whole. It ended the
    writer at once, and the run ended "DONE, but the recording was lost" (exit 3)."""
    with controller_beside_simulator(run_sets(tmp_path), stderr=subprocess.STDOUT) as run:
        proc = run.process
        lines = ProcessLines(proc)
        writer = _writer_once_driving(run)
        os.kill(writer, signal.SIGTERM)
        wait_until_drive_1_moves(run.bus, proc)  # still driving, recorded
        assert child_running(proc.pid, "logs.session_writer") == writer
        proc.send_signal(signal.SIGTERM)
        summary = _summary_at_its_end(proc, lines, returncode=0)
    assert summary["final_mode"] == "DONE", summary["fault_reason"]
    rec = summary["recording"]
    assert not rec.get("error") and not rec.get("lost") and rec["dropped"] == 0, rec
    assert rec["written"] > 0 and read_info(Path(rec["path"])).messages >= rec["written"]


def test_logs_recover_says_what_it_saved_as_json(tmp_path, capsys):
    path = tmp_path / "r.mcap"
    record_session(path, max_s=0.3)
    out = tmp_path / "copy.mcap"
    assert main(["logs", "recover", str(path), "-o", str(out), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["output"] == str(out) and result["messages_saved"] == read_info(out).messages > 0
    assert result["problems"] == []
