"""``cheope monitor``: subscribe to a controller's state, events and liveliness; show or print them.

``cheope monitor`` watches every controller reachable (``--robot-id '*'``, the default) or
one. With several, the live view is a table of robots (``FleetView``); with one, its whole
state. Finding no controller, it says so in one line on stderr and waits for one.

``MonitorClient`` receives on Zenoh's threads (callbacks with ``indirect=False`` that only
stamp the arrival time and put the sample on a queue) and hands decoded updates to the
caller's thread through ``next_update``. The live view is a rich ``Live`` refreshed in place
by the caller's thread; ``--json`` prints one JSON object per line instead.
"""

from __future__ import annotations

import json
import queue
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Self, TextIO

import zenoh
import zenoh.ext
from google.protobuf.json_format import MessageToDict
from google.protobuf.message import DecodeError

from controller.cli_output import printable
from controller.messages import cheope_pb2 as pb
from controller.monitoring.robot_identity import live_robot_ids
from controller.monitoring.zenoh_session import (
    MonitorKeys,
    SessionSettings,
    ZenohEntity,
    close_session,
    connected,
    declare_event_subscriber,
    open_session,
    source_name,
)

if TYPE_CHECKING:
    from rich.console import Group, RenderableType


MAX_QUEUED = 4096  # samples waiting for the view; beyond, dropped and counted
MAX_SAMPLE_BYTES = 1 << 16  # a state or event message is a few hundred bytes: larger ones are not kept
MAX_ROBOTS = 256  # robots a fleet view shows


@dataclass(frozen=True)
class StateUpdate:
    key: str
    msg: pb.MonitorState
    received_monotonic_s: float


@dataclass(frozen=True)
class EventUpdate:
    key: str
    msg: pb.Event
    received_monotonic_s: float


@dataclass(frozen=True)
class AliveUpdate:
    key: str
    alive: bool  # False: the controller's liveliness token went away (stopped, crashed, unreachable)
    received_monotonic_s: float


@dataclass(frozen=True)
class MissedEventsUpdate:
    key: str  # the events' key of the controller that published them (the subscribed one when unknown)
    count: int  # events that controller published and this monitor never received
    received_monotonic_s: float


@dataclass(frozen=True)
class UndecodableUpdate:
    key: str
    reason: str
    received_monotonic_s: float


@dataclass(frozen=True)
class DroppedSamplesUpdate:
    key: str  # the subscription (``cheope/*``): the samples of any robot under it
    count: int  # samples that found the monitor's queue full since the last such update
    received_monotonic_s: float


Update = (
    StateUpdate | EventUpdate | AliveUpdate | MissedEventsUpdate | UndecodableUpdate | DroppedSamplesUpdate
)


