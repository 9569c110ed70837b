"""A CAN frame as python-can's ``udp_multicast`` bus carries it: one datagram, a msgpack map.

python-can packs a ``Message`` as a map of eleven entries in one order (``pack_message`` in
``can/interfaces/udp_multicast/utils.py``): timestamp (a float64), arbitration_id, is_extended_id,
is_remote_frame, is_error_frame, channel, dlc, data (bin), is_fd, bitrate_switch,
error_state_indicator. Every process on the simulated bus, and any python-can tool beside them,
reads and writes that format; the bus keeps it.

Packing a dict through msgpack took 1.25 µs a frame, reading one back with its checks 3.4 µs
(``timeit``, a classic 8-byte frame); the controller's loop sends about 4 frames a cycle and reads
about 5, the simulator sends about 6 and reads 4 per SYNC. But a classic data frame, nearly every
frame, differs from another of the same identifier, flags and length only in its time and its data
bytes. So:

- ``pack_frame`` writes such a frame as one ``struct`` pack of a layout kept per (identifier,
  flags, length): 0.25 µs. Any other message (a remote or error frame, a channel, a value of
  another type than python-can's own) goes through ``pack_message``. The bytes are the same
  (tests/unit/test_multicast_frames.py compares them over frames of every kind).
- ``unpack_frame`` reads a datagram of exactly that form with one regular expression, and hands
  any other to the full reading (msgpack, each field's type, ``Message``'s own check), which names
  what is wrong. A datagram the pattern takes is a frame the full reading takes too, with the same
  fields (the same test, over datagrams of every kind, frames and not).
"""

from __future__ import annotations

import functools
import math
import re
import struct
from typing import Any

import can
import msgpack
from can.interfaces.udp_multicast.utils import pack_message

_TRUE, _FALSE = b"\xc3", b"\xc2"
_HEAD = b"\x8b\xa9timestamp\xcb"  # a map of 11; "timestamp"; a float64 follows
_LAYOUTS_MAX = 4096  # pack_frame's layouts kept: a bus of many identifiers keeps the cache bounded
_Layout = tuple[struct.Struct, bytes, bytes]


def _bool(value: bool) -> bytes:
    return _TRUE if value else _FALSE


def _uint(n: int) -> bytes:
    """``n`` (0 <= n < 2**32) as msgpack packs a non-negative int, in its smallest form."""
    if n < 0x80:
        return bytes((n,))
    if n < 0x100:
        return b"\xcc" + bytes((n,))
    if n < 0x10000:
        return b"\xcd" + n.to_bytes(2, "big")
    return b"\xce" + n.to_bytes(4, "big")


@functools.lru_cache(maxsize=_LAYOUTS_MAX)
def _layout(arb: int, ext: bool, fd: bool, brs: bool, esi: bool, n: int) -> _Layout:
    """A data frame's map around its timestamp and its ``n`` data bytes."""
    middle = b"".join(
        (
            b"\xaearbitration_id",
            _uint(arb),
            b"\xaeis_extended_id",
            _bool(ext),
            b"\xafis_remote_frame\xc2\xaeis_error_frame\xc2\xa7channel\xc0\xa3dlc",
            bytes((n,)),
            b"\xa4data\xc4",
            bytes((n,)),
        )
    )
    tail = b"".join(
        (b"\xa5is_fd", _bool(fd), b"\xaebitrate_switch", _bool(brs), b"\xb5error_state_indicator", _bool(esi))
    )
    return struct.Struct(f">{len(_HEAD)}sd{len(middle)}s{n}s{len(tail)}s"), middle, tail


def pack_frame(msg: can.Message) -> bytes:
    """``pack_message(msg)``: the same bytes; a classic or FD data frame through a kept layout."""
    data, arb, ext = msg.data, msg.arbitration_id, msg.is_extended_id
    fd, brs, esi = msg.is_fd, msg.bitrate_switch, msg.error_state_indicator
    if (
        type(msg.timestamp) is not float
        or type(arb) is not int
        or not 0 <= arb <= 0xFFFFFFFF
        or type(data) not in (bytearray, bytes)
        or type(msg.dlc) is not int
        or msg.dlc != len(data)
        or len(data) > 64
        or msg.channel is not None
        or msg.is_remote_frame is not False
        or msg.is_error_frame is not False
        or type(ext) is not bool
        or type(fd) is not bool
        or type(brs) is not bool
        or type(esi) is not bool
    ):
        return pack_message(msg)  # anything else: python-can's way
    packer, middle, tail = _layout(arb, ext, fd, brs, esi, len(data))
    return packer.pack(_HEAD, msg.timestamp, middle, data, tail)


