"""The CAN traffic of a recording: frames by function and direction, and the bus load they made.

A recording holds every frame of the session once with its direction (drivers/frame_tap.py), so
its frames are what the bus carried while the controller listened: their bus time, each frame by
its own length and flags (drivers/bus_load.py, worst-case stuffing as the budget), over the
cyclic phase (first to last SYNC the controller sent) is the measured load, comparable to the
budget the controller computed from its configuration before it started. The budget is for the
configured rate; a loop that skipped deadlines (a busy machine without real-time scheduling) sent
fewer cycles, so the comparison is at the SYNC rate achieved: ``planned_at_sync_rate_percent``.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import can

from drivers import cob_ids
from drivers.bus_load import measured_bus_load
from logs import messages as m
from logs.reader import ReadReport, iter_decoded, recorded_config


class RecordedFrame(Protocol):
    """One CAN frame of a recording, as the controller's bus tap saw it (drivers/frame_tap.py):
    ``cheope.v1.CanFrames.Frame``, whatever the file's format (logs/reader.py)."""

    @property
    def unix_time_ns(self) -> int: ...  # send or receive time on the wall clock (the MCAP log time) [ns]

    @property
    def outgoing(self) -> bool: ...  # sent by the controller (else received by it)

    @property
    def arbitration_id(self) -> int: ...

    @property
    def data(self) -> bytes: ...

    @property
    def is_extended_id(self) -> bool: ...

    @property
    def is_remote_frame(self) -> bool: ...

    @property
    def remote_length(self) -> int: ...  # the DLC a remote frame requests

    @property
    def is_fd(self) -> bool: ...

    @property
    def bitrate_switch(self) -> bool: ...

    @property
    def error_state_indicator(self) -> bool: ...

    @property
    def is_error_frame(self) -> bool: ...


def recorded_frames(path: str | Path, report: ReadReport | None = None) -> Iterator[RecordedFrame]:
    """Every CAN frame of the recording once, in recorded order: the one reader of ``/can`` for the
    tools (bus load, replay onto a bus, export), so a change of its layout on disk changes only this."""
    for d in iter_decoded(path, (m.TOPIC_CAN,), report):
        frame: RecordedFrame = d.message
        yield frame


def as_message(f: RecordedFrame, direction: bool = True) -> can.Message:
    """The frame as python-can's ``Message``, stamped with its Unix time [s]; ``direction``: Rx/Tx from
    the controller's side (``is_rx``), else python-can's default (a frame to send again)."""
    msg = can.Message(
        timestamp=f.unix_time_ns * 1e-9,
        arbitration_id=f.arbitration_id,
        is_extended_id=f.is_extended_id,
        is_remote_frame=f.is_remote_frame,
        dlc=f.remote_length if f.is_remote_frame else None,
        data=None if f.is_remote_frame else f.data,
        is_fd=f.is_fd,
        bitrate_switch=f.bitrate_switch,
        error_state_indicator=f.error_state_indicator,
        is_error_frame=f.is_error_frame,
    )
    if direction:
        msg.is_rx = not f.outgoing
    return msg


def clock_offset_s(report: ReadReport) -> float | None:
    """Unix time minus the controller's monotonic clock for this recording (``cheope.session``);
    None when the metadata is missing (a file damaged at its start)."""
    offset = report.metadata.get(m.META_SESSION, {}).get("clock_offset_ns")
    try:
        return int(offset) * 1e-9 if offset is not None else None
    except ValueError:
        return None