class MonitorClient:
    """Context manager: a Zenoh session subscribed to ``keys``' state, events and liveliness."""

    def __init__(
        self, settings: SessionSettings, keys: MonitorKeys, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self.settings = settings
        self.keys = keys
        self.clock = clock
        # bounded: a peer that publishes faster than the view keeps up (or under thousands of
        # ids) grew an unbounded queue to 1.7 GB in 10 s (an outside tester's finding)
        self._q: queue.Queue[tuple[int, str, object, float]] = queue.Queue(MAX_QUEUED)
        self.dropped = 0  # samples that found the queue full
        self._dropped_told = 0
        self._session: zenoh.Session | None = None
        self._entities: list[ZenohEntity] = []
        self._event_keys: dict[str, str] = {}  # an events publisher's id -> its key (to place its misses)

    def __enter__(self) -> Self:
        self._session, _ = open_session(self.settings)
        z, k = self._session, self.keys
        try:
            self._entities = [
                z.liveliness().declare_subscriber(
                    k.alive, zenoh.handlers.Callback(self._on_alive, indirect=False), history=True
                ),
                z.declare_subscriber(k.state, zenoh.handlers.Callback(self._on_state, indirect=False)),
            ]
            # the last events of each controller at once (joining late), then a count of any missed
            self._entities += declare_event_subscriber(z, k.events, self._on_event, self._on_miss)
        except zenoh.ZError:
            self._session.close()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        close_session(self._session, self._entities)
        self._entities = []
        self._session = None

    # Zenoh's threads: stamp and enqueue, nothing else.
    def _put(self, item: tuple[int, str, object, float]) -> None:
        try:
            self._q.put_nowait(item)
        except queue.Full:
            self.dropped += 1

    def _payload(self, s: zenoh.Sample) -> bytes | int:
        """The sample's bytes, or its size when no state or event message is that large (not kept)."""
        size = len(s.payload)
        return s.payload.to_bytes() if size <= MAX_SAMPLE_BYTES else size

    def _on_state(self, s: zenoh.Sample) -> None:
        self._put((0, str(s.key_expr), self._payload(s), self.clock()))

    def _on_event(self, s: zenoh.Sample) -> None:
        if s.source_info is not None and len(self._event_keys) < MAX_ROBOTS:
            self._event_keys[source_name(s.source_info.source_id)] = str(s.key_expr)
        self._put((1, str(s.key_expr), self._payload(s), self.clock()))

    def _on_miss(self, miss: zenoh.ext.Miss) -> None:
        key = self._event_keys.get(source_name(miss.source), self.keys.events)
        self._put((3, key, miss.nb, self.clock()))

    def _on_alive(self, s: zenoh.Sample) -> None:
        self._put((2, str(s.key_expr), s.kind == zenoh.SampleKind.PUT, self.clock()))

    def reachable(self) -> str:
        """Empty when a controller is there; else one line saying what was not found."""
        assert self._session is not None, "use MonitorClient as a context manager"
        where = ", ".join(self.settings.connect) or "the configured endpoints"
        if self.settings.connect and connected(self._session) == 0:
            return f"nothing answers at {where} yet; waiting for a controller there (Ctrl-C to stop)"
        key_prefix, robot_id = self.keys.prefix.rsplit("/", 1)
        if not live_robot_ids(self._session, key_prefix, robot_id):
            return (
                f"no controller found under {self.keys.prefix}/ (connected to {where}); waiting for one "
                "(Ctrl-C to stop)"
            )
        return ""

    def next_update(self, timeout_s: float) -> Update | None:
        """The next update, or None when nothing arrived within ``timeout_s``."""
        if self.dropped != self._dropped_told:
            lost, self._dropped_told = self.dropped - self._dropped_told, self.dropped
            return DroppedSamplesUpdate(self.keys.prefix, lost, self.clock())
        try:
            kind, key, data, at = self._q.get(timeout=max(0.0, timeout_s))
        except queue.Empty:
            return None
        if isinstance(data, int) and kind in (0, 1):
            return UndecodableUpdate(key, f"{data} bytes: larger than any cheope.v1 state or event", at)
        if kind == 2:
            return AliveUpdate(key, bool(data), at)
        if kind == 3:
            assert isinstance(data, int)
            return MissedEventsUpdate(key, data, at)
        try:
            if kind == 0:
                return StateUpdate(key, pb.MonitorState.FromString(data), at)
            return EventUpdate(key, pb.Event.FromString(data), at)
        except DecodeError as err:
            return UndecodableUpdate(key, f"not a cheope.v1 message: {err}", at)


def update_to_json(u: Update) -> str:
    """One line for ``cheope monitor --json``: a ``type`` field, the key, the arrival time and the message."""
    out: dict[str, object] = {
        "type": {
            StateUpdate: "state",
            EventUpdate: "event",
            AliveUpdate: "liveliness",
            MissedEventsUpdate: "missed_events",
            UndecodableUpdate: "undecodable",
            DroppedSamplesUpdate: "dropped_samples",
        }[type(u)],
        "key": u.key,
        "received_monotonic_s": u.received_monotonic_s,
    }
    if isinstance(u, (StateUpdate, EventUpdate)):
        out.update(
            MessageToDict(
                u.msg,
                preserving_proto_field_name=True,
                always_print_fields_with_no_presence=True,
                unquote_int64_if_possible=True,
            )
        )
    elif isinstance(u, AliveUpdate):
        out["alive"] = u.alive
    elif isinstance(u, (MissedEventsUpdate, DroppedSamplesUpdate)):
        out["count"] = u.count
    else:
        out["reason"] = u.reason
    return json.dumps(out)


@dataclass
class ViewModel:
    """What the live view shows, updated from the stream of updates (pure, testable)."""

    prefix: str
    alive: bool | None = None  # None: not heard of yet
    last_state: pb.MonitorState | None = None
    last_state_at_s: float = 0.0
    arrivals: deque[float] = field(default_factory=lambda: deque(maxlen=512))
    events: deque[str] = field(default_factory=lambda: deque(maxlen=8))
    changes: int = 0  # liveliness transitions seen
    missed_events: int = 0  # events the controller published that never arrived here

    def apply(self, u: Update) -> None:
        if isinstance(u, StateUpdate):
            self.last_state, self.last_state_at_s = u.msg, u.received_monotonic_s
            self.arrivals.append(u.received_monotonic_s)
            if self.alive is None:
                self.alive = True
        elif isinstance(u, EventUpdate):
            sev = severity_name(u.msg.severity)
            self.events.append(f"{u.msg.t_s:9.3f}s {sev:<7} {u.msg.message}")
        elif isinstance(u, AliveUpdate):
            if self.alive is not None and self.alive != u.alive:
                self.changes += 1
            self.alive = u.alive
            self.events.append(f"{'controller up' if u.alive else 'controller gone'} ({u.key})")
        elif isinstance(u, MissedEventsUpdate):
            self.missed_events += u.count
            self.events.append(f"{u.count} event(s) published and not received ({self.missed_events} in all)")

    def sample_rate_hz(self, now_s: float, window_s: float = 1.0) -> float:
        recent = [a for a in self.arrivals if now_s - a <= window_s]
        return len(recent) / window_s


def severity_name(value: int) -> str:
    """A peer's event severity by name, or by number when this build knows no such severity (a
    newer or a broken peer): ``pb.Severity.Name`` raised ``ValueError`` and ended the monitor."""
    return pb.Severity.Name(value) if value in pb.Severity.values() else f"severity {value}"


def _safe(text: str) -> str:
    """A peer's text in a rich table: its markup escaped ("[/bold]" ended the monitor) and its
    control characters as escapes (an ESC from a peer cleared the user's terminal)."""
    from rich.markup import escape

    return escape(printable(text))


def robot_of(key: str) -> str:
    """``<prefix>/<robot_id>/<leaf>`` -> ``robot_id``."""
    return key.rsplit("/", 2)[-2]


@dataclass
class FleetView:
    """One ViewModel per robot seen, by robot id (pure, testable)."""

    key_prefix: str
    robots: dict[str, ViewModel] = field(default_factory=dict)

    unshown: int = 0  # updates of robots beyond MAX_ROBOTS, not shown
    dropped: int = 0  # samples the monitor's queue could not take (DroppedSamplesUpdate)

    def apply(self, u: Update) -> None:
        if isinstance(u, DroppedSamplesUpdate):  # of no one robot: counted in the title
            self.dropped += u.count
            return
        rid = robot_of(u.key)
        if rid not in self.robots:
            if len(self.robots) >= MAX_ROBOTS:  # thousands of ids from one peer: a bounded table
                self.unshown += 1
                return
            self.robots[rid] = ViewModel(f"{self.key_prefix}/{rid}")
        self.robots[rid].apply(u)


def render_fleet(fleet: FleetView, now_s: float) -> RenderableType:
    """The one robot's whole view, or a table with a row per robot."""
    from rich.table import Table

    if len(fleet.robots) == 1:
        return render(next(iter(fleet.robots.values())), now_s)
    more = f", the first {MAX_ROBOTS} shown" if fleet.unshown else ""
    more += f", {fleet.dropped} sample(s) dropped" if fleet.dropped else ""
    table = Table(title=f"controllers under {fleet.key_prefix}/ ({len(fleet.robots)}{more})")
    for col in (
        "robot id",
        "alive",
        "mode",
        "task / phase",
        "cycle [-]",
        "rate [Hz]",
        "late [cycles]",
        "samples [1/s]",
        "alarms",
    ):
        table.add_column(col)
    if not fleet.robots:
        table.add_row("[yellow]waiting for a controller[/]", *([""] * 8))

    # every text a peer sent is shown as it is, never read as rich markup ("[/bold]" in a mode or
    # an event message raised MarkupError and ended the monitor)
    for rid, view in sorted(fleet.robots.items()):
        s = view.last_state
        alive = {None: "?", True: "[green]yes[/]", False: "[red]gone[/]"}[view.alive]
        if s is None:
            table.add_row(_safe(rid), alive, *([""] * 7))
            continue
        table.add_row(
            _safe(rid),
            alive,
            _safe(s.mode),
            _safe(f"{s.task or '-'} / {s.task_phase or '-'}"),
            str(s.cycle),
            f"{s.loop.achieved_rate_hz:.1f}",
            str(s.loop.late_cycles),
            f"{view.sample_rate_hz(now_s):.1f}",
            _safe("; ".join(s.alarms)) or "none",
        )
    return table


def render(view: ViewModel, now_s: float) -> Group:
    from rich.console import Group
    from rich.markup import escape
    from rich.panel import Panel
    from rich.table import Table

    status = {
        None: "[yellow]waiting for the controller[/]",
        True: "[green]alive[/]",
        False: "[red]gone (liveliness token lost)[/]",
    }[view.alive]
    head = Table.grid(padding=(0, 2))
    head.add_column(style="bold")
    head.add_column()
    head.add_row("controller", f"{_safe(view.prefix)}  {status}")
    s = view.last_state
    head.add_row(
        "samples",
        f"{view.sample_rate_hz(now_s):.1f} /s received"
        + (f", last {now_s - view.last_state_at_s:.1f} s ago" if s is not None else ""),
    )
    parts: list[RenderableType] = [head]
    if s is not None:
        head.add_row(
            "loop",
            f"{s.loop.achieved_rate_hz:.1f} Hz, period error p50 {s.loop.period_error_p50_us:.0f} µs "
            f"p99 {s.loop.period_error_p99_us:.0f} µs, late {s.loop.late_cycles} cycles, missing frames "
            f"{s.loop.missing_drive_frames} drive / {s.loop.missing_sensor_frames} sensor",
        )
        head.add_row("mode", _safe(f"{s.mode}   task {s.task or '-'}   phase {s.task_phase or '-'}"))
        head.add_row("cycle", f"{s.cycle}   t {s.t_s:.3f} s")
        head.add_row("TCP", _vec(s.tcp_m, 1e3, "mm"))
        head.add_row("force", _vec(s.force_n, 1.0, "N"))
        axes = Table(title="actuators", expand=False)
        for col in ("axis", "target [mm]", "position [mm]", "target - position [µm]"):
            axes.add_column(col, justify="right")
        # a peer's sample: before every drive answered it may carry targets without positions
        for j, (tg, ps) in enumerate(zip(s.targets, s.positions, strict=False)):
            axes.add_row(str(j + 1), f"{tg * 1e3:.3f}", f"{ps * 1e3:.3f}", f"{(tg - ps) * 1e6:.1f}")
        parts.append(axes)
        parts.append(
            Panel(
                escape("\n".join(printable(a) for a in s.alarms)) if s.alarms else "none",
                title="alarms",
                style="red" if s.alarms else "green",
            )
        )
    parts.append(Panel(escape("\n".join(printable(e) for e in view.events)) or "-", title="events"))
    return Group(*parts)


def _vec(v: Sequence[float], scale: float, unit: str) -> str:
    return "  ".join(f"{x * scale:+.3f}" for x in v) + f" {unit}" if len(v) else "-"


def run_monitor(
    settings: SessionSettings,
    keys: MonitorKeys,
    as_json: bool,
    out: TextIO,
    duration_s: float | None = None,
    count: int | None = None,
    refresh_hz: float = 10.0,
    notice: Callable[[str], None] | None = None,
) -> int:
    """Run until ``duration_s`` elapses, ``count`` state samples arrived, or Ctrl-C; returns samples seen.

    ``notice`` gets one line when no controller is found at the start (the monitor then waits)."""
    seen = 0
    deadline = time.monotonic() + duration_s if duration_s is not None else None
    with MonitorClient(settings, keys) as client:
        missing = client.reachable()
        if missing and notice is not None:
            notice(missing)
        if as_json:
            while count is None or seen < count:
                left = 0.5 if deadline is None else deadline - time.monotonic()
                if left <= 0:
                    break
                u = client.next_update(min(left, 0.5))
                if u is None:
                    continue
                seen += isinstance(u, StateUpdate)
                out.write(update_to_json(u) + "\n")
                out.flush()
            return seen
        from rich.console import Console
        from rich.live import Live

        view = FleetView(keys.prefix.rsplit("/", 1)[0])
        period = 1.0 / refresh_hz
        with Live(
            render_fleet(view, time.monotonic()),
            console=Console(file=out),
            auto_refresh=False,
            transient=False,
        ) as live:
            next_draw = time.monotonic()
            while count is None or seen < count:
                now = time.monotonic()
                if deadline is not None and now >= deadline:
                    break
                u = client.next_update(max(0.0, next_draw - now))
                if u is not None:
                    view.apply(u)
                    seen += isinstance(u, StateUpdate)
                if time.monotonic() >= next_draw:
                    live.update(render_fleet(view, time.monotonic()), refresh=True)
                    next_draw = time.monotonic() + period
    return seen
