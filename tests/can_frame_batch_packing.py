"""The packed ``CanFrameBatch`` as the recorder wrote it before ``CanFrames`` (logs/can_frame_batch.py
reads it): the tests write it to check that older recordings still read."""

from __future__ import annotations

import itertools
import math
import struct

from logs.can_frame_batch import TIMES_BITS, TIMES_NS

_U64 = (1 << 64) - 1
_NS_LIMIT = 1 << 62  # nanoseconds whose differences stay within int64 (146 years)

# (outgoing, monotonic_s, id, data, fd, brs, error)
LegacyFrame = tuple[bool, float, int, bytes, bool, bool, bool]


def _time_column(times: list[float]) -> tuple[int, list[int]]:
    try:
        ns = [round(t * 1e9) for t in times]
    except (ValueError, OverflowError):  # nan, inf
        ns = []
    if ns and all(
        abs(k) < _NS_LIMIT and k / 1e9 == t and (k or math.copysign(1.0, t) > 0)  # -0.0: bits
        for k, t in zip(ns, times, strict=True)
    ):
        return TIMES_NS, [(b - a) & _U64 for a, b in itertools.pairwise((0, *ns))]  # deltas
    bits = struct.unpack(f"<{len(times)}Q", struct.pack(f"<{len(times)}d", *times))
    return TIMES_BITS, [b ^ a for a, b in itertools.pairwise((0, *bits))]  # XOR with the last


def pack_frames(frames: list[LegacyFrame]) -> bytes:
    """``frames`` as ``CanFrameBatch.frames``: exact, every double bit for bit."""
    n = len(frames)
    encoding, times = _time_column([f[1] for f in frames])
    flags = [outgoing | fd << 1 | brs << 2 | err << 3 for outgoing, _, _, _, fd, brs, err in frames]
    return b"".join(
        (
            struct.pack(
                f"<BI{n}Q{n}I{n}B{n}B",
                encoding,
                n,
                *times,
                *[f[2] for f in frames],
                *flags,
                *[len(f[3]) for f in frames],
            ),
            *[f[3] for f in frames],
        )
    )