@dataclass(frozen=True)
class RecordedTraffic:
    frames_out: int
    frames_in: int
    by_function: dict[str, tuple[int, int]]  # CiA 301 function ("SYNC", "SDO request", ...) -> (out, in)
    cyclic_span_s: float  # first to last SYNC sent (received, where the kernel sent them)
    sync_rate_hz: float  # SYNCs sent per second inside the cyclic span
    load_percent: float  # of the frames inside the cyclic span
    frames_per_second: float  # inside the cyclic span
    planned_load_percent: float | None  # the budget computed from the recorded configuration
    nominal_rate_hz: float | None  # the configured cycle rate the budget is for

    @property
    def planned_at_sync_rate_percent(self) -> float | None:
        """The budget scaled to the SYNC rate achieved (its heartbeats, 0.1 % of it, scale too)."""
        if self.planned_load_percent is None or not self.nominal_rate_hz:
            return None
        return round(self.planned_load_percent * self.sync_rate_hz / self.nominal_rate_hz, 1)

    def as_dict(self) -> dict[str, Any]:
        return {
            "frames_out": self.frames_out,
            "frames_in": self.frames_in,
            "by_function": {k: {"out": o, "in": i} for k, (o, i) in self.by_function.items()},
            "cyclic_span_s": self.cyclic_span_s,
            "sync_rate_hz": self.sync_rate_hz,
            "load_percent": self.load_percent,
            "frames_per_second": self.frames_per_second,
            "planned_load_percent": self.planned_load_percent,
            "nominal_rate_hz": self.nominal_rate_hz,
            "planned_at_sync_rate_percent": self.planned_at_sync_rate_percent,
        }

    def format(self) -> str:
        lines = [f"CAN frames {self.frames_out} sent, {self.frames_in} received"]
        for name, (out, inc) in sorted(self.by_function.items()):
            lines.append(f"  {name:<16} {out:>9} out {inc:>9} in")
        planned = (
            ""
            if self.planned_load_percent is None
            else (
                f"; planned {self.planned_load_percent:.1f} % at {self.nominal_rate_hz:g} Hz, "
                f"{self.planned_at_sync_rate_percent:.1f} % at the SYNC rate achieved"
            )
        )
        lines.append(
            f"bus load   {self.load_percent:.1f} %, {self.frames_per_second:.0f} frames/s, SYNC at "
            f"{self.sync_rate_hz:.1f} Hz over the cyclic phase of {self.cyclic_span_s:.3f} s{planned}"
        )
        return "\n".join(lines)


def recorded_traffic(path: str | Path, report: ReadReport | None = None) -> RecordedTraffic:
    """Walk the ``/can`` channel of ``path`` (damaged parts are skipped and noted in ``report``)."""
    report = report if report is not None else ReadReport(Path(path))
    counts: Counter[tuple[str, bool]] = Counter()
    frames: list[tuple[int, int, int, bool, bool]] = []  # (t [ns], cob_id, bytes, is_fd, brs)
    first_sync = last_sync = None
    first_in = last_in = None  # SYNCs received: the kernel's, with bus.sync_producer = "kernel"
    for f in recorded_frames(path, report):
        counts[(cob_ids.function_name(f.arbitration_id), f.outgoing)] += 1
        if f.is_error_frame:
            continue
        t_ns = f.unix_time_ns
        frames.append((t_ns, f.arbitration_id, len(f.data), f.is_fd, f.bitrate_switch))
        if f.outgoing and f.arbitration_id == cob_ids.SYNC:
            first_sync = t_ns if first_sync is None else first_sync
            last_sync = t_ns
        elif f.arbitration_id == cob_ids.SYNC:
            first_in = t_ns if first_in is None else first_in
            last_in = t_ns
    if first_sync is None:  # the controller sent no SYNC: the broadcast manager did (drivers/kernel_sync.py)
        first_sync, last_sync = first_in, last_in
    cfg = recorded_config(report)
    nominal = cfg.bus.bitrate_bit_s if cfg is not None else 1e6
    data_rate = cfg.bus.data_bitrate_bit_s if cfg is not None else nominal
    span = 0.0 if first_sync is None or last_sync is None else (last_sync - first_sync) * 1e-9
    syncs = 0
    by_id: Counter[int] = Counter()
    shapes: dict[int, tuple[int, bool, bool]] = {}
    if first_sync is not None and last_sync is not None:
        # the frames of whole cycles: from the first SYNC up to (not including) the last one
        for t, cid, n, fd, brs in frames:
            if first_sync <= t < last_sync:
                by_id[cid] += 1
                shapes.setdefault(cid, (n, fd, brs))
        syncs = by_id[cob_ids.SYNC]
    load = measured_bus_load(dict(by_id), shapes, span, nominal, data_rate)
    names = sorted({name for name, _ in counts})
    planned = None
    if cfg is not None:
        from controller.assembly import planned_bus_load

        planned = round(planned_bus_load(cfg).percent, 1)
    return RecordedTraffic(
        frames_out=sum(k for (_, out), k in counts.items() if out),
        frames_in=sum(k for (_, out), k in counts.items() if not out),
        by_function={n: (counts[(n, True)], counts[(n, False)]) for n in names},
        cyclic_span_s=span,
        sync_rate_hz=round(syncs / span, 2) if span > 0 else 0.0,
        load_percent=load["percent"],
        frames_per_second=load["frames_per_second"],
        planned_load_percent=planned,
        nominal_rate_hz=cfg.loop.rate_hz if cfg is not None else None,
    )
