"""Answering Zenoh queries beside the loop, with a bound on what they can cost it.

A queryable whose handler is a Python callback runs Python on one of Zenoh's threads for
every query that arrives: it takes the GIL the loop needs at its deadline, as often as
anyone cares to ask. A flood of 4 722 garbage queries in 5 s raised the late cycles of a run
from 30-105 to 596 in that window (issue 18). Here instead:

- the queryable's handler is a ``zenoh.handlers.RingChannel`` of ``capacity`` queries: Zenoh
  (Rust, no GIL) keeps the newest ones and drops the rest; a dropped query is finalised
  by Zenoh, so its sender gets an empty answer rather than a hang;
- one Python thread per queryable takes them out with the channel's blocking ``recv``, which
  waits in Rust with the GIL released: an idle server never wakes;
- that thread answers at most ``rate_hz`` queries a second (a token bucket of ``burst``):
  between two answers it sleeps, GIL released, so a flood costs the loop's process at most
  ``rate_hz`` short GIL holds a second, whatever the flood's rate;
- nothing of it runs on the loop's thread, and nothing of it grows: the ring is fixed, the
  thread logs refused queries in one summary line at most every ``log_every_s``.

The loop only ever reads what the handlers leave for it (an event, a deque of at most 16
accepted commands), one entry per cycle.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import zenoh

from controller.monitoring.zenoh_session import ZenohEntity

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class QueryLimits:
    """What a queryable's server may cost: queries kept waiting, answers per second, burst."""

    capacity: int = 8  # queries the Rust ring keeps; older ones are dropped there
    rate_hz: float = 20.0  # answered queries per second, sustained
    burst: int = 5  # answered back to back before the rate applies
    log_every_s: float = 5.0  # at most one summary line of refused queries this often

    def __post_init__(self) -> None:
        if self.capacity < 1 or self.burst < 1 or not self.rate_hz > 0.0 or not self.log_every_s > 0.0:
            raise ValueError(
                f"query limits {self}: capacity and burst must be >= 1, rate_hz and log_every_s > 0"
            )


class TokenBucket:
    """``burst`` tokens, refilled at ``rate_hz``; ``wait`` sleeps until one is there and takes it."""

    def __init__(
        self,
        rate_hz: float,
        burst: int,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        self.rate_hz = rate_hz
        self.burst = float(burst)
        self.clock = clock
        self.sleep = sleep
        self.tokens = float(burst)
        self.at_s = clock()

    def _refill(self) -> None:
        now = self.clock()
        self.tokens = min(self.burst, self.tokens + (now - self.at_s) * self.rate_hz)
        self.at_s = now

    def wait(self) -> None:
        self._refill()
        if self.tokens < 1.0:
            self.sleep((1.0 - self.tokens) / self.rate_hz)
            self._refill()
        self.tokens = max(0.0, self.tokens - 1.0)


QueryHandler = Callable[[zenoh.Query], bool]  # answers one query; False: it was refused (counted, logged)


class QueryServer:
    """A queryable on ``key`` served by one rate-limited thread; ``close`` undeclares and joins it."""

    def __init__(
        self, session: zenoh.Session, key: str, handle: QueryHandler, limits: QueryLimits, name: str
    ) -> None:
        self.key = key
        self.limits = limits
        self.answered = 0  # written by the server's thread only
        self.refused = 0
        self._handle = handle
        self._bucket = TokenBucket(limits.rate_hz, limits.burst)
        self._queryable = session.declare_queryable(key, zenoh.handlers.RingChannel(limits.capacity))
        self._thread = threading.Thread(target=self._serve, name=name, daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        handler = self._queryable.handler
        refused_logged = 0
        next_log_s = 0.0
        while True:
            try:
                query = handler.recv()  # blocks in Rust, GIL released; ends when the queryable is undeclared
            except zenoh.ZError:
                break
            self._bucket.wait()
            with query:  # finalised on leaving: the sender's get ends without waiting for its timeout
                try:
                    ok = self._handle(query)
                except Exception:  # a query must never end the server (nor reach the loop)
                    log.exception("monitoring: answering a query on %s failed", self.key)
                    ok = False
            self.answered += ok
            self.refused += not ok
            now = time.monotonic()
            if self.refused > refused_logged and now >= next_log_s:
                log.info(
                    "monitoring: %d query(ies) on %s refused so far (answered %d)",
                    self.refused,
                    self.key,
                    self.answered,
                )
                refused_logged, next_log_s = self.refused, now + self.limits.log_every_s

    def close(self, timeout_s: float = 5.0) -> None:
        queryable: ZenohEntity = self._queryable  # zenoh's undeclare is unannotated
        queryable.undeclare()
        self._thread.join(timeout_s)
        if self._thread.is_alive():
            log.warning("monitoring: the query server of %s did not end within %g s", self.key, timeout_s)
