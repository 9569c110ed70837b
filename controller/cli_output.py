"""What the command line prints besides its results: strict JSON, and a progress line on a terminal.

``--json`` output is read by programs, so it is strict JSON (RFC 8259): a NaN or an infinity in a
report (a plan that did not converge, an empty statistic) becomes ``null`` rather than Python's
``NaN`` token, which ``jq``, JavaScript and most parsers reject.

A command that runs for more than a couple of seconds says where it is on one line of stderr,
redrawn in place with the time elapsed, and erased at the end; only when stderr is a terminal,
so pipes, files and ``--json`` consumers see nothing of it.

Text from elsewhere (a peer's mode, event or answer over Zenoh) is printed through ``printable``:
its control characters as escapes, so that a peer cannot clear or recolour the user's terminal.
"""

from __future__ import annotations

import json
import math
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import IO, Any

TICK_S = 0.5  # how often the elapsed time is redrawn between the command's own updates
_ERASE = "\r\x1b[K"  # carriage return, erase to the end of the line


def finite_or_none(value: Any) -> Any:
    """``value`` with every NaN and infinity, at any depth of dicts, lists and tuples, as None."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: finite_or_none(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_or_none(v) for v in value]
    return value


def printable(text: str, limit: int = 400) -> str:
    """``text`` from a peer, safe on a terminal: each character that is not printable (ESC, the
    other controls, line breaks) as its Python escape, and at most ``limit`` characters of it."""
    if len(text) > limit:
        text = text[:limit] + f"... ({len(text)} characters)"
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


def strict_json(value: Any, indent: int | None = None) -> str:
    """One JSON document that strict parsers accept: non-finite numbers as null."""
    return json.dumps(finite_or_none(value), allow_nan=False, indent=indent)


class ProgressLine:
    """``label: 12 s  TEXT`` on ``stream``, redrawn every ``TICK_S`` and on ``update``; silent off a terminal."""

    def __init__(
        self, label: str, stream: IO[str] | None = None, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self.stream = stream if stream is not None else sys.stderr
        self.label = label
        self.enabled = self.stream.isatty()
        self._clock = clock
        self._start = clock()
        self._text = ""
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._ticker: threading.Thread | None = None

    def line(self) -> str:
        elapsed = self._clock() - self._start
        return f"{self.label}: {elapsed:.0f} s" + (f"  {self._text}" if self._text else "")

    def update(self, text: str) -> None:
        self._text = text
        self._draw()

    def _draw(self) -> None:
        if not self.enabled:
            return
        with self._lock:
            self.stream.write(_ERASE + self.line())
            self.stream.flush()

    def _tick(self) -> None:
        while not self._stop.wait(TICK_S):
            self._draw()

    def start(self) -> None:
        if self.enabled and self._ticker is None:
            self._draw()
            self._ticker = threading.Thread(target=self._tick, name="progress-line", daemon=True)
            self._ticker.start()

    def close(self) -> None:
        self._stop.set()
        if self._ticker is not None:
            self._ticker.join()
        if self.enabled:
            with self._lock:
                self.stream.write(_ERASE)
                self.stream.flush()


@contextmanager
def progress_line(label: str, stream: IO[str] | None = None) -> Iterator[Callable[[str], None]]:
    """A ``ProgressLine`` for the ``with`` block; yields its ``update``."""
    progress = ProgressLine(label, stream)
    progress.start()
    try:
        yield progress.update
    finally:
        progress.close()
