"""A long session: files split by size and duration, each standing alone, retention, the free-space guard."""

from __future__ import annotations

import contextlib
import json
import os
import random
import re
import time
from pathlib import Path

import pytest
from test_recording import record_session

from controller.cli import main
from controller.config import Config, ConfigError, load_config
from controller.messages import cheope_pb2 as pb
from logs import messages as m
from logs.cycle_encoding import cycle_values
from logs.keyframe import ENCODING, decode_state, encode_state
from logs.reader import iter_decoded, iter_messages, read_head, read_info
from logs.recorder import session_metadata
from logs.recovery import recover
from logs.replay_verify import verify
from logs.session_list import list_sessions
from logs.session_writer import CYCLE, KEYFRAME, FileLimits, SessionWriter, enforce_retention

QUARTER_LAP = {"task.path.laps": 0.25, "task.path.ramp_s": 0.2}
CONTOUR = {"task.kind": "contour", "task.contour.approach_clearance_m": 0.003}


def split_session(tmp_path: Path, overrides=QUARTER_LAP, max_s: float = 10.0, duration_s: float = 0.4):
    """A simulated session split by ``recording.max_file_duration_s``; its files in session order."""
    tmp_path.mkdir(parents=True, exist_ok=True)
    first = tmp_path / "cheope-20260101-000000.mcap"
    _, _, stats, trace, _, rec = record_session(
        first,
        overrides,
        max_s=max_s,
        frames=False,
        chunk_size_bytes=8192,
        limits=FileLimits(max_file_duration_s=duration_s),
    )
    assert rec.error == "" and rec.dropped == 0
    return rec.files, stats, trace


@pytest.mark.parametrize("overrides", [QUARTER_LAP, CONTOUR], ids=["path", "contour"])
def test_a_session_split_in_files_verifies_file_by_file_and_as_a_whole(tmp_path, overrides, capsys):
    files, stats, _ = split_session(tmp_path, overrides, max_s=2.0 if overrides is CONTOUR else 10.0)
    assert len(files) >= 3 and all(f.exists() for f in files)
    alone = [verify(f) for f in files]
    for k, (f, r) in enumerate(zip(files, alone, strict=True)):
        assert r.ok, (f.name, r.summary())
        # the first from the law's initial state, every other one from its own keyframe
        assert (r.started_from == "") == (k == 0) and (k == 0 or f.name in r.started_from)
        assert r.continues_in == (files[k + 1].name if k + 1 < len(files) else "")
    assert sum(r.cycles_checked for r in alone) == stats.cycles
    # the whole session, in any order given: across the boundaries, each keyframe checked
    shuffled = random.Random(1).sample(files, len(files))
    whole = verify(shuffled)
    assert whole.ok and whole.cycles_checked == stats.cycles and whole.files == files, whole.summary()
    assert main(["replay", *map(str, shuffled), "--verify"]) == 0
    assert capsys.readouterr().out.startswith(
        f"OK: {stats.cycles} cycle(s) reproduced bit for bit in {len(files)} files"
    )


def test_the_files_of_a_session_are_linked_and_each_carries_what_a_reader_needs(tmp_path):
    files, _, _ = split_session(tmp_path)
    heads = [read_head(f).metadata for f in files]
    ids = {h[m.META_FILE]["session_id"] for h in heads}
    assert len(ids) == 1 and len(ids.pop()) == 32
    assert [h[m.META_FILE]["sequence"] for h in heads] == [str(k) for k in range(1, len(files) + 1)]
    assert [h[m.META_FILE]["previous"] for h in heads] == ["", *(f.name for f in files[:-1])]
    for f, h in zip(files, heads, strict=True):
        assert m.META_CONFIG in h and m.META_SESSION in h  # each file rebuilds the law alone
        info = read_info(f)
        assert info.complete and not info.problems
        assert (info.message_counts[m.TOPIC_KEYFRAME] == 1) == (f != files[0])
    assert [read_info(f).metadata[m.META_RECORDING].get("next", "") for f in files] == [
        *(f.name for f in files[1:]),
        "",
    ]


