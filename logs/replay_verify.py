"""``cheope replay FILE --verify``: the recorded inputs through today's step, bit for bit.

The control law is pure (``step(state, inputs, t)``), so a session is fully determined by
its configuration and the inputs of each cycle. The law is rebuilt with
``build_law(recorded_config_from_dict(<cheope.config metadata>))`` (``--set`` overrides apply on top,
to see what a change would do), started from ``law.initial_state()``, and fed every recorded
``CycleInputs`` with the recorded ``t`` (the loop may skip cycles: ``t`` is what it passed).
Each cycle's outputs, state sample and events must equal the recorded ones exactly (doubles
compared bit for bit); the first difference is reported with its cycle, field and both values.

A cycle the recorder dropped (a gap in the ``/cycle`` MCAP sequence numbers) ends the check
there: the state after it cannot be known. A damaged file is verified up to its damage.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from controller.config import ConfigError, recorded_config_from_dict, set_dotted
from controller.messages import cheope_pb2 as pb
from logs import messages as m
from logs.reader import LogFileError, ReadReport, iter_decoded, read_info

if TYPE_CHECKING:
    from controller.core.cycle_data import Event


@dataclass(frozen=True)
class Divergence:
    cycle: int
    t_s: float
    field: str
    recorded: str
    recomputed: str

    def __str__(self) -> str:
        return (f"cycle {self.cycle} (t = {self.t_s!r} s): {self.field}: recorded {self.recorded}, "
                f"recomputed {self.recomputed}")


@dataclass
class VerifyResult:
    path: Path
    cycles_checked: int = 0
    divergence: Divergence | None = None
    problems: list[str] = field(default_factory=list)  # what limited the check (damage, drops)
    report: ReadReport | None = None

    @property
    def ok(self) -> bool:
        return self.divergence is None and self.cycles_checked > 0

    def summary(self) -> str:
        if self.divergence is not None:
            return (f"DIVERGES after {self.cycles_checked} identical cycle(s): first difference at "
                    f"{self.divergence}")
        if self.cycles_checked == 0:
            return "nothing verified: " + ("; ".join(self.problems) or "the recording has no cycles")
        text = f"OK: {self.cycles_checked} cycle(s) reproduced bit for bit"
        return text + (f" (check limited: {'; '.join(self.problems)})" if self.problems else "")


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v!r} ({v.hex()})"
    return repr(v)


class _Compare:
    def __init__(self, cycle: int, t: float) -> None:
        self.cycle, self.t = cycle, t
        self.diff: Divergence | None = None

    def value(self, name: str, rec: Any, new: Any) -> None:
        if self.diff is not None:
            return
        same = m.same_double(rec, new) if isinstance(rec, float) and isinstance(new, float) else rec == new
        if not same:
            self.diff = Divergence(self.cycle, self.t, name, _fmt(rec), _fmt(new))

    def seq(self, name: str, rec: Any, new: Any) -> None:
        rec, new = list(rec), list(new)
        if len(rec) != len(new):
            self.value(f"{name} (length)", len(rec), len(new))
            if self.diff is not None:
                self.diff = Divergence(self.cycle, self.t, name, repr(rec), repr(new))
            return
        for i, (a, b) in enumerate(zip(rec, new)):
            self.value(f"{name}[{i}]", float(a) if isinstance(b, float) else a, b)


def _compare_cycle(c: _Compare, rec: pb.Cycle, state: Any, outputs: Any) -> None:
    c.seq("outputs.controlwords", rec.outputs.controlwords, outputs.controlwords)
    c.seq("outputs.targets", rec.outputs.targets, outputs.targets)
    st = rec.state
    c.value("state.mode", st.mode, state.mode.name)
    c.seq("state.setpoint_position", st.setpoint_position, state.setpoint.position)
    c.seq("state.setpoint_velocity", st.setpoint_velocity, state.setpoint.velocity)
    c.seq("state.setpoint_acceleration", st.setpoint_acceleration, state.setpoint.acceleration)
    c.seq("state.tcp_reference_m", st.tcp_reference_m, state.tcp_reference_m or ())
    c.seq("state.tcp_measured_m", st.tcp_measured_m, state.tcp_measured_m or ())
    c.value("state.fault_reason", st.fault_reason, state.fault_reason)


def _compare_events(c: _Compare, rec: list[pb.Event], new: tuple[Event, ...]) -> None:
    c.value("events", [e.message for e in rec], [e.message for e in new])
    for i, (a, b) in enumerate(zip(rec, new)):
        c.value(f"events[{i}].kind", a.kind, b.kind)
        c.value(f"events[{i}].severity", int(a.severity), int(b.severity))


def _law_from(report: ReadReport, overrides: dict[str, Any]) -> Any:
    from controller.assembly import build_law

    meta = report.metadata.get(m.META_CONFIG)
    if meta is None or "json" not in meta:
        raise LogFileError(f"{report.path} has no {m.META_CONFIG} metadata: the law cannot be rebuilt")
    table = json.loads(meta["json"])
    for key, value in overrides.items():
        set_dotted(table, key, value)
    try:
        return build_law(recorded_config_from_dict(table))
    except ConfigError as err:
        raise LogFileError(f"the configuration recorded in {report.path} does not load any more: {err}") from err


def verify(path: str | Path, overrides: dict[str, Any] | None = None,
           progress: Callable[[int], None] | None = None) -> VerifyResult:
    """Replay ``path``'s inputs through a law rebuilt from its configuration; see the module doc."""
    path = Path(path)
    result = VerifyResult(path)
    report = ReadReport(path)
    result.report = report
    law = state = None
    pending: tuple[pb.Cycle, tuple[Event, ...]] | None = None  # the last cycle, waiting for its recorded events
    rec_events: list[pb.Event] = []
    next_seq = 0

    def settle() -> bool:
        """Compare the pending cycle's events; True when it diverged."""
        nonlocal pending
        if pending is None:
            return False
        rec, new_events = pending
        c = _Compare(rec.cycle, rec.t_s)
        _compare_events(c, rec_events, new_events)
        pending = None
        rec_events.clear()
        if c.diff is not None:
            result.divergence = c.diff
            result.cycles_checked -= 1
            return True
        return False

    for d in iter_decoded(path, (m.TOPIC_CYCLE, m.TOPIC_EVENTS), report):
        if d.topic == m.TOPIC_EVENTS:
            if pending is not None and d.message.cycle == pending[0].cycle and d.message.kind != "recorder_drop":
                rec_events.append(d.message)
            continue
        if settle():
            return result
        rec: pb.Cycle = d.message
        if d.sequence != next_seq:
            why = "lost in a damaged chunk" if report.damaged_chunks else "dropped by the recorder"
            result.problems.append(
                f"{d.sequence - next_seq} cycle(s) {why} before cycle {rec.cycle}: verified up to there"
                if d.sequence > next_seq else f"cycle sequence restarts at {d.sequence} (cycle {rec.cycle})")
            break
        next_seq += 1
        if law is None:
            if m.META_CONFIG not in report.metadata:  # a file with its metadata at the end
                report.metadata.update(read_info(path).metadata)
            law = _law_from(report, overrides or {})
            state = law.initial_state()
        state, outputs, events = law.step(state, m.inputs_from_pb(rec.inputs), rec.t_s)
        c = _Compare(rec.cycle, rec.t_s)
        _compare_cycle(c, rec, state, outputs)
        if c.diff is not None:
            result.divergence = c.diff
            return result
        result.cycles_checked += 1
        pending = (rec, events)
        if progress is not None and result.cycles_checked % 2000 == 0:
            progress(report.end_offset)
    settle()
    result.problems.extend(report.problems)
    return result
