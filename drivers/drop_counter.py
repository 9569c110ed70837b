"""A count of what a receiver dropped, named in a log warning at most every few seconds.

A flood of foreign datagrams or malformed frames must not flood the log nor cost the receiver a
log record each: the count says how many, the warning names the last one, at most every
``every_s`` (the first at once).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

DEFAULT_WARN_EVERY_S = 5.0


class DropCounter:
    """``count`` of dropped items; ``add(*details)`` counts one and warns ``message % (count, *details)``
    when the last warning is ``every_s`` old."""

    def __init__(
        self,
        logger: logging.Logger,
        message: str,
        every_s: float = DEFAULT_WARN_EVERY_S,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.logger = logger
        self.message = message  # its first %d is the count so far
        self.every_s = every_s
        self.clock = clock
        self.count = 0
        self._warned_s = -float("inf")

    def add(self, *details: object) -> None:
        self.count += 1
        now = self.clock()
        if now - self._warned_s >= self.every_s:
            self._warned_s = now
            self.logger.warning(self.message, self.count, *details)