def test_logs_list_shows_the_session_and_its_files(tmp_path, capsys):
    files, _, _ = split_session(tmp_path)
    (tmp_path / "notes.mcap").write_bytes(b"not a recording")
    listing = list_sessions(tmp_path)
    assert len(listing.sessions) == 1 and [f.path for f in listing.sessions[0].files] == files
    assert all(f.finished and f.duration_s is not None for f in listing.sessions[0].files)
    assert main(["logs", "list", str(tmp_path)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[1].startswith("session ") and f"{len(files)} file(s)" in out[1]
    assert [line.split()[1] for line in out[2 : 2 + len(files)]] == [f.name for f in files]
    assert out[-1].startswith("not a recording: notes.mcap")
    assert main(["logs", "list", "--json", str(tmp_path)]) == 0
    assert json.loads(capsys.readouterr().out)["sessions"][0]["missing_sequences"] == []
    assert main(["logs", "list", str(tmp_path / "nope")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "does not exist" in err


def test_a_truncated_file_of_a_session_says_how_much_was_verified_and_exits_non_zero(tmp_path, capsys):
    files, stats, _ = split_session(tmp_path)
    middle = files[1]
    data = middle.read_bytes()
    middle.write_bytes(data[: len(data) * 2 // 3])
    alone = verify(middle)
    assert not alone.ok and alone.divergence is None and alone.cycles_checked > 0
    assert main(["replay", str(middle), "--verify"]) == 3
    out = capsys.readouterr().out
    assert (
        out.startswith(f"PARTLY VERIFIED: the {alone.cycles_checked} readable cycle(s)")
        and "truncated" in out
    )
    # the whole session: up to the cut, then again from the next file's keyframe
    whole = verify(files)
    assert not whole.ok and whole.divergence is None
    assert (
        stats.cycles - whole.cycles_checked == stats.cycles - whole.cycles_recorded > 0
    )  # the cut-off cycles
    assert files[2].name in " ".join(whole.resumed)
    assert main(["replay", *map(str, files), "--verify"]) == 3


def test_files_of_different_sessions_or_with_a_gap_are_refused_with_one_line(tmp_path, capsys):
    a, _, _ = split_session(tmp_path / "a")
    b, _, _ = split_session(tmp_path / "b")
    assert main(["replay", str(a[0]), str(b[1]), "--verify"]) == 2
    assert "different sessions" in capsys.readouterr().err
    assert main(["replay", str(a[0]), str(a[2]), "--verify"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "file 2 is missing" in err
    assert main(["replay", str(a[1]), str(a[2]), "--rerun"]) == 2
    assert "take one file" in capsys.readouterr().err


def _copy_with_keyframe(src: Path, dst: Path, state: bytes) -> None:
    """``src`` message for message, metadata and all, with another state in its keyframe."""
    from mcap.writer import Writer

    from logs.reader import ReadReport, iter_messages

    report = read_info(src)
    r = ReadReport(src)
    with open(dst, "wb") as fh:
        w = Writer(fh)
        w.start()
        ids: dict[int, int] = {}
        for ch, msg in iter_messages(src, r):
            if ch.id not in ids:
                sc = r.schemas[ch.schema_id]
                ids[ch.id] = w.register_channel(
                    ch.topic, ch.message_encoding, w.register_schema(sc.name, sc.encoding, sc.data)
                )
            data = msg.data
            if ch.topic == m.TOPIC_KEYFRAME:
                kf = pb.Keyframe.FromString(data)
                kf.state = state
                data = kf.SerializeToString()
            w.add_message(ids[ch.id], msg.log_time, data, msg.publish_time, msg.sequence)
        for name, meta in report.metadata.items():
            w.add_metadata(name, meta)
        w.finish()


def test_a_keyframe_that_disagrees_with_the_replayed_state_is_a_divergence(tmp_path):
    import dataclasses

    files, _, _ = split_session(tmp_path / "s")
    kf = next(d.message for d in iter_decoded(files[1], [m.TOPIC_KEYFRAME]))
    state = decode_state(kf.state)
    assert encode_state(state) == kf.state  # the codec is exact: a state comes back as it was
    forged = tmp_path / files[1].name
    _copy_with_keyframe(
        files[1], forged, encode_state(dataclasses.replace(state, late_streak=state.late_streak + 1))
    )
    whole = verify([files[0], forged])
    assert whole.divergence is not None and whole.divergence.field == f"the keyframe of {forged.name}"
    assert whole.cycles_checked == verify(files[0]).cycles_checked and not whole.ok


def test_the_writer_asks_for_a_keyframe_past_the_size_limit_and_rotates_on_it(tmp_path):
    """The size limit is the writer's: it asks, goes on writing until the state comes, then rotates."""
    _, _, _, trace, _, _ = record_session(tmp_path / "ref.mcap", max_s=0.5, frames=False)
    cfg = load_config()
    asked: list[dict] = []
    first = tmp_path / "cheope-20260101-000000.mcap"
    w = SessionWriter(_writer_settings(first, cfg, max_file_bytes=8000), lambda **f: asked.append(f))
    body = cycle_values(0, 0.0, trace.rows[0][2], trace.rows[0][3], trace.rows[0][4], _Timing())
    k = 0
    while not asked:
        w.write((CYCLE, 0, [], k, k * 0.0025, k * 0.0025, k, body, (), None, None))
        k += 1
        assert k < 1000, "the writer never asked for a keyframe"
    assert asked == [{"keyframe": 2}] and w.files == [str(first)]
    w.write((CYCLE, 0, [], k, k * 0.0025, k * 0.0025, k, body, (), None, None))  # the file goes on meanwhile
    w.write((KEYFRAME, 0, k, k * 0.0025, k * 0.0025, k, ENCODING, encode_state(trace.rows[0][3]), ""))
    assert asked[-1] == {"file": str(tmp_path / "cheope-20260101-000000.002.mcap")} and len(w.files) == 2
    w.finish(k + 1, 0)
    assert read_info(first).complete and read_info(w.files[1]).complete
    assert read_info(first).message_counts[m.TOPIC_CYCLE] == k + 1


class _Timing:
    wake_error_s = 0.0
    step_s = 0.0


def _writer_settings(path: Path, cfg: Config, **extra: object) -> dict[str, object]:
    """A SessionWriter's SETUP settings for ``path``: small chunks, one session."""
    return {
        "path": str(path),
        "metadata": session_metadata(cfg),
        "clock_offset_ns": 0,
        "chunk_size_bytes": 1024,
        "flush_interval_s": 0.5,
        "compression": "zstd",
        "session_id": "s" * 32,
        **extra,
    }


def test_a_cycle_whose_values_do_not_fit_its_message_stops_the_recording_with_the_file_whole(tmp_path):
    """The writer builds each cycle's Protobuf from the loop's values: values that do not fit (a
    plug-in's setpoint of text) stop the recording with the reason, told to the controller and on
    /events, and the file is complete up to the cycle before."""
    _, _, _, trace, _, _ = record_session(tmp_path / "ref.mcap", max_s=0.2, frames=False)
    path = tmp_path / "cheope-20260101-000000.mcap"
    told: list[dict] = []
    w = SessionWriter(_writer_settings(path, load_config()), lambda **f: told.append(f))
    good = cycle_values(0, 0.0, trace.rows[0][2], trace.rows[0][3], trace.rows[0][4], _Timing())
    for k in range(3):
        w.write((CYCLE, 0, [], k, k * 0.0025, k * 0.0025, k, good, (), None, None))
    bad = (*good[:6], ("not", "numbers", "!"), *good[7:])  # the setpoint's position
    w.write((CYCLE, 0, [], 3, 0.0075, 0.0075, 3, bad, (), None, None))
    assert w.stopped.startswith("cycle 3 cannot be recorded (TypeError:") and not w.error
    assert told == [{"stopped": w.stopped}]
    w.finish(4, 0)
    info = read_info(path)
    assert info.complete and info.message_counts[m.TOPIC_CYCLE] == 3
    assert [d.message.kind for d in iter_decoded(path, [m.TOPIC_EVENTS])] == ["recording_stopped"]


def test_retention_deletes_the_oldest_recordings_first_never_an_open_or_a_foreign_file(tmp_path):
    now = time.time()
    names = [f"cheope-20260101-00000{k}.mcap" for k in range(5)]
    for k, name in enumerate(names):
        p = tmp_path / name
        p.write_bytes(b"x" * 1000)
        os.utime(p, (now - 10_000 + k, now - 10_000 + k))
    foreign = tmp_path / "my-notes.mcap"
    foreign.write_bytes(b"x" * 5000)
    os.utime(foreign, (now - 20_000, now - 20_000))
    recent = tmp_path / "cheope-20260101-000009.002.mcap"  # another controller's open file
    recent.write_bytes(b"x" * 1000)
    open_file = tmp_path / names[0]  # ours, open: the oldest, still kept
    deleted = enforce_retention(str(tmp_path), 3000, {str(open_file)}, now=now)
    assert [Path(p).name for p, _ in deleted] == names[1:4]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        [names[0], names[4], foreign.name, recent.name]
    )


def test_below_the_free_space_limit_the_recording_stops_cleanly_and_says_why(tmp_path):
    path = tmp_path / "s.mcap"
    failures: list[str] = []
    # more free space required than any disk has: the guard trips at the first chunk
    _, _, _, _, _, rec = record_session(
        path, chunk_size_bytes=1024, on_failure=failures.append, limits=FileLimits(min_free_bytes=1 << 62)
    )
    assert "below recording.min_free_space_mb" in rec.error
    assert rec.written == read_info(path).messages > 0  # the writer's last answer reached the recorder
    assert failures in ([], [rec.error])  # called when the loop wrote after the writer stopped
    info = read_info(path)
    assert info.complete and not info.problems  # closed cleanly while it could be
    assert "below recording.min_free_space_mb" in info.metadata[m.META_RECORDING]["stopped"]
    # the writer stopped reading, so no END came: that is not a controller that died without one
    assert "ended" not in info.metadata[m.META_RECORDING]
    events = [d.message for d in iter_decoded(path, [m.TOPIC_EVENTS])]
    assert events[-1].kind == "recording_stopped" and "free space" in events[-1].message
    # the recorder's own event, not the law's: what was recorded replays bit-exactly (44dbcbc
    # reported a divergence at the stop's cycle)
    result = verify(path)
    assert result.divergence is None and result.cycles_checked > 0, result.divergence


def test_a_recovered_files_gap_is_named_as_lost_with_the_damaged_original(tmp_path):
    path = tmp_path / "s.mcap"
    record_session(
        path, QUARTER_LAP, frames=False, chunk_size_bytes=4096
    )  # many chunks: one damaged mid-file
    data = bytearray(path.read_bytes())
    mid = len(data) // 2
    data[mid : mid + 64] = bytes(b ^ 0xA5 for b in data[mid : mid + 64])
    damaged = tmp_path / "damaged.mcap"
    damaged.write_bytes(data)
    out = recover(damaged).output
    result = verify(out)
    assert not result.ok and result.divergence is None
    gap = next(p for p in result.problems if "before cycle" in p)
    assert "lost with the damaged part of" in gap and "dropped by the recorder" not in gap


def test_a_recovered_file_lists_under_its_session(tmp_path):
    """``logs list`` reads each file's head: a recovered file carries its session's metadata there
    too, so it lists beside the cut original, not as a session of its own ("file:...", started ?)."""
    recorded = Path(__file__).resolve().parents[1] / "data" / "contour_contact.mcap"
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(recorded.read_bytes()[: recorded.stat().st_size * 3 // 4])
    out = recover(cut).output
    assert read_info(out).chunks > 1  # the metadata found at the end is written after the first chunk
    (session,) = list_sessions(tmp_path).sessions
    assert sorted(f.path for f in session.files) == sorted([cut, out])
    assert not session.session_id.startswith("file:") and session.started_utc and session.task
    assert read_info(out).metadata[m.META_SESSION] == read_head(cut).metadata[m.META_SESSION]


def test_rotation_settings_are_validated_with_the_key_and_the_value():
    with pytest.raises(
        ConfigError, match=r"recording.max_file_size_mb = 0.1: must be 0 \(no limit\) or at least"
    ):
        load_config(overrides={"recording.max_file_size_mb": 0.1})
    with pytest.raises(ConfigError, match=re.escape("recording.max_file_duration_s = 0.5")):
        load_config(overrides={"recording.max_file_duration_s": 0.5})
    with pytest.raises(ConfigError, match=re.escape("recording.keep_total_size_gb = 0.1")):
        load_config(overrides={"recording.keep_total_size_gb": 0.1})
    with pytest.raises(ConfigError, match=re.escape("recording.min_free_space_mb")):
        load_config(overrides={"recording.min_free_space_mb": -1.0})
    r = load_config().recording
    assert (r.max_file_size_mb, r.max_file_duration_s, r.keep_total_size_gb, r.min_free_space_mb) == (
        256.0,
        3600.0,
        20.0,
        1024.0,
    )


def _with_packed_batches(src: Path, dst: Path) -> int:
    """``src`` as the recorder wrote it before CanFrames: its /can messages as CanFrameBatch (packed by
    column, tests/can_frame_batch_packing.py), everything else as it is. Returns the batches written."""
    from can_frame_batch_packing import pack_frames
    from mcap.reader import make_reader
    from mcap.writer import Writer
    from mcap_protobuf.schema import register_schema

    offset = int(read_info(src).metadata[m.META_SESSION]["clock_offset_ns"])
    batches = 0
    with src.open("rb") as f, dst.open("wb") as out:
        reader = make_reader(f)
        w = Writer(out)
        w.start()
        channels = {}
        for schema, channel, msg in reader.iter_messages():
            if channel.id not in channels:
                if channel.topic == m.TOPIC_CAN:
                    sid = register_schema(w, pb.CanFrameBatch)
                else:
                    sid = w.register_schema(schema.name, schema.encoding, schema.data)
                channels[channel.id] = w.register_channel(channel.topic, channel.message_encoding, sid)
            data = msg.data
            if channel.topic == m.TOPIC_CAN:
                frames = pb.CanFrames.FromString(data).frames
                data = pb.CanFrameBatch(
                    frames=pack_frames(
                        [
                            (
                                x.outgoing,
                                (x.unix_time_ns - offset) / 1e9,
                                x.arbitration_id,
                                x.data,
                                x.is_fd,
                                x.bitrate_switch,
                                x.is_error_frame,
                            )
                            for x in frames
                        ]
                    )
                ).SerializeToString()
                batches += 1
            w.add_message(channels[channel.id], msg.log_time, data, msg.publish_time, msg.sequence)
        for record in reader.iter_metadata():
            w.add_metadata(record.name, record.metadata)
        w.finish()
    return batches


def test_an_older_file_with_packed_batches_reads_frame_by_frame(tmp_path):
    """A recording as the recorder wrote it before CanFrames (a CanFrameBatch per cycle, frames packed by
    column): each batch reads as its frames at the times they had, the first at the batch's log time."""
    today = tmp_path / "today.mcap"
    record_session(today, max_s=0.3)
    old = tmp_path / "packed.mcap"
    assert _with_packed_batches(today, old) > 50
    assert {s.name for s in read_info(old).schemas.values()} >= {"cheope.v1.CanFrameBatch"}
    assert [(d.log_time_ns, d.message) for d in iter_decoded(old, [m.TOPIC_CAN])] == [
        (d.log_time_ns, d.message) for d in iter_decoded(today, [m.TOPIC_CAN])
    ]


def test_an_older_file_with_a_message_per_frame_reads_as_todays_format_does(tmp_path):
    """tests/data/frames_one_message_each.mcap was written before the frames were batched (one
    cheope.v1.CanFrame per frame): it reads and verifies as before, and the same session written
    today gives the reader the same frames with the same times, and the same cycles."""
    from tools.bench_recording_size import main as rewrite

    old = Path(__file__).resolve().parents[1] / "data" / "frames_one_message_each.mcap"
    assert read_info(old).schemas and any(
        s.name == "cheope.v1.CanFrame" for s in read_info(old).schemas.values()
    )
    assert verify(old).ok
    new = tmp_path / "batched.mcap"
    rewrite(old, new)
    assert {s.name for s in read_info(new).schemas.values()} >= {"cheope.v1.CanFrames"}
    offset = int(read_info(old).metadata[m.META_SESSION]["clock_offset_ns"])

    def content(path):
        return [
            (d.topic, d.log_time_ns, d.message.SerializeToString())
            for d in iter_decoded(path, [m.TOPIC_CAN, m.TOPIC_CYCLE])
        ]

    frames = [d for d in iter_decoded(old, [m.TOPIC_CAN])]
    as_written = [
        pb.CanFrame.FromString(msg.data) for ch, msg in iter_messages(old) if ch.topic == m.TOPIC_CAN
    ]
    assert len(frames) == 206 and [(d.log_time_ns, d.message.unix_time_ns) for d in frames] == [
        (int(f.monotonic_s * 1e9) + offset,) * 2 for f in as_written
    ]
    assert content(new) == content(old)

    def can_messages(path):
        return sum(ch.topic == m.TOPIC_CAN for ch, _ in iter_messages(path))

    # a message a cycle, not a frame: the file's size is the bench's (docs/reference/can-frames.md);
    # at 206 frames it is mostly schemas, and one more field in them outweighed the records saved
    assert can_messages(old) == 206 and can_messages(new) == 103  # two frames a cycle in this session


def test_a_keyframe_request_already_answered_does_not_split_the_file_twice(tmp_path):
    """Both limits at once: the duration's keyframe went out while the writer asked for the same
    file because of the size; the stale request must not start a nearly empty file after it."""
    from logs.recorder import SessionRecorder

    rec = SessionRecorder(tmp_path / "s.mcap", {})
    rec._note({"keyframe": 2})
    assert rec._keyframe_wanted
    rec._keyframe_wanted, rec._keyframes_sent = False, 1  # the keyframe for file 2 went out
    rec._note({"keyframe": 2})
    assert not rec._keyframe_wanted
    rec._note({"keyframe": 3})
    assert rec._keyframe_wanted


def test_a_record_the_writer_cannot_read_stops_the_recording_with_the_file_whole(tmp_path):
    """Bytes that do not unpickle in the writer's process (a value of a class it cannot import, or
    no pickle at all) stop the recording with the reason, and the cycles before are on file."""
    import io
    import json
    import signal
    import struct

    from logs.session_writer import SETUP, pack_record, serve

    _, _, _, trace, _, _ = record_session(tmp_path / "ref.mcap", max_s=0.2, frames=False)
    path = tmp_path / "cheope-20260101-000000.mcap"
    settings = _writer_settings(path, load_config())
    values = cycle_values(0, 0.0, trace.rows[0][2], trace.rows[0][3], trace.rows[0][4], _Timing())
    read_fd, write_fd = os.pipe()
    records = [pack_record((SETUP, settings))]
    records += [
        pack_record((CYCLE, 0, [], k, k * 0.0025, k * 0.0025, k, values, (), None, None)) for k in range(2)
    ]
    records.append(struct.pack("<I", 5) + b"\x80\x05xyz")  # no pickle
    os.write(write_fd, b"".join(records))
    os.close(write_fd)
    out = io.StringIO()
    handlers = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    try:
        serve(read_fd, out)  # sets the writer process's own handlers of SIGINT and SIGTERM
    finally:
        signal.signal(signal.SIGINT, handlers[0])
        signal.signal(signal.SIGTERM, handlers[1])
        with contextlib.suppress(OSError):
            os.close(read_fd)
    replies = [json.loads(line) for line in out.getvalue().splitlines()]
    stopped = [r["stopped"] for r in replies if "stopped" in r]
    assert len(stopped) == 1 and stopped[0].startswith("a record of 5 bytes could not be read (")
    info = read_info(path)
    assert info.complete and info.message_counts[m.TOPIC_CYCLE] == 2


def test_the_retention_deletes_a_sessions_own_older_files_never_the_open_one(tmp_path, monkeypatch):
    """A long session (a service's, in hourly files) is held to recording.keep_total_size_gb too:
    every file of the session was kept, and it grew until min_free_space_mb stopped it."""
    import logs.session_writer as session_writer

    files, _, _ = split_session(tmp_path / "session")
    writer = session_writer.SessionWriter(
        {
            "path": str(tmp_path / "session" / "cheope-20260101-000100.mcap"),  # a new file beside them
            "clock_offset_ns": 0,
            "chunk_size_bytes": 8192,
            "flush_interval_s": 1.0,
            "compression": "none",
            "metadata": {},
        }
    )
    writer.files = [str(f) for f in files] + [writer.path]  # the session so far, the open file last
    writer.limits = FileLimits(keep_total_bytes=1)
    monkeypatch.setattr(session_writer, "OPEN_FILE_AGE_S", 0.0)  # in a real session they are minutes old
    writer._retain()
    assert sorted(writer.deleted) == sorted(str(f) for f in files) and not any(f.exists() for f in files)
    assert Path(writer.path).exists()
    assert writer.files == [writer.path]  # the run's summary lists the files still on disk
    writer.finish(None, 0)


def test_a_file_removed_while_it_is_written_stops_the_recording_and_says_so(tmp_path):
    """Its directory deleted mid-run: the run ended DONE and exit 0, naming a file that was gone."""
    import logs.session_writer as session_writer

    said: list[dict[str, object]] = []
    writer = session_writer.SessionWriter(
        {
            "path": str(tmp_path / "cheope-20260101-000000.mcap"),
            "clock_offset_ns": 0,
            "chunk_size_bytes": 1 << 20,
            "flush_interval_s": 0.0,  # every maybe_flush flushes
            "compression": "none",
            "metadata": {},
        },
        lambda **fields: said.append(fields),
    )
    writer._event("note", "before")  # something to flush
    writer.maybe_flush()
    assert not writer.stopped
    Path(writer.path).unlink()
    writer._event("note", "after")
    writer.maybe_flush()
    assert "was removed while it was written" in writer.stopped
    assert said and "was removed" in str(said[-1].get("stopped"))
    writer.finish(None, 0)
