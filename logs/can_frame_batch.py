"""The ``/can`` messages of recordings written before ``cheope.v1.CanFrames``: ``CanFrameBatch``.

A cycle's frames were packed by column into the one ``bytes`` field of a ``CanFrameBatch``,
little-endian: the time encoding (uint8) and the count n (uint32), n times, n arbitration ids
(uint32), n flags (uint8: 1 outgoing, 2 FD, 4 bitrate switch, 8 error frame), n data lengths
(uint8), the data. The times: ``TIMES_NS`` (uint64): the first frame's integer nanoseconds, then
each one's difference from the one before, when every ``monotonic_s`` was its nanoseconds / 1e9;
else ``TIMES_BITS``: each double's bits XOR the previous one's. Either way every double comes back
bit for bit. Nothing writes this format any more; ``logs.reader`` reads it (tests/data holds such
recordings).
"""

from __future__ import annotations

import struct
from collections.abc import Iterator

from controller.messages import cheope_pb2 as pb

_HEAD = struct.Struct("<BI")
TIMES_NS, TIMES_BITS = 1, 2
_OUTGOING, _FD, _BRS, _ERROR = 1, 2, 4, 8
_U64 = (1 << 64) - 1


def _times(encoding: int, column: tuple[int, ...]) -> tuple[float, ...]:
    acc, out = 0, []
    for x in column:
        acc = (acc + x) & _U64 if encoding == TIMES_NS else acc ^ x
        out.append(acc)
    if encoding == TIMES_NS:
        return tuple((k - (1 << 64) if k >> 63 else k) / 1e9 for k in out)
    if encoding == TIMES_BITS:
        return struct.unpack(f"<{len(out)}d", struct.pack(f"<{len(out)}Q", *out))
    raise ValueError(f"a CAN frame batch with an unknown time encoding {encoding}")


def unpack_frames(packed: bytes) -> Iterator[pb.CanFrame]:
    """The frames of ``CanFrameBatch.frames``, each as the ``CanFrame`` the oldest files held;
    ``ValueError`` when the bytes do not hold what their count says."""
    if len(packed) < _HEAD.size:
        raise ValueError(f"a CAN frame batch of {len(packed)} bytes has no frame count")
    encoding, n = _HEAD.unpack_from(packed)
    columns = struct.Struct(f"<{n}Q{n}I{n}B{n}B")
    if _HEAD.size + columns.size > len(packed):
        raise ValueError(f"a CAN frame batch of {len(packed)} bytes is too short for its {n} frames")
    cols = columns.unpack_from(packed, _HEAD.size)
    ids, flags, lengths = cols[n : 2 * n], cols[2 * n : 3 * n], cols[3 * n :]
    times = _times(encoding, cols[:n])
    pos = _HEAD.size + columns.size
    if pos + sum(lengths) != len(packed):
        raise ValueError(f"a CAN frame batch holds {len(packed) - pos} data bytes, its frames {sum(lengths)}")
    for t, arb, f, length in zip(times, ids, flags, lengths, strict=True):
        yield pb.CanFrame(
            monotonic_s=t,
            outgoing=bool(f & _OUTGOING),
            arbitration_id=arb,
            data=packed[pos : pos + length],
            is_fd=bool(f & _FD),
            bitrate_switch=bool(f & _BRS),
            is_error_frame=bool(f & _ERROR),
        )
        pos += length
