"""``cheope logs list [DIR]``: the sessions recorded in a directory and the files of each.

A long session is split into files (``recording.max_file_size_mb``, ``max_file_duration_s``);
each file names its session and its place in it in the ``cheope.file`` metadata at its start
(logs/session_writer.py). This reads only each file's head (the metadata before the first
chunk) and, for a finished file, its summary: milliseconds per file, whatever its size. A file
without ``cheope.file`` (recorded before files were split) is a session of its own. How each file
ended is ``logs.file_ending``'s word, the one ``logs info`` says too.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from logs import messages as m
from logs.file_ending import FileEnding, file_ending
from logs.reader import MAGIC, LogFileError, read_head, read_info_from_summary


@dataclass(frozen=True)
class SessionFile:
    path: Path
    sequence: int
    size_bytes: int
    finished: bool  # the file ends with its footer (closed by the writer, or rotated)
    duration_s: float | None  # from the summary of a finished file
    ending: FileEnding  # how it ended: a footer is also there when the controller was killed


@dataclass
class Session:
    session_id: str
    started_utc: str
    task: str
    files: list[SessionFile] = field(default_factory=list)

    @property
    def size_bytes(self) -> int:
        return sum(f.size_bytes for f in self.files)

    def missing(self) -> list[int]:
        """Sequence numbers absent between the first and the last file here (deleted by retention, moved)."""
        seqs = {f.sequence for f in self.files}
        return [k for k in range(min(seqs), max(seqs) + 1) if k not in seqs] if seqs else []

    def as_dict(self) -> dict[str, Any]:
        return {
            "session_id": self.session_id,
            "started_utc": self.started_utc,
            "task": self.task,
            "size_bytes": self.size_bytes,
            "missing_sequences": self.missing(),
            "files": [
                {
                    "path": str(f.path),
                    "sequence": f.sequence,
                    "size_bytes": f.size_bytes,
                    "finished": f.finished,
                    "ended": f.ending.word,
                    "duration_s": f.duration_s,
                }
                for f in self.files
            ],
        }


@dataclass(frozen=True)
class SessionListing:
    directory: Path
    sessions: list[Session]
    unreadable: list[str]  # "name: why" for .mcap files that are not recordings


def _ends_with_magic(path: Path, size: int) -> bool:
    if size < 16:
        return False
    try:
        with open(path, "rb") as fh:
            fh.seek(-8, os.SEEK_END)
            return fh.read(8) == MAGIC
    except OSError:
        return False


def list_sessions(directory: str | Path = "") -> SessionListing:
    """The sessions of ``directory`` ('' = the default sessions directory), oldest first."""
    from logs.recorder import default_sessions_directory

    d = Path(directory) if str(directory) else default_sessions_directory()
    if not d.is_dir():
        raise LogFileError(f"{d} is not a directory" if d.exists() else f"{d} does not exist")
    sessions: dict[str, Session] = {}
    unreadable: list[str] = []
    for path in sorted(d.glob("*.mcap")):
        try:
            head = read_head(path)
        except LogFileError as err:
            unreadable.append(f"{path.name}: {err}")
            continue
        file_meta = head.metadata.get(m.META_FILE, {})
        session_meta = head.metadata.get(m.META_SESSION, {})
        sid = file_meta.get("session_id") or session_meta.get("session_id") or f"file:{path.name}"
        seq = int(file_meta.get("sequence", "1")) if file_meta.get("sequence", "1").isdigit() else 1
        finished = _ends_with_magic(path, head.size_bytes)
        try:
            summary = read_info_from_summary(path) if finished else None
        except LogFileError as err:  # a damaged footer or summary: this file, not the whole listing
            unreadable.append(f"{path.name}: {err}")
            continue
        session = sessions.setdefault(
            sid, Session(sid, session_meta.get("started_utc", ""), session_meta.get("task", ""))
        )
        session.files.append(
            SessionFile(
                path,
                seq,
                head.size_bytes,
                finished,
                None if summary is None else summary.duration_s,
                # cheope.recording is written at close: the summary's metadata has it, the head not
                file_ending(head.metadata if summary is None else summary.metadata, finished),
            )
        )
    for s in sessions.values():
        s.files.sort(key=lambda f: f.sequence)
    return SessionListing(
        d, sorted(sessions.values(), key=lambda s: (s.started_utc, s.files[0].path.name)), unreadable
    )


def format_sessions(listing: SessionListing) -> str:
    lines = [
        (
            f"{listing.directory}: {len(listing.sessions)} session(s), "
            f"{sum(s.size_bytes for s in listing.sessions) / 1e6:.1f} MB"
        )
    ]
    for s in listing.sessions:
        sid = s.session_id if s.session_id.startswith("file:") else s.session_id[:12]
        missing = s.missing()
        lines.append(
            f"session {sid}  started {s.started_utc or '?'}  task {s.task or '?'}  "
            f"{len(s.files)} file(s), {s.size_bytes / 1e6:.1f} MB"
            + (f"  (files {', '.join(map(str, missing))} not here)" if missing else "")
        )
        for f in s.files:
            duration = "" if f.duration_s is None else f"{f.duration_s:9.1f} s"
            lines.append(
                f"  {f.sequence:>3}  {f.path.name:<40} {f.size_bytes / 1e6:9.2f} MB {duration:>11}  "
                f"{f.ending.word}"
            )
    lines += [f"not a recording: {u}" for u in listing.unreadable]
    return "\n".join(lines)
