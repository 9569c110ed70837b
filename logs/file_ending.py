"""How a recording's file ended, in one word that ``logs list`` and ``logs info`` both say.

The footer alone does not tell: a controller killed with SIGKILL closes the writer's pipe and the
writer still finishes the file (logs/session_writer.py), so the file of a killed session ends
with its footer as a closed one does, and ``logs list`` called it "finished". What tells them
apart is the ``cheope.recording`` record the writer adds at close: ``queued`` is the count the
recorder's END carried, or ``unknown`` with ``ended`` saying why when no END came; ``next`` names
the file a rotation went on in; ``stopped`` why the writer stopped the recording itself.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from logs.messages import META_RECORDING

FINISHED = "finished"
NOT_CLOSED = "not closed"
STOPPED = "stopped"
OPEN_OR_CUT_SHORT = "open or cut short"


@dataclass(frozen=True)
class FileEnding:
    word: str  # one of the four above
    why: str  # what the file says about it ("" when it says nothing more)

    def __str__(self) -> str:
        return f"{self.word}: {self.why}" if self.why else self.word


def file_ending(metadata: Mapping[str, Mapping[str, str]], has_footer: bool) -> FileEnding:
    """How the file of ``metadata`` (its ``cheope.recording`` record, read with the rest) ended."""
    if not has_footer:
        return FileEnding(OPEN_OR_CUT_SHORT, "no footer: still being written, or its writer was killed")
    recording = metadata.get(META_RECORDING)
    if recording is None:  # an older file, or one another tool wrote: the footer is all there is
        return FileEnding(FINISHED, "")
    if recording.get("next"):
        return FileEnding(FINISHED, f"the session goes on in {recording['next']}")
    # before the missing END: a writer that stops the recording itself stops reading, so no END
    # comes either, and its reason is the one to name
    if recording.get("stopped"):
        return FileEnding(STOPPED, f"the writer stopped the recording: {recording['stopped']}")
    if recording.get("queued") == "unknown" or "ended" in recording:
        return FileEnding(
            NOT_CLOSED,
            "the controller ended without closing the recording (killed or crashed); "
            "the file holds what it had handed over",
        )
    return FileEnding(FINISHED, "closed by its controller")
