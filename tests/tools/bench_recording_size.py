"""Bytes per hour and writer CPU of the recording format, on the content of a recorded session.

    .venv/bin/python tests/tools/bench_recording_size.py SESSION.mcap [OUT.mcap] [--without-can]

The session's frames, cycles and events are handed to ``logs.session_writer.SessionWriter`` as
the recorder hands them over (``controller.tools.bench.writer_work.session_records``: one CYCLE
record per cycle, with the frames before it), in the
same process, and the writer's CPU time (``time.process_time``, the scene drawing included) and
the file it writes are measured. Run an older checkout's copy of this file with ``PYTHONPATH`` at
that checkout to measure that version's writer on the same content. ``--without-can`` writes the
same session without its CAN frames: the difference to a whole file is what ``/can`` costs
(``can_frames`` says how many frames that is). Not a pytest benchmark: it prints numbers, asserts
nothing.
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path

from controller.tools.bench.writer_work import session_records, writer_settings
from logs.session_writer import CYCLE, FRAMES, SessionWriter

HOUR_S = 3600.0


def main(src: Path, dst: Path | None, with_can: bool = True) -> dict[str, float]:
    recs, metadata, duration_s = session_records(src, with_can)
    with tempfile.TemporaryDirectory() as tmp:
        out = dst or Path(tmp) / "bench.mcap"
        settings = writer_settings(out, metadata)
        session_now = [0.0]
        # chunks close on the session's clock (every flush_interval_s of it), as in the recorded run
        writer = SessionWriter(settings, clock=lambda: session_now[0])
        cpu0 = time.process_time()
        for r in recs:
            if r[0] == CYCLE:
                session_now[0] = float(r[5])  # type: ignore[arg-type]
            writer.write(r)
        writer.finish(len(recs), 0)
        cpu_s = time.process_time() - cpu0
        size = out.stat().st_size
    return {
        "source_duration_s": round(duration_s, 3),
        "cycles": sum(1 for r in recs if r[0] == CYCLE),
        "can_frames": sum(len(r[2]) for r in recs if r[0] in (CYCLE, FRAMES)),  # type: ignore[arg-type]
        "bytes": size,
        "bytes_per_hour": round(size * HOUR_S / duration_s),
        "gb_per_hour": round(size * HOUR_S / duration_s / 1e9, 3),
        "writer_cpu_s": round(cpu_s, 3),
        "writer_cpu_percent_of_session": round(100 * cpu_s / duration_s, 2),
    }


if __name__ == "__main__":
    flags = [a for a in sys.argv[1:] if a.startswith("--")]
    paths = [a for a in sys.argv[1:] if not a.startswith("--")]
    if len(paths) not in (1, 2) or set(flags) - {"--without-can"}:
        sys.exit(__doc__)
    print(
        json.dumps(
            main(Path(paths[0]), Path(paths[1]) if len(paths) == 2 else None, "--without-can" not in flags)
        )
    )