# A data frame exactly as ``pack_frame`` and python-can write it: no remote or error frame, no
# channel; the identifier a fixint, uint8, uint16 or uint32; the dlc a fixint up to 64.
_DATA_FRAME = re.compile(
    rb"\x8b\xa9timestamp\xcb.{8}"
    rb"\xaearbitration_id(?:([\x00-\x7f])|\xcc(.)|\xcd(..)|\xce(....))"
    rb"\xaeis_extended_id([\xc2\xc3])\xafis_remote_frame\xc2\xaeis_error_frame\xc2\xa7channel\xc0"
    rb"\xa3dlc([\x00-\x40])\xa4data\xc4(.)(.*)"
    rb"\xa5is_fd([\xc2\xc3])\xaebitrate_switch([\xc2\xc3])\xb5error_state_indicator([\xc2\xc3])",
    re.DOTALL,
)


def unpack_frame(data: bytes, timestamp_s: float) -> can.Message:
    """A datagram as python-can's ``unpack_message`` reads it (msgpack map of ``Message``'s arguments,
    checked), received at ``timestamp_s``; raises ``ValueError`` naming what is wrong."""
    # anything but bytes goes the checked way, which names it (the pattern raised TypeError on a str)
    match = _DATA_FRAME.fullmatch(data) if isinstance(data, (bytes, bytearray, memoryview)) else None
    if match is not None and 0.0 <= timestamp_s < math.inf:
        fixint, uint8, uint16, uint32, ext_byte, dlc_byte, length, payload, fd_byte, brs_byte, esi_byte = (
            match.groups()
        )
        arb = fixint[0] if fixint is not None else int.from_bytes(uint8 or uint16 or uint32, "big")
        ext, fd = ext_byte == _TRUE, fd_byte == _TRUE
        brs, esi = brs_byte == _TRUE, esi_byte == _TRUE
        dlc = dlc_byte[0]
        if (
            dlc == length[0] == len(payload)
            and arb < (0x20000000 if ext else 0x800)
            and (dlc <= 8 if not fd else True)
            and (fd or not (brs or esi))
        ):
            return can.Message(
                timestamp=timestamp_s,
                arbitration_id=arb,
                is_extended_id=ext,
                dlc=dlc,
                data=payload,
                is_fd=fd,
                bitrate_switch=brs,
                error_state_indicator=esi,
            )
    return _unpack_checked(data, timestamp_s)


# The fields python-can packs (udp_multicast.utils.pack_message) and the types msgpack gives them
# back as: anything else (a float identifier, an integer as data, 2**63 anywhere) is no frame. An
# integer as data would have had python-can allocate that many bytes before its check.
_FIELD_TYPES: dict[str, tuple[type, ...]] = {
    "timestamp": (float, int),
    "arbitration_id": (int,),
    "is_extended_id": (bool,),
    "is_remote_frame": (bool,),
    "is_error_frame": (bool,),
    "channel": (str, int, type(None)),
    "dlc": (int, type(None)),
    "data": (bytes, type(None)),
    "is_fd": (bool,),
    "bitrate_switch": (bool,),
    "error_state_indicator": (bool,),
}


def _unpack_checked(data: bytes, timestamp_s: float) -> can.Message:
    """``unpack_frame`` of any datagram: msgpack, each field's type, then ``Message``'s check."""
    try:
        fields: Any = msgpack.unpackb(data, raw=False)
    # msgpack's errors have no common base but Exception (ExtraData, FormatError, ...)
    except Exception as err:
        raise ValueError(f"not msgpack ({type(err).__name__}: {err})") from err
    if not isinstance(fields, dict):
        raise ValueError(f"a msgpack {type(fields).__name__}, not the map of a frame")
    for key, value in fields.items():
        kinds = _FIELD_TYPES.get(key)
        if kinds is None:
            raise ValueError(f"not a CAN frame (a field {key!r})")
        if type(value) not in kinds:  # exactly: a bool is no identifier, a float no length
            raise ValueError(f"not a CAN frame ({key} is a {type(value).__name__})")
    payload = fields.get("data")
    if payload is not None and len(payload) > 64:
        raise ValueError(f"not a CAN frame ({len(payload)} data bytes)")
    fields["timestamp"] = timestamp_s
    try:
        return can.Message(check=True, **fields)
    except (TypeError, ValueError, OverflowError) as err:  # a value out of range
        raise ValueError(f"not a CAN frame ({err})") from err
