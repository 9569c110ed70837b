"""Bodies of ``cheope logs info|recover|export`` and ``cheope replay``; ``add_commands`` wires them in.

Errors end as one line on stderr with exit code 2; ``--verify`` exits 1 on a divergence and 3 when
it could check only part of the recording (truncated, damaged, cycles dropped, a file without its
keyframe), saying how much; ``logs info`` on a damaged file, ``logs recover`` when it recovered
nothing and ``logs export`` when the format could not hold every frame exit 1. Every command that
read nothing exits 1 too: ``logs export`` without a frame, ``replay --rerun`` without a cycle,
``replay --bus`` without a frame sent, ``logs list`` without a session (an unreadable file's
export said "wrote 0 frames" and exited 0).
"""

from __future__ import annotations

import argparse
import sys
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TypeVar

from controller.cli_output import progress_line, strict_json
from controller.errors import InputError, RefusedError

# The caller's parser class (cheope's own ArgumentParser subclass): _SubParsersAction is invariant in it.
ParserT = TypeVar("ParserT", bound=argparse.ArgumentParser)

LARGE_FILE_BYTES = 4 * 1024 * 1024
VERIFY_INCOMPLETE = 3  # --verify: no divergence, but part of the recording could not be checked  # a progress bar above this size (on a terminal)


def add_commands(
    sub: argparse._SubParsersAction[ParserT], stop_on_signals: Callable[[], threading.Event]
) -> None:
    """``cheope logs`` and ``cheope replay``; ``stop_on_signals`` is the caller's (SIGINT/SIGTERM)."""
    p = sub.add_parser("logs", help="inspect and repair session recordings (MCAP)")
    logs_sub = p.add_subparsers(dest="logs_command", required=True)
    q = logs_sub.add_parser(
        "info", help="duration, channels, message counts, metadata, damage, CAN traffic and bus load"
    )
    q.add_argument("file", help="the recording (.mcap)")
    q.add_argument("--json", action="store_true", help="print one JSON object")
    q.add_argument(
        "--check",
        action="store_true",
        help="read every chunk, check its CRC and count the recorded CAN traffic (default: the summary at the end of a finished "
        "file; a file without one is always read whole)",
    )
    q.set_defaults(func=cmd_logs_info)
    q = logs_sub.add_parser(
        "list", help="the sessions in a directory and their files (a long session is split)"
    )
    q.add_argument(
        "directory",
        nargs="?",
        default="",
        help='default: $XDG_DATA_HOME/cheope/sessions, where recording.directory = "" records',
    )
    q.add_argument("--json", action="store_true", help="print one JSON object")
    q.set_defaults(func=cmd_logs_list)
    q = logs_sub.add_parser("recover", help="write a complete, indexed file from a truncated or damaged one")
    q.add_argument("file", help="the truncated or damaged recording (.mcap)")
    q.add_argument("-o", "--output", help="output file (default: FILE.recovered.mcap beside it)")
    q.add_argument("--json", action="store_true", help="print the result as one JSON object")
    q.set_defaults(func=cmd_logs_recover)
    q = logs_sub.add_parser(
        "export",
        help="the recorded CAN frames for CAN tools: Vector ASC/BLF, candump log, PEAK TRC, "
        "CSV, ASAM MF4 (python-can's writers)",
    )
    q.add_argument("file", help="the recording (.mcap)")
    q.add_argument(
        "--format",
        required=True,
        choices=("asc", "blf", "log", "trc", "csv", "mf4"),
        help="asc, blf (Vector), log (candump -L), trc (PEAK), csv (python-can's columns: no direction), "
        "mf4 (ASAM MDF 4; needs the mf4 extra: asammdf)",
    )
    q.add_argument("-o", "--output", help="output file (default: FILE with the format's suffix, beside it)")
    q.add_argument("--json", action="store_true", help="print the result as one JSON object")
    q.set_defaults(func=cmd_logs_export)

    p = sub.add_parser(
        "replay", help="replay a recording: to Rerun, onto a CAN bus, or through the step (--verify)"
    )
    p.add_argument(
        "file",
        nargs="*",
        help="the recording (.mcap; may also follow --rerun); --verify: one file, or "
        "several files of one session",
    )
    what = p.add_mutually_exclusive_group(required=True)
    what.add_argument(
        "--rerun",
        nargs="?",
        const="",
        metavar="OUT.rrd",
        help="to Rerun with the robot drawn: without OUT spawn the viewer (or write FILE.rrd when none "
        "can start); cheope replay --rerun FILE.mcap reads FILE.mcap",
    )
    what.add_argument(
        "--bus", metavar="INTERFACE[:CHANNEL]", help="send the recorded frames with their timing"
    )
    what.add_argument(
        "--verify",
        action="store_true",
        help="run the recorded inputs through the step and compare the outputs bit for bit "
        "(exit 1: a divergence, 3: only part of the recording could be checked)",
    )
    p.add_argument("--speed", type=float, default=1.0, help="--bus: time scale (2 = twice as fast)")
    p.add_argument(
        "--only",
        choices=("sent", "received"),
        help="--bus: only the frames the controller sent, or only those it received (a bus carries "
        "no direction: a listener sees every replayed frame as received; logs export keeps it)",
    )
    p.add_argument("--udp-port", type=int, help="--bus: UDP port of the udp_multicast bus")
    p.add_argument("--fd", action="store_true", help="--bus: open the bus for CAN FD")
    p.add_argument(
        "--live-devices",
        action="store_true",
        help="--bus: send the controller's frames even where the recording's devices or a master answer "
        "(the devices then move as recorded, open loop, with no controller watching), or the devices' "
        "frames (--only received) beside the recording's devices live; refused without it",
    )
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="--verify: change the recorded configuration (does the change alter the outputs?)",
    )
    p.add_argument("--json", action="store_true", help="print the result as one JSON object")
    p.set_defaults(func=cmd_replay, stop_on_signals=stop_on_signals)


