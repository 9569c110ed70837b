"""Log records handed off by the loop's process to a thread that writes them, so a slow stderr cannot stall it.

A logging handler writes under its lock to its stream; a terminal paused with Ctrl-S, a pipe that
its reader stopped reading or a full journal blocks the write, and with it every thread that logs
next: the loop itself, at its next warning (a lost recording, a remote command), or while waiting
for the handler's lock held by a helper that blocked. While a run lasts, ``log_records_off_the_loop``
puts one handler in front of the root logger's: it only queues the record (a bounded queue, never
waited on) and one listener thread (a helper, real-time below the loop: helper_threads.py) hands
it to the handlers that were there. When the queue is full the record is dropped and counted,
and the count is logged once at the end of the run. At the end the queue is written out and the
handlers are put back as they were.
"""

from __future__ import annotations

import logging
import queue
from collections.abc import Iterator
from contextlib import contextmanager
from logging.handlers import QueueHandler, QueueListener

log = logging.getLogger(__name__)

LOG_QUEUE_RECORDS = 1000  # records waiting for a slow stream before new ones are dropped
STOP_TIMEOUT_S = 5.0  # at the end, how long the queue may take to be written out


class DroppingQueueHandler(QueueHandler):
    """Queues a record without waiting; a full queue drops it and counts it."""

    def __init__(self, records: queue.Queue[logging.LogRecord]) -> None:
        super().__init__(records)
        self.dropped = 0

    def enqueue(self, record: logging.LogRecord) -> None:
        try:
            self.queue.put_nowait(record)
        except queue.Full:
            self.dropped += 1


class _Listener(QueueListener):
    """Its ``stop`` waits at most ``STOP_TIMEOUT_S`` for a stream that does not take the records:
    then the (daemon) thread is left behind, the process ends all the same."""

    def stop(self) -> None:
        thread = self._thread  # QueueListener's own
        if thread is None:
            return
        try:
            self.queue.put(self._sentinel, timeout=STOP_TIMEOUT_S)  # type: ignore[attr-defined]
        except queue.Full:
            return
        thread.join(STOP_TIMEOUT_S)
        self._thread = None


@contextmanager
def log_records_off_the_loop(capacity: int = LOG_QUEUE_RECORDS) -> Iterator[DroppingQueueHandler | None]:
    """The root logger's handlers behind a queue and a listener thread for the ``with`` block (module
    text); yields the queueing handler, or None when the root logger has no handler (nothing is written)."""
    root = logging.getLogger()
    handlers = list(root.handlers)
    if not handlers:
        yield None
        return
    records: queue.Queue[logging.LogRecord] = queue.Queue(capacity)
    handoff = DroppingQueueHandler(records)
    listener = _Listener(records, *handlers, respect_handler_level=True)
    listener.start()
    root.handlers = [handoff]
    try:
        yield handoff
    finally:
        root.handlers = handlers
        listener.stop()  # writes out what is queued
        if handoff.dropped:
            log.warning(
                "%d log record(s) dropped during the run: the log's stream did not take them in time",
                handoff.dropped,
            )
