"""``cheope replay FILE --verify``: the recorded inputs through today's step, bit for bit.

The control law is pure (``step(state, inputs, t)``), so a session is fully determined by
its configuration and the inputs of each cycle. The law is rebuilt with
``build_law(recorded_config_from_dict(<cheope.config metadata>))`` (``--set`` overrides apply on top,
to see what a change would do), started from ``law.initial_state()``, and fed every recorded
``CycleInputs`` with the recorded ``t`` (the loop may skip cycles: ``t`` is what it passed).
Each cycle's outputs, state sample and events must equal the recorded ones exactly (doubles
compared bit for bit); the first difference is reported with its cycle, field and both values.

A long session is split into files (logs/session_writer.py); every file after the first starts
with a keyframe: the law's whole state after the last cycle of the file before (logs/keyframe.py).
A file alone is verified from its keyframe; several files of one session (any order: they are
sorted by their ``cheope.file`` sequence, and must be consecutive) are verified across the
boundaries, each keyframe checked against the state replayed up to it.

A cycle missing (a gap in the ``/cycle`` MCAP sequence numbers) ends the check of that file
there: the state after it cannot be known; the gap is named by what the file says (a damaged
chunk, the damaged original of a recovered file, the recorder's drops). A damaged file is
verified up to its damage. The next file of a session is verified again from its keyframe.
``VerifyResult.ok`` is True only when every readable cycle of the files was reproduced and
nothing limited the check; ``summary()`` says how much was verified otherwise.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from controller.config import ConfigError, recorded_config_from_dict, set_dotted
from controller.messages import cheope_pb2 as pb
from logs import messages as m
from logs.keyframe import ENCODINGS as KEYFRAME_ENCODINGS
from logs.keyframe import KeyframeError, decode_state, encode_state
from logs.reader import LogFileError, ReadReport, iter_decoded, read_head, read_info, recorded_config_table

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
        return (
            f"cycle {self.cycle} (t = {self.t_s!r} s): {self.field}: recorded {self.recorded}, "
            f"recomputed {self.recomputed}"
        )


@dataclass
class VerifyResult:
    path: Path  # the first file given
    cycles_checked: int = 0
    cycles_recorded: int = 0  # readable /cycle messages in the files given
    divergence: Divergence | None = None
    problems: list[str] = field(
        default_factory=list
    )  # what limited the check (damage, drops, a missing keyframe)
    report: ReadReport | None = None  # the last file's
    files: list[Path] = field(default_factory=list)  # in session order
    started_from: str = ""  # "the initial state" or the keyframe a file alone starts from
    first_cycle: int | None = None
    last_cycle: int | None = None  # the last cycle reproduced
    resumed: list[str] = field(default_factory=list)  # keyframes the check started again from, after a gap
    continues_in: str = ""  # the session's next file, when the last file given names one

    @property
    def ok(self) -> bool:
        """Every recorded cycle of the files given reproduced, nothing in the way."""
        return (
            self.divergence is None
            and self.cycles_checked > 0
            and not self.problems
            and self.cycles_checked == self.cycles_recorded
        )

    def _span(self) -> str:
        if self.first_cycle is None:
            return ""
        return f"cycles {self.first_cycle}..{self.last_cycle}"

    def summary(self) -> str:
        where = f" in {len(self.files)} files" if len(self.files) > 1 else ""
        if self.divergence is not None:
            return (
                f"DIVERGES after {self.cycles_checked} identical cycle(s){where}: first difference at "
                f"{self.divergence}"
            )
        if self.cycles_checked == 0:
            return "NOT VERIFIED: nothing verified: " + (
                "; ".join(self.problems) or "the recording has no cycles"
            )
        start = f" from {self.started_from}" if self.started_from else ""
        if self.resumed:
            start += f", again from {', '.join(self.resumed)}"
        if self.continues_in:
            start += f" (the session goes on in {self.continues_in})"
        if self.ok:
            return f"OK: {self.cycles_checked} cycle(s) reproduced bit for bit{where}{start}"
        if self.cycles_checked == self.cycles_recorded:
            what = f"the {self.cycles_checked} readable cycle(s) ({self._span()})"
        else:
            share = 100.0 * self.cycles_checked / self.cycles_recorded if self.cycles_recorded else 0.0
            what = (
                f"{self.cycles_checked} of the {self.cycles_recorded} readable cycle(s) ({share:.1f} %, "
                f"{self._span()})"
            )
        return (
            f"PARTLY VERIFIED: {what} reproduced bit for bit{where}{start}; not checked: "
            f"{'; '.join(self.problems) or 'cycles past the end of the check'}"
        )


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
        for i, (a, b) in enumerate(zip(rec, new, strict=True)):
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
    # a different count is already the divergence above; compare what both have
    for i, (a, b) in enumerate(zip(rec, new, strict=False)):
        c.value(f"events[{i}].kind", a.kind, b.kind)
        c.value(f"events[{i}].severity", int(a.severity), int(b.severity))


def _law_from(report: ReadReport, overrides: dict[str, Any]) -> Any:
    from controller.assembly import build_law

    table = recorded_config_table(report)
    if table is None:
        raise LogFileError(f"{report.path} has no {m.META_CONFIG} metadata: the law cannot be rebuilt")
    for key, value in overrides.items():
        set_dotted(table, key, value)
    try:
        return build_law(recorded_config_from_dict(table))
    except ConfigError as err:
        if overrides:  # the user's --set may be what is wrong, not the recording
            raise ConfigError(
                f"the configuration recorded in {report.path} with --set {', '.join(overrides)}: {err}"
            ) from err
        raise LogFileError(
            f"the configuration recorded in {report.path} does not load any more: {err}"
        ) from err


def verify(
    paths: str | Path | Sequence[str | Path],
    overrides: dict[str, Any] | None = None,
    progress: Callable[[int], None] | None = None,
) -> VerifyResult:
    """Replay the inputs of ``paths`` (one file, or files of one session in any order) through a
    law rebuilt from the recorded configuration; see the module doc."""
    files = session_order([Path(p) for p in ([paths] if isinstance(paths, (str, Path)) else paths)])
    result = VerifyResult(files[0], files=files)
    run = _Run(result, overrides or {}, progress)
    for i, path in enumerate(files):
        if run.file(path):
            continue
        if result.divergence is not None:
            run.count_rest(files[i + 1 :])
            break
        run.state = run.next_seq = None  # the state is lost here: the next file starts from its keyframe
    if result.report is not None and result.divergence is None:
        result.continues_in = result.report.metadata.get(m.META_RECORDING, {}).get("next", "")
    return result


def session_order(paths: list[Path]) -> list[Path]:
    """``paths`` in the order of their session (``cheope.file`` sequence); ``LogFileError`` when they
    are not consecutive files of one session."""
    if len(paths) == 1:
        return paths
    keyed = []
    for p in paths:
        meta = read_head(p).metadata.get(m.META_FILE)
        if meta is None:
            raise LogFileError(
                f"{p} has no {m.META_FILE} metadata: it is not a file of a split session, verify it alone"
            )
        keyed.append((int(meta.get("sequence", "0")), meta.get("session_id", ""), p))
    keyed.sort(key=lambda k: k[0])
    sessions = {k[1] for k in keyed}
    if len(sessions) > 1:
        raise LogFileError(
            "the files are of different sessions: "
            + ", ".join(f"{p.name} of {sid[:8]}" for _, sid, p in keyed)
        )
    for (a, _, pa), (b, _, pb_) in itertools.pairwise(keyed):
        if b != a + 1:
            raise LogFileError(
                f"{pa.name} is file {a} of its session and {pb_.name} file {b}: "
                + ("the same file twice" if a == b else f"file {a + 1} is missing")
            )
    return [k[2] for k in keyed]


class _Run:
    """The replay's state across the files of a session."""

    def __init__(
        self, result: VerifyResult, overrides: dict[str, Any], progress: Callable[[int], None] | None
    ) -> None:
        self.result = result
        self.overrides = overrides
        self.progress = progress
        self.law: Any = None
        self.state: Any = None
        self.next_seq: int | None = None
        self.stopped_in: Path | None = None  # the file whose rest was not checked

    def _build_law(self, report: ReadReport, path: Path) -> None:
        if self.law is None:
            if m.META_CONFIG not in report.metadata:  # a file with its metadata at the end
                report.metadata.update(read_info(path).metadata)
            self.law = _law_from(report, self.overrides)

    def file(self, path: Path) -> bool:  # noqa: C901  (every way one file of a session can start, continue or end)
        """Verify one file on from where the last one ended; False when the check ends here."""
        result = self.result
        report = ReadReport(path)
        result.report = report
        pending: tuple[pb.Cycle, tuple[Event, ...]] | None = None  # the last cycle, waiting for its events
        rec_events: list[pb.Event] = []
        gap: tuple[int, int] | None = None  # (cycles missing, the cycle after them)
        saw_drop = False  # a recorder_drop event: the recorder's own word that it dropped cycles

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

        decoded = iter_decoded(path, (m.TOPIC_CYCLE, m.TOPIC_EVENTS, m.TOPIC_KEYFRAME), report)
        for d in decoded:
            if d.topic == m.TOPIC_KEYFRAME:
                if not self._keyframe(path, report, d.message):
                    return False
                continue
            if d.topic == m.TOPIC_EVENTS:
                saw_drop = saw_drop or d.message.kind == "recorder_drop"
                if (
                    pending is not None
                    and d.message.cycle == pending[0].cycle
                    and d.message.kind not in m.RECORDER_EVENT_KINDS
                ):
                    rec_events.append(d.message)
                continue
            result.cycles_recorded += 1
            if settle():
                self._count_rest(decoded)
                return False
            rec: pb.Cycle = d.message
            if self.next_seq is None:
                if d.sequence != 0:
                    result.problems.append(_no_start(path, report, rec.cycle, d.sequence))
                    self._count_rest(decoded)
                    self._file_problems(path, report)  # the damage by the walk's words (logs info --check's)
                    return False
                self._build_law(report, path)
                self.state = self.law.initial_state()
                self.next_seq = 0
            if d.sequence != self.next_seq:
                gap = (d.sequence - self.next_seq, rec.cycle)
                if d.sequence < self.next_seq:
                    result.problems.append(f"cycle sequence restarts at {d.sequence} (cycle {rec.cycle})")
                    gap = None
                self._count_rest(decoded)
                break
            self.next_seq += 1
            self.state, outputs, events = self.law.step(self.state, m.inputs_from_pb(rec.inputs), rec.t_s)
            c = _Compare(rec.cycle, rec.t_s)
            _compare_cycle(c, rec, self.state, outputs)
            if c.diff is not None:
                result.divergence = c.diff
                self._count_rest(decoded)
                return False
            result.cycles_checked += 1
            result.first_cycle = rec.cycle if result.first_cycle is None else result.first_cycle
            result.last_cycle = rec.cycle
            pending = (rec, events)
            if self.progress is not None and result.cycles_checked % 2000 == 0:
                self.progress(report.end_offset)
        if settle():
            return False
        if gap is not None:
            result.problems.append(
                f"{gap[0]} cycle(s) {_why_missing(report, saw_drop)} before cycle {gap[1]} in "
                f"{path.name}: verified up to there"
            )
        self._file_problems(path, report)
        return gap is None and not report.problems

    def _file_problems(self, path: Path, report: ReadReport) -> None:
        """What the walk through ``path`` found (damage, truncation), as ``logs info --check`` names it."""
        many = len(self.result.files) > 1
        self.result.problems.extend(f"{path.name}: {p}" if many else p for p in report.problems)

    def _keyframe(self, path: Path, report: ReadReport, kf: Any) -> bool:
        """A file's keyframe: where a file alone starts; in a session, the state replayed so far must equal it."""
        result = self.result
        if kf.encoding not in KEYFRAME_ENCODINGS or not kf.state:
            if self.state is None:
                result.problems.append(
                    f"{path.name}'s keyframe holds no state it can start from"
                    + (f" (encoding {kf.encoding!r})" if kf.encoding else "")
                )
                return False
            return True
        self._build_law(report, path)
        try:
            state = decode_state(kf.state, kf.encoding)
        except KeyframeError as err:
            if self.state is None:
                result.problems.append(f"{path.name}: {err}")
                return False
            return True
        if self.state is None:
            self.state = state
            self.next_seq = kf.sequence + 1
            where = f"the keyframe of {path.name} (the state after cycle {kf.cycle})"
            if result.cycles_checked:
                result.resumed.append(where)
            else:
                result.started_from = where
            return True
        if encode_state(self.state) != encode_state(state):  # both as the law keeps its state now
            result.divergence = Divergence(
                kf.cycle,
                kf.t_s,
                f"the keyframe of {path.name}",
                "the state at the start of the file",
                "a different state replayed from the files before it",
            )
            return False
        return True

    def _count_rest(self, decoded: Iterator[Any]) -> None:
        """The recorded cycles the check did not reach, for "N of M verified"."""
        for d in decoded:
            if d.topic == m.TOPIC_CYCLE:
                self.result.cycles_recorded += 1

    def count_rest(self, files: list[Path]) -> None:
        """The cycles of the files after a divergence, for "N of M verified"."""
        for path in files:
            self._count_rest(iter_decoded(path, (m.TOPIC_CYCLE,), ReadReport(path)))
            self.result.problems.append(f"{path.name} not checked: the check ended before it")


