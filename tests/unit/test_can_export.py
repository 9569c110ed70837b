"""``cheope logs export``: every recorded frame once, read back by python-can, decoded by cantools.

The recording (tests/can_traffic.py) is written by the project's own recorder with the traffic of
40 cycles built from the shipped DBC; one CAN FD frame and one error frame test the formats'
limits. The Unix times written are the recorded monotonic times + the recorded clock offset.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import can
import cantools
import pytest
from can_traffic import DBC, T0_S
from can_traffic import record_traffic as _record

from logs.bus_traffic import clock_offset_s, recorded_frames
from logs.can_export import FORMATS, export_frames
from logs.reader import ReadReport

# Reading back: 1 us of resolution in the text formats, plus the float rounding of a Unix time (0.24 us).
RESOLUTION_S = {"asc": 1.5e-6, "blf": 1.5e-6, "log": 1.5e-6, "trc": 1.5e-6, "csv": 1e-9, "mf4": 1e-6}


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[tuple[float, bool, can.Message]]]:
    path = tmp_path_factory.mktemp("export") / "session.mcap"
    return path, _record(path)


def _unix_offset(path: Path) -> float:
    report = ReadReport(path)
    for _ in recorded_frames(path, report):
        break
    offset = clock_offset_s(report)
    assert offset is not None and offset > 1e9  # a Unix time, 2001 or later
    return offset


@pytest.mark.parametrize("fmt", FORMATS)
def test_python_can_reads_every_frame_back_with_its_direction_and_time(recording, tmp_path: Path, fmt: str):
    path, frames = recording
    out = tmp_path / f"x.{fmt}"
    result = export_frames(path, fmt, out)
    assert result.frames_written == len(frames) and result.frames_not_written == {}
    assert result.frames_out == sum(o for _, o, _ in frames)
    offset = _unix_offset(path)
    read = list(can.LogReader(out, **({"relative_timestamp": False} if fmt == "asc" else {})))
    assert len(read) == len(frames)
    first_read = read[0].timestamp
    for (t, outgoing, sent), got in zip(frames, read, strict=True):
        assert (got.arbitration_id, bytes(got.data)) == (sent.arbitration_id, bytes(sent.data))
        if fmt != "csv":  # python-can's CSV has no direction column (the export says so)
            assert got.is_rx is (not outgoing)
        if fmt == "asc":  # ASC: times after the first frame to 1 us; its start (the date line) to 1 ms
            assert math.isclose(got.timestamp - first_read, t - T0_S, abs_tol=RESOLUTION_S[fmt])
            assert math.isclose(first_read, T0_S + offset, abs_tol=1e-3)
        else:
            assert math.isclose(got.timestamp, t + offset, abs_tol=RESOLUTION_S[fmt]), (
                got.timestamp,
                t + offset,
            )
    assert ("direction" in result.note) is (fmt == "csv")


def test_cantools_decodes_the_export_with_the_shipped_dbc(recording, tmp_path: Path):
    path, _ = recording
    db = cantools.database.load_file(DBC)
    out = export_frames(path, "log", tmp_path / "x.log").output
    decoded = {}
    for msg in can.LogReader(out):
        if msg.arbitration_id in (0x601, 0x581):  # SDO: not in the DBC
            continue
        decoded[db.get_message_by_frame_id(msg.arbitration_id).name] = db.decode_message(
            msg.arbitration_id, msg.data
        )
    assert {"SYNC", "Drive1_RPDO1", "Drive3_TPDO1", "ForceSensor_TPDO1"} <= set(decoded)
    want = db.decode_message(0x190, bytes([39, 1, 2, 3, 4, 5, 6, 7]))  # the last cycle's sensor frame
    assert decoded["ForceSensor_TPDO1"] == want


def test_frames_a_format_cannot_hold_are_counted_not_dropped(tmp_path: Path):
    fd = can.Message(
        arbitration_id=0x201, data=bytes(range(12)), is_extended_id=False, is_fd=True, bitrate_switch=True
    )
    error = can.Message(arbitration_id=0, data=bytes(8), is_error_frame=True, is_extended_id=False)
    path = tmp_path / "fd.mcap"
    frames = _record(path, [(True, fd), (False, error)])
    trc = export_frames(path, "trc", tmp_path / "x.trc")
    assert trc.frames_written == len(frames) - 2 and sum(trc.frames_not_written.values()) == 2
    blf = export_frames(path, "blf", tmp_path / "x.blf")  # BLF holds both
    assert blf.frames_written == len(frames)
    back = list(can.LogReader(blf.output))
    assert back[-2].is_fd and back[-2].bitrate_switch and bytes(back[-2].data) == bytes(range(12))
    assert back[-1].is_error_frame and back[-1].is_rx


@pytest.mark.parametrize("fmt", ["asc", "blf", "log", "csv", "mf4"])
def test_remote_frames_and_extended_ids_are_recorded_and_exported_as_they_were(tmp_path: Path, fmt: str):
    """A node-guarding RTR (0x701, DLC 1) and a 29-bit id at 0x123 (below 0x7FF: not guessed from the
    value): both recorded with their flags, both read back from the export as they were sent."""
    rtr = can.Message(arbitration_id=0x701, is_remote_frame=True, dlc=1, is_extended_id=False)
    ext = can.Message(arbitration_id=0x123, data=b"\x01\x02", is_extended_id=True)
    path = tmp_path / "flags.mcap"
    _record(path, [(True, rtr), (False, ext)])
    recorded = list(recorded_frames(path))[-2:]
    assert [(f.is_remote_frame, f.remote_length, f.is_extended_id) for f in recorded] == [
        (True, 1, False),
        (False, 0, True),
    ]
    back = list(can.LogReader(export_frames(path, fmt, tmp_path / f"x.{fmt}").output))[-2:]
    # candump's log as python-can writes it: ``701#R``, the requested length left out (logs/can_export.py)
    assert (back[0].arbitration_id, back[0].is_remote_frame, back[0].dlc) == (0x701, True, fmt != "log")
    assert (back[1].arbitration_id, back[1].is_extended_id, bytes(back[1].data)) == (0x123, True, b"\x01\x02")


def test_the_command_exits_1_and_names_what_a_format_could_not_hold(tmp_path: Path):
    fd = can.Message(arbitration_id=0x201, data=bytes(range(12)), is_extended_id=False, is_fd=True)
    path = tmp_path / "fd.mcap"
    _record(path, [(True, fd)])
    r = _cheope("logs", "export", str(path), "--format", "trc", "--json")
    assert r.returncode == 1, r.stderr
    result = json.loads(r.stdout)
    assert result["frames_not_written"] == {"CAN FD frames (python-can's TRC writer has none)": 1}
    assert Path(result["output"]) == path.with_suffix(".trc") and r.stderr == ""


def test_bad_input_is_one_line_and_exit_2(tmp_path: Path):
    not_mcap = tmp_path / "x.mcap"
    not_mcap.write_text("hello")
    r = _cheope("logs", "export", str(not_mcap), "--format", "asc")
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "not an MCAP file" in r.stderr
    r = _cheope("logs", "export", str(not_mcap), "--format", "mdf")
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "--format" in r.stderr


def test_an_output_that_cannot_be_written_is_one_line_and_exit_2(recording, tmp_path: Path):
    path, _ = recording
    r = _cheope("logs", "export", str(path), "--format", "blf", "-o", str(tmp_path / "missing" / "x.blf"))
    assert (
        r.returncode == 2 and r.stderr.count("\n") == 1 and "cannot write" in r.stderr and "x.blf" in r.stderr
    )
    r = _cheope("logs", "export", str(path), "--format", "log", "-o", str(path))
    assert (
        r.returncode == 2 and "is the recording itself" in r.stderr and path.read_bytes()[:5] == b"\x89MCAP"
    )


def test_an_output_that_is_the_recording_by_another_name_is_refused(recording, tmp_path: Path):
    """A hard link to the recording (or a bind mount of its directory) is the same file by another
    path: the export, the recovery and the Rerun file overwrote the recording (an outside tester's
    finding; a comparison of the paths caught only the same path and symbolic links)."""
    path, _ = recording
    copy = tmp_path / "copy.mcap"
    copy.write_bytes(path.read_bytes())
    for name, args in (
        ("other.csv", ("logs", "export", str(copy), "--format", "csv", "-o")),
        ("other.mcap", ("logs", "recover", str(copy), "-o")),
        ("other.rrd", ("replay", str(copy), "--rerun")),
    ):
        link = tmp_path / name
        link.hardlink_to(copy)
        r = _cheope(*args, str(link))
        assert r.returncode == 2 and copy.read_bytes()[:5] == b"\x89MCAP", (name, r.stderr)
        assert "is the recording itself" in r.stderr or "not the damaged one" in r.stderr, r.stderr
        link.unlink()


def _cheope(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "controller", *args], capture_output=True, text=True, check=False, timeout=60
    )


def test_an_existing_output_is_refused_and_left_as_it_was(recording, tmp_path: Path):
    """``-o`` naming a file that is there (another recording) overwrote it, even when nothing was
    exported (an outside tester's finding): refused as ``logs recover`` refuses it, before any work."""
    path, _ = recording
    other = tmp_path / "other.mcap"
    other.write_bytes(b"\x89MCAP0\r\nanother recording")
    before = other.read_bytes()
    for args in (("logs", "export", str(path), "--format", "csv"), ("logs", "recover", str(path))):
        r = _cheope(*args, "-o", str(other))
        assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
        assert f"{other} already exists; pass another output file" in r.stderr
        assert other.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["other.mcap"]  # no partial file left


def test_an_export_of_no_frame_creates_no_file(tmp_path: Path):
    nothing = tmp_path / "nothing.mcap"
    nothing.write_bytes(b"\x89MCAP0\r\n" + bytes(4096))
    out = tmp_path / "n.csv"
    r = _cheope("logs", "export", str(nothing), "--format", "csv", "-o", str(out))
    assert r.returncode == 1 and "no CAN frame read from" in r.stderr
    assert f"{out} not created" in r.stdout
    assert sorted(p.name for p in tmp_path.iterdir()) == ["nothing.mcap"]
