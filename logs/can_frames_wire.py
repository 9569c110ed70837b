"""A ``/can`` message (``cheope.v1.CanFrames``) written as Protobuf wire bytes, without building it.

The recording writer turns every cycle's CAN frames into one ``CanFrames`` message: about nine
frames a cycle at 400 Hz. Through upb each frame is an ``add`` with keyword arguments into a
repeated field, then the whole is serialized.

A frame's wire bytes depend on its fields alone: each ``Frame`` is a length-delimited entry of
field 1, its fields in field-number order, the proto3 defaults (zero, false, empty) left out, as
upb writes them (controller/messages/cheope.proto):

    1 unix_time_ns fixed64, 2 arbitration_id uint32, 3 data bytes, 4 outgoing bool,
    5 is_extended_id, 6 is_remote_frame, 7 remote_length uint32, 8 is_fd, 9 bitrate_switch,
    10 error_state_indicator, 11 is_error_frame (bools)

A classic data frame, nearly every frame, differs from the last one with its identifier, length
and direction only in its time and its data bytes: it is one ``struct`` pack of a layout kept per
(identifier, length, direction); so is the SYNC, a classic frame without data. Any other frame is
written field by field. On a default contour demo's recording the writer's work fell from 422 100
to 409 127 instructions a cycle, 0.97 times (``python -m controller.tools.bench.writer_work
SESSION.mcap --first 8400``), and with the SYNC's layout from 407 113 to 396 451 (another
recording); compiled with mypyc it took 409 860, no fewer, so it stays interpreted.

The same bytes as ``can_frames(...).SerializeToString()`` (logs/messages.py), byte for byte:
tests/unit/test_can_frames_wire.py compares the two over frames of every kind. A value the message
cannot hold (a negative time, an identifier of 32 bits or more) raises ``ValueError`` here as it
does there.
"""

from __future__ import annotations

import functools
import struct

from logs.messages import FrameRecord, unix_time_ns_of
from logs.task_values_wire import varint

_MAX_UINT32 = 0xFFFFFFFF
_MAX_UINT64 = 0xFFFFFFFFFFFFFFFF
_FRAME_TAG = 0x0A  # CanFrames.frames: field 1, length-delimited
_TIME_TAG = 0x09  # Frame.unix_time_ns: field 1, fixed64
_ID_TAG = 0x10  # field 2, varint
_DATA_TAG = 0x1A  # field 3, length-delimited
_REMOTE_LENGTH_TAG = 0x38  # field 7, varint
# the bool fields 4, 5, 6, 8, 9, 10, 11 when true: their tag (varint) and 1
_OUTGOING = b"\x20\x01"
_EXTENDED = b"\x28\x01"
_REMOTE = b"\x30\x01"
_FD = b"\x40\x01"
_BRS = b"\x48\x01"
_ESI = b"\x50\x01"
_ERROR = b"\x58\x01"


def _frame(frame: FrameRecord, unix_ns: int) -> bytes:
    """One ``Frame`` at ``unix_ns`` (``unix_time_ns_of`` its time), field by field, as a
    length-delimited entry of field 1."""
    outgoing, _, arb, data, ext, rtr, rlen, fd, brs, esi, err = frame
    if not 0 <= unix_ns <= _MAX_UINT64:
        raise ValueError(f"a CAN frame's time {unix_ns} ns is out of range of fixed64")
    if not 0 <= arb <= _MAX_UINT32 or not 0 <= rlen <= _MAX_UINT32:
        raise ValueError(f"a CAN frame's identifier {arb} or remote length {rlen} is out of range of uint32")
    body = bytearray()
    if unix_ns:
        body.append(_TIME_TAG)
        body += unix_ns.to_bytes(8, "little")
    if arb:
        body.append(_ID_TAG)
        body += varint(arb)
    if data:
        body.append(_DATA_TAG)
        body += varint(len(data))
        body += data
    if outgoing:
        body += _OUTGOING
    if ext:
        body += _EXTENDED
    if rtr:
        body += _REMOTE
    if rlen:
        body.append(_REMOTE_LENGTH_TAG)
        body += varint(rlen)
    if fd:
        body += _FD
    if brs:
        body += _BRS
    if esi:
        body += _ESI
    if err:
        body += _ERROR
    return bytes((_FRAME_TAG,)) + varint(len(body)) + body


@functools.lru_cache(maxsize=4096)  # a bus of many identifiers keeps the cache bounded
def _layout(arb: int, n: int, outgoing: bool) -> tuple[struct.Struct, bytes, bytes]:
    """A classic data frame's wire bytes as one ``struct`` format around its time and its ``n`` data
    bytes: everything else depends on the identifier, the length and the direction alone. With no
    data bytes (the SYNC) the data field is left out, as proto3 leaves out empty bytes."""
    data_head = bytes([_DATA_TAG]) + varint(n) if n else b""
    body_length = 1 + 8 + 1 + len(varint(arb)) + len(data_head) + n + (2 if outgoing else 0)
    head = bytes([_FRAME_TAG]) + varint(body_length) + bytes([_TIME_TAG])
    middle = bytes([_ID_TAG]) + varint(arb) + data_head
    if outgoing:
        return struct.Struct(f"<{len(head)}sQ{len(middle)}s{n}s2s"), head, middle
    return struct.Struct(f"<{len(head)}sQ{len(middle)}s{n}s"), head, middle


def can_frames_bytes(frames: list[FrameRecord], offset_ns: int) -> bytes:
    """``can_frames(frames, offset_ns).SerializeToString()`` (logs/messages.py), written directly.

    A classic data frame (nearly all of them, the SYNC without data too) is one ``pack`` of a layout
    kept per identifier, length and direction (``_layout``); any other frame is written field by
    field (``_frame``)."""
    out: list[bytes] = []
    for frame in frames:
        outgoing, mono_s, arb, data, ext, rtr, rlen, fd, brs, esi, err = frame
        unix_ns = unix_time_ns_of(mono_s, offset_ns)
        if (
            ext
            or rtr
            or rlen
            or fd
            or brs
            or esi
            or err
            or not 0 < arb <= _MAX_CLASSIC_ID
            or not 0 < unix_ns <= _MAX_UINT64
        ):
            out.append(_frame(frame, unix_ns))
            continue
        packer, head, middle = _layout(arb, len(data), outgoing)
        if outgoing:
            out.append(packer.pack(head, unix_ns, middle, data, _OUTGOING))
        else:
            out.append(packer.pack(head, unix_ns, middle, data))
    return b"".join(out)


_MAX_CLASSIC_ID = 0x7FF
