"""``rerun-importer-cheope``: the Rerun viewer draws the robot of a cheope recording it opens.

The viewer runs every executable on ``PATH`` whose name starts with ``rerun-importer-`` for each
file it opens, passing the file and its recording id; this one (a console script of the package:
``.venv/bin`` on ``PATH``, e.g. an activated venv) answers a cheope recording with what ``cheope
replay FILE --rerun`` draws (logs/rerun_export.py: the robot under ``/world``, the plots, the
events, the blueprint) on standard output, in the viewer's own recording beside its MCAP
channels; any other file with exit code 66, "not mine", so the viewer's other importers decide.

    rerun FILE.mcap        # with the venv's bin on PATH
"""

from __future__ import annotations

import argparse
import sys

INCOMPATIBLE = (
    66  # rerun.EXTERNAL_IMPORTER_INCOMPATIBLE_EXIT_CODE, without importing rerun for a file not ours
)


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="rerun-importer-cheope", description=__doc__.split("\n\n")[0])
    ap.add_argument("filepath", help="the file the viewer opens")
    ap.add_argument("--application-id", help="the viewer's application id for it")
    ap.add_argument("--recording-id", help="the viewer's recording id for it: the robot joins that recording")
    # passed by the viewer, not used: the robot's entities keep their own paths and timelines
    for flag in (
        "--entity-path-prefix",
        "--time_sequence",
        "--time_duration_nanos",
        "--time_timestamp_nanos",
    ):
        ap.add_argument(flag, action="append", help=argparse.SUPPRESS)
    ap.add_argument("--static", action="store_true", help=argparse.SUPPRESS)
    return ap


def is_cheope_recording(path: str) -> bool:
    """An MCAP file whose metadata holds a cheope configuration (read from its start only)."""
    from pathlib import Path

    from logs import messages as m
    from logs.reader import LogFileError
    from logs.rerun_export import leading_metadata

    try:
        return m.META_CONFIG in leading_metadata(Path(path)).metadata
    except (LogFileError, OSError):
        return False


def main(argv: list[str] | None = None) -> int:
    args, _ = parser().parse_known_args(argv)  # a newer viewer's unknown flags are no reason to fail
    if not args.filepath.endswith(".mcap") or not is_cheope_recording(args.filepath):
        return INCOMPATIBLE
    from logs.reader import LogFileError
    from logs.rerun_export import APP_ID, StdoutStream, export

    try:
        r = export(args.filepath, stdout=StdoutStream(args.application_id or APP_ID, args.recording_id))
    except LogFileError as err:  # no readable cycle: the viewer's MCAP importer still shows what there is
        print(f"rerun-importer-cheope: {err}", file=sys.stderr)
        return INCOMPATIBLE
    if r.scene_left_out:  # standard output is the viewer's data: the word goes to stderr
        print(f"rerun-importer-cheope: {r.scene_left_out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
