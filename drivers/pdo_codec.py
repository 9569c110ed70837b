"""Byte layouts of the cyclic PDOs and their scaling to SI units.

The layouts match the PDO mappings in ``drivers/eds/*.eds`` and the DBC file
``drivers/dbc/cheope.dbc`` (tests check all three agree). Counts and fixed point exist only
here; everything above this module works in SI units.

Drive (CiA 402, cyclic synchronous position):
  RPDO1 (0x200 + node): controlword 0x6040 (u16), target position 0x607A (i32)
  TPDO1 (0x180 + node): statusword 0x6041 (u16), position actual value 0x6064 (i32)
Force/torque sensor:
  TPDO1 (0x180 + node): Fx, Fy, Fz (i16, FORCE_N_PER_COUNT), status (u8), counter (u8)
  TPDO2 (0x280 + node): Tx, Ty, Tz (i16, TORQUE_NM_PER_COUNT), status (u8), counter (u8)
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

from controller.errors import InputError


class FrameError(InputError):
    """A received frame does not decode; the message names the frame and the problem."""


DRIVE_RPDO = struct.Struct("<Hi")
DRIVE_TPDO = struct.Struct("<Hi")
SENSOR_TPDO = struct.Struct("<hhhBB")

FORCE_N_PER_COUNT = 0.01
TORQUE_NM_PER_COUNT = 0.001
INT16_MAX = 32767
INT32_MAX = 2**31 - 1

# Sensor status bits.
SENSOR_FORCE_SATURATED = 0x01
SENSOR_TORQUE_SATURATED = 0x02
SENSOR_ERROR = 0x04


@dataclass(frozen=True)
class PositionScale:
    """Encoder scaling: ``counts_per_unit`` counts per metre (linear) or per radian (rotary)."""

    counts_per_unit: float

    def __post_init__(self) -> None:
        if not (self.counts_per_unit > 0 and math.isfinite(self.counts_per_unit)):
            raise ValueError(f"counts_per_unit must be a positive finite number, got {self.counts_per_unit}")

    def to_counts(self, value: float) -> int:
        counts = round(value * self.counts_per_unit)
        if not -INT32_MAX - 1 <= counts <= INT32_MAX:
            raise ValueError(f"position {value} does not fit in an int32 at {self.counts_per_unit} counts/unit")
        return counts

    def to_unit(self, counts: int) -> float:
        return counts / self.counts_per_unit


def encode_drive_rpdo(controlword: int, target_counts: int) -> bytes:
    return DRIVE_RPDO.pack(controlword, target_counts)


def decode_drive_rpdo(data: bytes | bytearray) -> tuple[int, int]:
    if len(data) != DRIVE_RPDO.size:
        raise FrameError(f"drive RPDO1 must have {DRIVE_RPDO.size} data bytes, got {len(data)}")
    return DRIVE_RPDO.unpack(data)


def encode_drive_tpdo(statusword: int, position_counts: int) -> bytes:
    return DRIVE_TPDO.pack(statusword, position_counts)


def decode_drive_tpdo(data: bytes | bytearray) -> tuple[int, int]:
    if len(data) != DRIVE_TPDO.size:
        raise FrameError(f"drive TPDO1 must have {DRIVE_TPDO.size} data bytes, got {len(data)}")
    return DRIVE_TPDO.unpack(data)


def _saturating_i16(value: float, per_count: float) -> tuple[int, bool]:
    counts = round(value / per_count)
    if counts > INT16_MAX:
        return INT16_MAX, True
    if counts < -INT16_MAX:
        return -INT16_MAX, True
    return counts, False


def encode_sensor_frame(values: tuple[float, float, float], per_count: float, status: int, counter: int) -> bytes:
    """One sensor TPDO; values beyond the i16 range saturate and set the status bit."""
    c0, s0 = _saturating_i16(values[0], per_count)
    c1, s1 = _saturating_i16(values[1], per_count)
    c2, s2 = _saturating_i16(values[2], per_count)
    if s0 or s1 or s2:
        status |= SENSOR_FORCE_SATURATED if per_count == FORCE_N_PER_COUNT else SENSOR_TORQUE_SATURATED
    return SENSOR_TPDO.pack(c0, c1, c2, status & 0xFF, counter & 0xFF)


def decode_sensor_frame(data: bytes | bytearray, per_count: float) -> tuple[float, float, float, int, int]:
    if len(data) != SENSOR_TPDO.size:
        raise FrameError(f"sensor TPDO must have {SENSOR_TPDO.size} data bytes, got {len(data)}")
    x, y, z, status, counter = SENSOR_TPDO.unpack(data)
    return x * per_count, y * per_count, z * per_count, status, counter