def _fail(args: argparse.Namespace, err: Exception) -> int:
    print(f"cheope {args.command}: error: {err}", file=sys.stderr)
    return 2


@contextmanager
def _progress(path: Path, label: str) -> Iterator[Callable[[int], None] | None]:
    """A rich progress bar over the file's bytes, for large files on a terminal; else nothing."""
    try:
        size = path.stat().st_size
    except OSError:
        size = 0
    if size < LARGE_FILE_BYTES or not sys.stderr.isatty():
        yield None
        return
    from rich.console import Console
    from rich.progress import BarColumn, DownloadColumn, Progress, TextColumn, TimeRemainingColumn

    with Progress(
        TextColumn(label),
        BarColumn(),
        DownloadColumn(),
        TimeRemainingColumn(),
        console=Console(stderr=True),
        transient=True,
    ) as bar:
        task = bar.add_task(label, total=size)
        yield lambda done: bar.update(task, completed=done)


@contextmanager
def _working(path: Path, label: str) -> Iterator[Callable[[str], None]]:
    """A status line with the time elapsed while a large file is walked (on a terminal); else silent."""
    try:
        large = path.stat().st_size >= LARGE_FILE_BYTES
    except OSError:
        large = False
    if not large:
        yield lambda _text: None
        return
    with progress_line(label) as progress:
        yield progress


def cmd_logs_info(args: argparse.Namespace) -> int:
    """Exit 0 for an intact file, 1 for a damaged or truncated one (it says what), 2 for no MCAP at all.

    A finished file answers from its MCAP summary (milliseconds); ``--check`` walks every chunk and
    adds the recorded CAN traffic (frames and bus load by direction, logs/bus_traffic.py).
    """
    from logs import messages as m
    from logs.bus_traffic import recorded_traffic
    from logs.reader import LogFileError, format_info, info_dict, read_info, read_info_from_summary

    try:
        report = None if args.check else read_info_from_summary(args.file)
        traffic = None
        if report is None:
            with _working(Path(args.file), "cheope logs info") as progress:
                progress("reading every chunk")
                report = read_info(args.file)
                if report.message_counts.get(m.TOPIC_CAN):
                    progress("counting the CAN traffic")
                    traffic = recorded_traffic(args.file)
    except LogFileError as err:
        return _fail(args, err)
    if args.json:
        print(
            strict_json({**info_dict(report), **({"can": traffic.as_dict()} if traffic is not None else {})})
        )
    else:
        print(format_info(report) + ("\n" + traffic.format() if traffic is not None else ""))
    return 1 if report.damaged else 0


