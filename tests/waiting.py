"""Waiting in tests: on an event, or on a condition with a generous deadline; never a fixed sleep.

A deadline here is a bound for a test that would otherwise hang, not a timing requirement:
the tests assert what happened, never how long it took (timing is `cheope bench`'s job).
"""

from __future__ import annotations

import os
import select
import subprocess
import time
from collections.abc import Callable
from typing import TypeVar

T = TypeVar("T")

GENEROUS_S = 60.0  # a loaded two-core CI machine runs several processes at once


def wait_until(
    condition: Callable[[], T], what: str, timeout_s: float = GENEROUS_S, poll_s: float = 0.02
) -> T:
    """The first truthy value of ``condition()``, polled until ``timeout_s``; else fail naming ``what``.

    For conditions nothing signals (a file's size, an SDO object): the poll interval only paces
    the checks, the deadline only stops a hung test.
    """
    deadline = time.monotonic() + timeout_s
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() >= deadline:
            raise AssertionError(f"{what}: not within {timeout_s} s")
        time.sleep(poll_s)


def wait_for_exit(pid: int, what: str, timeout_s: float = GENEROUS_S) -> None:
    """Wait for any process (not only a child) to end: a pidfd becomes readable when it does."""
    try:
        fd = os.pidfd_open(pid)
    except ProcessLookupError:
        return  # already gone
    except OSError:  # a kernel without pidfd (before 5.3): poll for it instead

        def gone() -> bool:
            try:
                os.kill(pid, 0)
            except ProcessLookupError:
                return True
            return False

        wait_until(gone, what, timeout_s, poll_s=0.05)
        return
    try:
        readable, _, _ = select.select([fd], [], [], timeout_s)
        assert readable, f"{what}: not within {timeout_s} s"
    finally:
        os.close(fd)


class ProcessLines:
    """The lines a child process writes to its stdout pipe, waited for with ``select`` on the raw fd.

    Reads the file descriptor itself (no text-mode buffer that could hold lines ``select`` cannot
    see); do not mix with ``proc.stdout.readline()``.
    """

    def __init__(self, proc: subprocess.Popen) -> None:
        assert proc.stdout is not None
        self.proc = proc
        self.fd = proc.stdout.fileno()
        self.buffer = b""
        self.lines: list[str] = []  # every line read so far

    def next_matching(self, accept: Callable[[str], bool], what: str, timeout_s: float = GENEROUS_S) -> str:
        """The next line for which ``accept`` is true; fail at the deadline or at the end of the output."""
        deadline = time.monotonic() + timeout_s
        while True:
            while b"\n" in self.buffer:
                raw, self.buffer = self.buffer.split(b"\n", 1)
                line = raw.decode(errors="replace")
                self.lines.append(line)
                if accept(line):
                    return line
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise AssertionError(f"{what}: not within {timeout_s} s; output so far {self.lines[-5:]}")
            readable, _, _ = select.select([self.fd], [], [], remaining)
            if readable:
                chunk = os.read(self.fd, 65536)
                if not chunk:
                    raise AssertionError(
                        f"{what}: the process ended its output (exit {self.proc.poll()}); "
                        f"last lines {self.lines[-5:]}"
                    )
                self.buffer += chunk
