"""The recording writer's work per cycle: machine instructions under callgrind, on a recorded session.

    .venv/bin/python -m controller.tools.bench.writer_work SESSION.mcap [--first 8000] [--cycles 2000]
        [--without-can] [--without-task-values] [--scene-rate HZ] [--compression zstd|lz4|none] [--callgrind-out FILE]

The session's frames, cycles and events become the records the recorder hands its writer process
(``session_records``: one CYCLE record per cycle, with the frames before it), and a window of them
is written by ``logs.session_writer.SessionWriter`` in a second process under valgrind's callgrind,
between two markers (``cycle_work.callgrind_window``, as ``cycle_work --instructions``): a figure that the host's
load does not move (two runs of one file agree to a few instructions in a million), unlike the
writer's share of a core in ``cheope bench``. ``--first`` cycles of the file are skipped (the
contour's tracking starts near cycle 8 000 of the default demo) and 400 more are written before the
window (the chunk and the 3D scene warm).

The options take one part away, so that the difference to a whole run says what that part costs:
``--without-can`` the session's CAN frames (``/can``), ``--without-task-values`` the task's fields
(``state.task_values`` of ``/cycle``), ``--scene-rate`` the rate of the robot's 3D scene and of the
viewers' copies (``recording.scene_rate_hz`` of the recorded configuration; 0.1 draws almost none),
``--compression`` the chunks' compression. Prints JSON: instructions per cycle, the window's cycles,
and the bytes of the file written. Not a timing: it asserts nothing (tests/tools/test_writer_work.py
checks that it runs).
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import pickle
import shutil
import sys
import tempfile
from pathlib import Path
from typing import Any

from controller.tools.bench.cycle_work import callgrind_window

WARMUP_CYCLES = 400

Record = tuple[object, ...]


def session_records(
    path: Path, with_can: bool = True
) -> tuple[list[Record], dict[str, dict[str, str]], float]:
    """The recorder's records for the session ``path`` (without its CAN frames unless ``with_can``),
    its metadata and its duration [s]."""
    from controller.core.cycle_data import Event, Severity
    from logs import messages as m
    from logs.reader import ReadReport, iter_decoded, read_info
    from logs.session_writer import CYCLE, FRAMES

    info = read_info(path)
    offset_ns = int(info.metadata[m.META_SESSION]["clock_offset_ns"])
    out: list[Record] = []
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


def writer_settings(
    path: Path,
    metadata: dict[str, dict[str, str]],
    compression: str = "zstd",
    scene_rate_hz: float | None = None,
) -> dict[str, Any]:
    """What the recorder's SETUP record gives the writer, for a rewrite of a session with ``metadata``
    into ``path``: today's chunking, the session's clock offset, its configuration (its 3D scene at
    ``scene_rate_hz`` when given)."""
    from controller.config import load_config
    from logs import messages as m

    metadata = {k: dict(v) for k, v in metadata.items() if k != m.META_RECORDING}
    if scene_rate_hz is not None and m.META_CONFIG in metadata:
        recorded = json.loads(metadata[m.META_CONFIG]["json"])
        recorded.setdefault("recording", {})["scene_rate_hz"] = scene_rate_hz
        metadata[m.META_CONFIG]["json"] = json.dumps(recorded)
    cfg = load_config()
    return {
        "path": str(path),
        "metadata": metadata,
        "clock_offset_ns": int(metadata[m.META_SESSION]["clock_offset_ns"]),
        "chunk_size_bytes": cfg.recording.chunk_size_bytes,
        "flush_interval_s": cfg.recording.flush_interval_s,
        "compression": compression,
    }


def without_task_values(record: Record) -> Record:
    """A CYCLE record whose values carry no task fields (the phase neither)."""
    from logs.cycle_encoding import TASK_FIELDS_AT
    from logs.session_writer import CYCLE

    if record[0] != CYCLE:
        return record
    values = list(record[7])  # type: ignore[call-overload]
    values[TASK_FIELDS_AT] = None
    return (*record[:7], tuple(values), *record[8:])


def window(records: list[Record], first: int, cycles: int) -> list[Record]:
    """The records from the ``first``-th cycle's on: ``WARMUP_CYCLES`` and then ``cycles`` cycles."""
    from logs.session_writer import CYCLE

    at = [i for i, r in enumerate(records) if r[0] == CYCLE]
    last = first + WARMUP_CYCLES + cycles
    if last > len(at):
        raise ValueError(f"the session has {len(at)} cycles: {first} + {WARMUP_CYCLES} + {cycles} do not fit")
    return as_sent(records[at[first] : at[last]])


