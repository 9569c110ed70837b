"""How a recording ended, as ``logs list`` and ``logs info`` say it (logs/file_ending.py).

A controller killed with SIGKILL closes its writer's pipe without END, and the writer still
finishes the file with its footer: ``logs list`` called that session "finished" where only a
metadata line (``cheope.recording.ended``) said otherwise (an outside tester's finding). The
recordings here go through the writer process itself, fed on its standard input as the recorder
feeds it; a controller that vanished is an input that ends without END.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from controller.cli import main
from logs.session_writer import END, FRAMES, SETUP, pack_record

FRAME = (True, 1.0, 0x181, b"\x01\x02", False, False, 0, False, False, False, False)  # a FrameRecord


def _record(path: Path, closed: bool) -> None:
    """One file through ``python -m logs.session_writer``: a CAN frame, then END when ``closed``."""
    settings = {
        "path": str(path),
        "metadata": {"cheope.session": {"task": "path", "started_utc": path.stem[7:]}},
        "clock_offset_ns": 0,
        "chunk_size_bytes": 1024,
        "flush_interval_s": 0.5,
        "compression": "zstd",
        "session_id": path.stem,
    }
    records = [pack_record((SETUP, settings)), pack_record((FRAMES, 0, [FRAME]))]
    if closed:
        records.append(pack_record((END, 2, 0)))
    writer = subprocess.run(
        [sys.executable, "-m", "logs.session_writer"],
        input=b"".join(records),  # the input ends here: with END, or as a killed controller's does
        capture_output=True,
        check=True,
    )
    assert b'"written": 1' in writer.stdout, writer.stdout


def test_a_session_whose_controller_vanished_is_not_closed_in_logs_list_and_logs_info(tmp_path, capsys):
    closed, killed = tmp_path / "cheope-20260101-000000.mcap", tmp_path / "cheope-20260101-000100.mcap"
    _record(closed, closed=True)
    _record(killed, closed=False)

    assert main(["logs", "list", str(tmp_path)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert next(line for line in lines if closed.name in line).endswith("  finished")
    assert next(line for line in lines if killed.name in line).endswith("  not closed")

    assert main(["logs", "list", str(tmp_path), "--json"]) == 0
    files = [f for s in json.loads(capsys.readouterr().out)["sessions"] for f in s["files"]]
    assert [(Path(f["path"]).name, f["ended"]) for f in files] == [
        (closed.name, "finished"),
        (killed.name, "not closed"),
    ]

    for check in ([], ["--check"]):  # from the summary, and walking every chunk: the same word
        assert main(["logs", "info", *check, str(killed)]) == 0  # the file itself is intact
        ended = next(line for line in capsys.readouterr().out.splitlines() if line.startswith("ended"))
        assert ended.startswith("ended      not closed: the controller ended without closing the recording")
        assert main(["logs", "info", *check, str(closed)]) == 0
        assert "ended      finished: closed by its controller" in capsys.readouterr().out