def _no_start(path: Path, report: ReadReport, cycle: int, sequence: int) -> str:
    """Why a file's first readable cycle is no start for the check (not the session's first, no
    keyframe before it): its start was in a damaged part (the first chunk: the walk has named it by
    now), or the file is a later one of a session whose keyframe is missing."""
    if report.data_lost:
        return (
            f"the start of {path.name} (its keyframe or first cycles, before cycle {cycle}, sequence "
            f"{sequence}) is in a damaged part of the file: the check has nowhere to start"
        )
    return (
        f"{path.name} starts at cycle {cycle} (sequence {sequence}) without a keyframe: "
        "verify it with the session's earlier files"
    )


def _why_missing(report: ReadReport, saw_drop: bool) -> str:
    """Why cycles are missing, from what the file says (walked to its end by now)."""
    if report.data_lost:
        return "lost in a damaged part of the file"
    recovery = report.metadata.get("cheope.recovery")
    if recovery is not None:
        return (
            f"lost with the damaged part of {recovery.get('source', 'the original file')}, which "
            f"cheope logs recover copied this file from ({recovery.get('problems', 'no details')})"
        )
    dropped = report.metadata.get(m.META_RECORDING, {}).get("dropped", "")
    if saw_drop or (dropped.isdigit() and int(dropped) > 0):
        return "dropped by the recorder"
    return "missing (the file does not say why: the recorder reported no drop)"