def cmd_logs_recover(args: argparse.Namespace) -> int:
    from logs.recovery import recover

    try:
        with _working(Path(args.file), "cheope logs recover") as progress:
            progress("copying what is readable")
            r = recover(args.file, args.output)
    except InputError as err:  # the recording, or the output (one there already: output_paths.py)
        return _fail(args, err)
    lost = "; ".join(r.report.problems) or "nothing was damaged"
    if args.json:
        print(
            strict_json(
                {
                    "output": str(r.output) if r.messages_saved else None,
                    "messages_saved": r.messages_saved,
                    "chunks": r.report.chunks,
                    "problems": r.report.problems,
                }
            )
        )
    if r.messages_saved == 0:
        r.output.unlink(missing_ok=True)  # a file with no message in it would only look like a recovery
        print(
            f"cheope logs recover: nothing recovered from {args.file}: no readable message ({lost})",
            file=sys.stderr,
        )
        return 1
    if not args.json:
        print(
            f"recovered {r.messages_saved} messages from {r.report.chunks} chunk(s) into {r.output} ({lost})"
        )
    return 0


def cmd_logs_list(args: argparse.Namespace) -> int:
    from logs.reader import LogFileError
    from logs.session_list import format_sessions, list_sessions

    try:
        sessions = list_sessions(args.directory)
    except LogFileError as err:
        return _fail(args, err)
    if args.json:
        print(
            strict_json(
                {"directory": str(sessions.directory), "sessions": [x.as_dict() for x in sessions.sessions]}
            )
        )
    else:
        print(format_sessions(sessions))
    return 0 if sessions.sessions else 1  # read nothing


def rerun_input_and_output(file: str | None, rerun: str | None) -> tuple[str, str | None]:
    """(recording, OUT.rrd or None) of ``cheope replay [FILE] --rerun [X]``: an X that names a
    recording (``cheope replay --rerun FILE.mcap``) is the input, never an output to overwrite."""
    if file is None:
        if not rerun:
            raise InputError("no recording given: cheope replay FILE.mcap --rerun [OUT.rrd]")
        if rerun.endswith(".rrd"):
            raise InputError(
                f"--rerun {rerun}: is the output; which recording? cheope replay FILE.mcap --rerun {rerun}"
            )
        return rerun, None
    if rerun and not rerun.endswith(".rrd"):
        raise InputError(f"--rerun {rerun}: the output must be a .rrd file (Rerun's recording format)")
    return file, rerun or None


def cmd_logs_export(args: argparse.Namespace) -> int:
    """Exit 0 when every recorded frame was written, 1 when the format could not hold some (it says
    which), 2 when the input is no recording or the output cannot be written."""
    from logs.can_export import export_frames

    path = Path(args.file)
    try:
        with _progress(path, "exporting") as progress:
            r = export_frames(path, args.format, args.output, progress)
    except InputError as err:  # the recording, the format, the output (output_paths.py)
        return _fail(args, err)
    not_written = "; ".join(f"{k} {why} not written" for why, k in r.frames_not_written.items())
    if args.json:
        print(
            strict_json(
                {
                    "output": str(r.output),
                    "file_written": r.file_written,
                    "format": r.format,
                    "frames_written": r.frames_written,
                    "frames_out": r.frames_out,
                    "frames_in": r.frames_written - r.frames_out,
                    "frames_not_written": r.frames_not_written,
                    "note": r.note,
                    "problems": r.report.problems,
                }
            )
        )
    else:
        wrote = (
            f"wrote {r.frames_written} frames to {r.output} ({r.frames_out} Tx, {r.frames_written - r.frames_out} Rx)"
            if r.file_written
            else f"wrote no frame: {r.output} not created"
        )
        print(wrote + "".join(f"; {t}" for t in (not_written, r.note, "; ".join(r.report.problems)) if t))
    if r.frames_written == 0:
        print(f"cheope logs export: no CAN frame read from {path}", file=sys.stderr)
    return 1 if r.frames_not_written or r.frames_written == 0 else 0


