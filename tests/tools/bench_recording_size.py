"""Bytes per hour and writer CPU of the recording format, on the content of a recorded session.

    .venv/bin/python tests/tools/bench_recording_size.py SESSION.mcap [OUT.mcap] [--without-can]

The session's frames, cycles and events are handed to ``logs.session_writer.SessionWriter`` as
the recorder hands them over (one CYCLE record per cycle, with the frames before it), in the
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
from types import SimpleNamespace

from controller.config import load_config
from controller.core.cycle_data import Event, Severity
from logs import messages as m
from logs import session_writer as sw
from logs.reader import ReadReport, iter_decoded, read_info
from logs.session_writer import CYCLE, FRAMES, SessionWriter

HOUR_S = 3600.0


def records(
    path: Path, with_can: bool = True
) -> tuple[list[tuple[object, ...]], dict[str, dict[str, str]], float]:
    """The recorder's records for ``path`` (without its CAN frames unless ``with_can``), its metadata
    and its duration [s]."""
    info = read_info(path)
    offset_ns = int(info.metadata[m.META_SESSION]["clock_offset_ns"])
    out: list[tuple[object, ...]] = []
    frames: list[m.FrameRecord] = []
    events: dict[int, list[Event]] = {}
    for d in iter_decoded(path, (m.TOPIC_EVENTS,), ReadReport(path)):
        if d.message.kind != "recorder_drop":
            events.setdefault(d.message.cycle, []).append(
                Event(d.message.kind, Severity(d.message.severity), d.message.message)
            )
    for d in iter_decoded(path, (m.TOPIC_CAN, m.TOPIC_CYCLE), ReadReport(path)):
        if d.topic == m.TOPIC_CAN:
            f = d.message
            if not with_can:
                continue
            frames.append(
                (
                    f.outgoing,
                    (f.unix_time_ns - offset_ns) * 1e-9,  # the monotonic reading (m.unix_time_ns_of)
                    f.arbitration_id,
                    bytes(f.data),
                    f.is_extended_id,
                    f.is_remote_frame,
                    f.remote_length,
                    f.is_fd,
                    f.bitrate_switch,
                    f.error_state_indicator,
                    f.is_error_frame,
                )
            )
            continue
        c = d.message
        st = c.state
        out.append(
            (
                CYCLE,
                0,
                frames,
                c.cycle,
                c.t_s,
                (d.log_time_ns - offset_ns) * 1e-9,
                d.sequence,
                m.cycle_values_of_pb(c),
                tuple(events.get(c.cycle, ())),
                tuple(st.tcp_measured_m) or None,
                tuple(st.tcp_reference_m) or None,
            )
        )
        frames = []
    if frames:
        out.append((FRAMES, 0, frames))
    return out, info.metadata, info.duration_s


def main(src: Path, dst: Path | None, with_can: bool = True) -> dict[str, float]:
    recs, metadata, duration_s = records(src, with_can)
    metadata.pop(m.META_RECORDING, None)
    with tempfile.TemporaryDirectory() as tmp:
        out = dst or Path(tmp) / "bench.mcap"
        settings = {
            "path": str(out),
            "metadata": metadata,
            "clock_offset_ns": int(metadata[m.META_SESSION]["clock_offset_ns"]),
            "chunk_size_bytes": load_config().recording.chunk_size_bytes,
            "flush_interval_s": load_config().recording.flush_interval_s,
            "compression": "zstd",
        }
        session_now = [0.0]
        # chunks close on the session's clock (every flush_interval_s of it), as in the recorded run
        real_time = sw.time  # type: ignore[attr-defined]
        sw.time = SimpleNamespace(monotonic=lambda: session_now[0])  # type: ignore[attr-defined,assignment]
        try:
            writer = SessionWriter(settings)
            cpu0 = time.process_time()
            for r in recs:
                if r[0] == CYCLE:
                    session_now[0] = float(r[5])  # type: ignore[arg-type]
                writer.write(r)
            writer.finish(len(recs), 0)
            cpu_s = time.process_time() - cpu0
        finally:
            sw.time = real_time  # type: ignore[attr-defined]
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