def as_sent(records: list[Record]) -> list[Record]:
    """``records`` as the recorder sends them: a cycle's task fields' names only when they differ
    from the last ones sent (``logs.cycle_encoding.without_sent_names``), so that the writer takes
    its path of every cycle, not that of a change of names."""
    from logs.cycle_encoding import without_sent_names
    from logs.session_writer import CYCLE

    out: list[Record] = []
    sent: tuple[str, ...] | None = None
    for r in records:
        if r[0] == CYCLE:
            values, names = without_sent_names(r[7], sent)  # type: ignore[arg-type]
            sent = names or sent
            r = (*r[:7], values, *r[8:])
        out.append(r)
    return out


def write_window(records: list[Record], settings: dict[str, Any], marker: bool) -> int:
    """``records`` written by a SessionWriter on the session's clock (its chunks close as they did);
    ``os.getsid`` before and after all but the first ``WARMUP_CYCLES`` cycles when ``marker``.
    Returns the bytes of the file."""
    from logs.session_writer import CYCLE, SessionWriter

    now = [0.0]
    writer = SessionWriter(settings, clock=lambda: now[0])
    gc.collect()
    gc.freeze()  # the records loaded: not walked by every collection of the writer's garbage
    seen = 0
    for r in records:
        if r[0] == CYCLE:
            if seen == WARMUP_CYCLES and marker:
                os.getsid(0)
            seen += 1
            now[0] = float(r[5])  # type: ignore[arg-type]
        writer.write(r)
    if marker:
        os.getsid(0)
    writer.finish(len(records), 0)
    return Path(settings["path"]).stat().st_size


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("session", nargs="?", type=Path, help="a recorded session (.mcap)")
    ap.add_argument("--first", type=int, default=8000, help="cycles of the session skipped")
    ap.add_argument("--cycles", type=int, default=2000, help="cycles counted, after 400 written to warm")
    ap.add_argument("--without-can", action="store_true", help="the session's CAN frames left out")
    ap.add_argument("--without-task-values", action="store_true", help="the task's fields left out")
    ap.add_argument("--scene-rate", type=float, default=None, help="the 3D scene's rate [Hz] (recorded: 20)")
    ap.add_argument("--compression", choices=("zstd", "lz4", "none"), default="zstd")
    ap.add_argument(
        "--callgrind-out",
        type=Path,
        default=None,
        help="keep the window's callgrind dump here (callgrind_annotate)",
    )
    ap.add_argument("--child", type=Path, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child is not None:
        records, settings = pickle.loads(args.child.read_bytes())
        write_window(records, settings, marker=True)
        return 0
    if args.session is None:
        ap.error("a recorded session is needed")
    from controller.errors import InputError

    try:  # a file that is not a session, or too short a one: one line naming it (argparse's exit 2)
        records, metadata, _ = session_records(args.session, with_can=not args.without_can)
        records = window(records, args.first, args.cycles)
    except (InputError, ValueError) as err:
        ap.error(str(err))
    valgrind = shutil.which("valgrind")
    if valgrind is None:
        ap.error("valgrind not found (apt-get install valgrind)")
    if args.without_task_values:
        records = [without_task_values(r) for r in records]
    with tempfile.TemporaryDirectory(prefix="cheope-writer-work-") as tmp:
        out = Path(tmp) / "rewritten.mcap"
        settings = writer_settings(out, metadata, args.compression, args.scene_rate)
        job = Path(tmp) / "job.pickle"
        job.write_bytes(pickle.dumps((records, settings)))
        instructions, dump = callgrind_window(
            ["controller.tools.bench.writer_work", "--child", str(job)], Path(tmp) / "callgrind.out", valgrind
        )
        if args.callgrind_out is not None:
            shutil.copyfile(dump, args.callgrind_out)
        size = out.stat().st_size
    print(
        json.dumps(
            {
                "session": str(args.session),
                "cycles": args.cycles,
                "first": args.first,
                "without": [
                    p
                    for p, on in (("can", args.without_can), ("task_values", args.without_task_values))
                    if on
                ],
                "scene_rate_hz": args.scene_rate,
                "compression": args.compression,
                "instructions_per_cycle": round(instructions / args.cycles),
                "bytes_written": size,
                "tool": "valgrind --tool=callgrind",
            }
        )
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
