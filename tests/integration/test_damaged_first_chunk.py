"""A recording whose first chunk is damaged keeps the rest (issue 38, item 7; logs/reader.py).

The first chunk defines every schema and channel; its loss made every later message an orphan
("nothing recovered ... N message(s) whose channel definition was lost") although the other
chunks were intact and the summary section at the end repeats every schema and channel. Now the
reader takes them from the summary when it passes its CRC; ``logs info --check`` checks that CRC;
and every ``logs`` command that read nothing exits non-zero.
"""

from __future__ import annotations

import struct
from pathlib import Path

import can
import pytest

from controller.cli import main
from logs.reader import read_info, read_info_from_summary
from logs.recorder import SessionRecorder

pytestmark = pytest.mark.integration
DATA = Path(__file__).resolve().parents[1] / "data"


def _chunks(raw: bytes) -> list[tuple[int, int]]:
    """(offset, record length with its 9-byte header) of every chunk record, walking the data section."""
    out, pos = [], 8
    while pos + 9 <= len(raw):
        opcode, length = struct.unpack_from("<BQ", raw, pos)
        if opcode == 0x06:
            out.append((pos, 9 + length))
        if opcode in (0x02, 0x0F):  # footer, data end
            break
        pos += 9 + length
    return out


def _first_chunk_zeroed(src: Path, dst: Path) -> Path:
    raw = bytearray(src.read_bytes())
    offset, length = _chunks(bytes(raw))[0]
    raw[offset : offset + length] = bytes(length)
    dst.write_bytes(raw)
    return dst


def _first_chunk_flipped(src: Path, dst: Path) -> Path:
    raw = bytearray(src.read_bytes())
    offset, length = _chunks(bytes(raw))[0]
    raw[offset + length // 2] ^= 0xFF  # inside the compressed data: the chunk fails to decode or its CRC
    dst.write_bytes(raw)
    return dst


@pytest.fixture
def frames_recording(tmp_path: Path) -> Path:
    """A recording of 600 CAN frames in small chunks (the first defines every channel)."""
    path = tmp_path / "frames.mcap"
    now = [100.0]
    with SessionRecorder(
        path,
        {"cheope.session": {"task": "path"}},
        clock=lambda: now[0],
        chunk_size_bytes=1024,
        flush_interval_s=0.001,
    ) as rec:
        for i in range(600):
            now[0] = 100.0 + i * 0.001
            msg = can.Message(
                arbitration_id=0x181 + i % 3, data=struct.pack("<HI", i, i), is_extended_id=False
            )
            rec.on_frame(i % 2 == 0, now[0], msg)
    assert len(_chunks(path.read_bytes())) >= 3
    return path


@pytest.mark.parametrize("damage", [_first_chunk_zeroed, _first_chunk_flipped])
def test_recover_info_export_and_rerun_read_the_intact_chunks(damage, tmp_path: Path, capsys) -> None:
    source = DATA / "contour_contact.mcap"
    whole = read_info(source)
    broken = damage(source, tmp_path / "broken.mcap")
    report = read_info(broken)
    assert report.orphan_messages == 0 and report.channels_from_summary > 0
    assert 0 < report.messages < whole.messages and report.chunks == whole.chunks - 1
    assert main(["logs", "info", "--check", str(broken)]) == 1  # damaged, and says what it read
    assert "taken from the summary" in capsys.readouterr().out
    # the messages the damage took are put down to it, not to a change by hand (an outside tester's)
    gap = next(p for p in report.problems if "where its writer wrote" in p)
    assert gap.endswith("the rest were in the damaged part(s) named before"), gap
    assert main(["logs", "recover", str(broken), "-o", str(tmp_path / "r.mcap")]) == 0
    recovered = read_info(tmp_path / "r.mcap")
    assert recovered.messages == report.messages and not recovered.damaged
    assert recovered.message_counts == report.message_counts
    capsys.readouterr()
    assert main(["replay", str(broken), "--rerun", str(tmp_path / "out.rrd")]) == 0
    assert (tmp_path / "out.rrd").stat().st_size > 0


def test_export_of_a_damaged_first_chunk_keeps_the_later_frames(
    frames_recording: Path, tmp_path: Path
) -> None:
    broken = _first_chunk_zeroed(frames_recording, tmp_path / "broken.mcap")
    out = tmp_path / "frames.log"
    assert main(["logs", "export", str(broken), "--format", "log", "-o", str(out)]) == 0
    lines = out.read_text().splitlines()
    assert 0 < len(lines) < 600


def test_every_logs_command_that_read_nothing_exits_non_zero(tmp_path: Path, capsys) -> None:
    """A file with its magic and nothing readable after it, and an empty directory."""
    nothing = tmp_path / "nothing.mcap"
    nothing.write_bytes(b"\x89MCAP0\r\n" + bytes(4096))
    assert main(["logs", "info", str(nothing)]) == 1
    assert main(["logs", "recover", str(nothing), "-o", str(tmp_path / "r.mcap")]) == 1
    assert main(["logs", "export", str(nothing), "--format", "csv", "-o", str(tmp_path / "n.csv")]) == 1
    assert "no CAN frame read from" in capsys.readouterr().err
    assert (
        main(["replay", str(nothing), "--rerun", str(tmp_path / "n.rrd")]) == 2
    )  # "no readable control cycles"
    assert main(["replay", str(nothing), "--verify"]) != 0
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["logs", "list", str(empty)]) == 1