def cmd_replay(args: argparse.Namespace) -> int:
    from logs.reader import LogFileError

    if not args.verify and len(args.file) > 1:
        print(
            f"cheope {args.command}: error: --rerun and --bus take one file, got {len(args.file)}",
            file=sys.stderr,
        )
        return 2
    if args.rerun is None and not args.file:
        return _fail(args, InputError("no recording given: cheope replay FILE.mcap --verify|--bus|--rerun"))
    if not args.verify:
        args.file = args.file[0] if args.file else None
    try:
        if args.verify:
            return _verify(args)
        if args.bus is not None:
            return _bus(args)
        return _rerun(args)
    except LogFileError as err:
        return _fail(args, err)


def _verify(args: argparse.Namespace) -> int:
    from controller.config import parse_override
    from logs.replay_verify import verify

    overrides = dict(parse_override(s) for s in args.set)
    paths = [Path(f) for f in args.file]
    with _progress(paths[0], "verifying") as progress:
        result = verify(paths, overrides, progress)
    if args.json:
        d = result.divergence
        print(
            strict_json(
                {
                    "ok": result.ok,
                    "cycles_checked": result.cycles_checked,
                    "cycles_recorded": result.cycles_recorded,
                    "problems": result.problems,
                    "files": [str(p) for p in result.files],
                    "started_from": result.started_from,
                    "continues_in": result.continues_in,
                    "divergence": None
                    if d is None
                    else {
                        "cycle": d.cycle,
                        "t_s": d.t_s,
                        "field": d.field,
                        "recorded": d.recorded,
                        "recomputed": d.recomputed,
                    },
                }
            )
        )
    else:
        print(result.summary())
    if result.ok:
        return 0
    return 1 if result.divergence is not None else VERIFY_INCOMPLETE


def _bus(args: argparse.Namespace) -> int:
    from drivers.bus import DEFAULT_UDP_PORT, parse_bus_spec
    from logs.replay_bus import replay_to_bus

    spec = parse_bus_spec(
        args.bus, fd=args.fd, udp_port=DEFAULT_UDP_PORT if args.udp_port is None else args.udp_port
    )
    stop: threading.Event = args.stop_on_signals()
    path = Path(args.file)
    with _progress(path, "replaying") as progress:
        try:
            r = replay_to_bus(
                path, spec, args.speed, stop, progress, only=args.only, live_devices=args.live_devices
            )
        except RefusedError as err:  # the recording's devices or a master on that bus (logs/replay_bus.py)
            return _fail(args, err)
    problems = "; ".join(r.report.problems)
    if args.json:
        print(
            strict_json(
                {
                    "frames_sent": r.frames_sent,
                    "send_errors": r.send_errors,
                    "duration_s": r.duration_s,
                    "problems": r.report.problems,
                }
            )
        )
    else:
        print(
            f"sent {r.frames_sent} frames onto {spec} in {r.duration_s:.2f} s (speed {args.speed:g}, "
            f"{r.send_errors} send errors)" + (f"; {problems}" if problems else "")
        )
    return 0 if r.frames_sent else 1  # read (or sent) nothing


def _rerun(args: argparse.Namespace) -> int:
    from controller.output_paths import check_output_file
    from logs.rerun_export import export

    try:
        file, out = rerun_input_and_output(args.file, args.rerun)
        if out is not None:
            check_output_file(out, "--rerun")  # before the conversion (Rerun's own error was a traceback)
    except InputError as err:
        return _fail(args, err)
    path = Path(file)
    with _progress(path, "converting") as progress:
        r = export(path, out, spawn=out is None, progress=progress)
    if r.scene_left_out:  # the rest is converted: said, not refused (logs/rerun_export.py)
        print(f"cheope {args.command}: {r.scene_left_out}", file=sys.stderr)
    problems = "; ".join(r.report.problems)
    if r.spawned:
        text = f"sent {r.cycles} cycles to a new Rerun viewer"
    else:
        text = f"wrote {r.output} ({r.cycles} cycles)" + (
            f"; no viewer: {r.note}; open it with: rerun {r.output}" if r.note else ""
        )
    if args.json:
        print(
            strict_json(
                {
                    "output": str(r.output) if r.output else None,
                    "spawned": r.spawned,
                    "cycles": r.cycles,
                    "entities": list(r.entities),
                    "note": r.note,
                    "scene_left_out": r.scene_left_out or None,
                    "problems": r.report.problems,
                }
            )
        )
    else:
        print(text + (f" (input: {problems})" if problems else ""))
    return 0 if r.cycles else 1  # read nothing