def test_info_check_covers_the_summarys_crc(tmp_path: Path, capsys) -> None:
    raw = bytearray((DATA / "path_quarter_lap.mcap").read_bytes())
    footer = len(raw) - 8 - 29
    summary_start = struct.unpack_from("<Q", raw, footer + 9)[0]
    raw[summary_start + 20] ^= 0x01  # a byte of the summary's first record (its first schema)
    bad = tmp_path / "bad-summary.mcap"
    bad.write_bytes(raw)
    assert read_info_from_summary(bad) is None  # not trusted: answered by walking the file instead
    assert main(["logs", "info", "--check", str(bad)]) == 1
    assert "does not match its CRC" in capsys.readouterr().out
    assert main(["logs", "info", str(bad)]) == 1
    assert main(["logs", "info", str(DATA / "path_quarter_lap.mcap")]) == 0


def test_info_check_finds_bytes_appended_after_the_end(tmp_path: Path, capsys) -> None:
    """700 bytes after the closing magic were "complete", exit 0 (an outside tester's finding)."""
    raw = (DATA / "contour_contact.mcap").read_bytes()
    changed = tmp_path / "appended.mcap"
    changed.write_bytes(raw + bytes(range(256)) * 2 + bytes(188))
    for args in (["logs", "info", "--check", str(changed)], ["logs", "info", str(changed)]):
        assert main(args) == 1
        out = capsys.readouterr().out
        assert f"700 byte(s) after the closing magic bytes at offset {len(raw)}" in out
        assert "status     complete" not in out
    assert main(["logs", "info", "--check", str(DATA / "contour_contact.mcap")]) == 0


def _without_some_cycles(src: Path, dst: Path, drop: int) -> None:
    """``src`` written again by the mcap library without ``drop`` of its /cycle messages: a complete
    file, its index and summary matching what it holds, its metadata as written."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    with open(src, "rb") as f_in, open(dst, "wb") as f_out:
        reader = make_reader(f_in)
        w = Writer(f_out)
        w.start(profile="", library="an editor")
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        left = drop
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            if channel.topic == "/cycle" and left and message.sequence % 50 == 7:
                left -= 1
                continue
            if schema.id not in schemas:
                schemas[schema.id] = w.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channels:
                channels[channel.id] = w.register_channel(
                    channel.topic, channel.message_encoding, schemas[schema.id], dict(channel.metadata)
                )
            w.add_message(
                channels[channel.id], message.log_time, message.data, message.publish_time, message.sequence
            )
        for m in reader.iter_metadata():
            w.add_metadata(m.name, dict(m.metadata))
        w.finish()
    assert left == 0


def test_messages_removed_from_a_complete_file_are_a_problem_by_its_writers_count(tmp_path: Path):
    """An outside tester removed 10 /cycle messages and rewrote the file: ``logs info --check`` said
    complete, no problem (only ``replay --verify`` found the gap)."""
    edited = tmp_path / "edited.mcap"
    _without_some_cycles(DATA / "path_quarter_lap.mcap", edited, drop=3)
    said = "the file holds 907 message(s) where its writer wrote 910 (cheope.recording file_written)"
    for report in (read_info(edited), read_info_from_summary(edited)):
        assert report is not None and report.complete
        assert any(p.startswith(said) for p in report.problems), report.problems
    assert read_info(DATA / "path_quarter_lap.mcap").problems == []


def _footer_pointing_outside(src: Path, dst: Path) -> Path:
    """``src`` with its footer's summary_start at 2**60 (the footer: opcode, length, three fields, magic)."""
    raw = bytearray(src.read_bytes())
    footer = len(raw) - 8 - 29
    assert raw[footer] == 0x02  # Opcode.FOOTER
    struct.pack_into("<Q", raw, footer + 9, 2**60)
    dst.write_bytes(raw)
    return dst


def test_a_footer_pointing_outside_the_file_is_named_and_spares_the_others(tmp_path: Path, capsys) -> None:
    """An outside tester's: one such file ended ``logs list`` of the whole directory ("cannot read ...:
    Invalid argument", exit 2), ``logs info`` said only that, and ``info --check`` said complete."""
    good = tmp_path / "good.mcap"
    good.write_bytes((DATA / "path_quarter_lap.mcap").read_bytes())
    bad = _footer_pointing_outside(DATA / "path_quarter_lap.mcap", tmp_path / "bad.mcap")
    assert read_info_from_summary(bad) is None  # no usable summary: the walk is the answer
    report = read_info(bad)
    assert report.messages == read_info(good).messages
    assert report.problems == [f"the footer's summary_start {2**60} is not where the summary starts (164284)"]
    assert main(["logs", "info", "--check", str(bad)]) == 1
    capsys.readouterr()
    assert main(["logs", "list", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "bad.mcap" in out and "good.mcap" in out
