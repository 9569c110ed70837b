"""Byte layouts of the cyclic PDOs and their scaling to SI units.

The layouts match the PDO mappings in ``drivers/eds/*.eds`` and the DBC file
``drivers/dbc/cheope.dbc`` (tests check all three agree). Counts and fixed point exist only
here; everything above this module works in SI units.

Drive (CiA 402, cyclic synchronous position):
  RPDO1 (0x200 + node): controlword 0x6040 (u16), target position 0x607A (i32)
  TPDO1 (0x180 + node): statusword 0x6041 (u16), position actual value 0x6064 (i32) in the EDS's
  default mapping; Cheope's configuration maps the torque actual value 0x6077 too (i16, per thousand
  of the motor's rated torque 0x6076: for a linear motor its rated force in mN): the drive's effort,
  the contact force's second witness (controller/core/contact_guard.py)
Force/torque sensor:
  TPDO1 (0x180 + node): Fx, Fy, Fz (i16, FORCE_N_PER_COUNT), status (u8), counter (u8)
  TPDO2 (0x280 + node): Tx, Ty, Tz (i16, TORQUE_NM_PER_COUNT), status (u8), counter (u8)
Pose tracker (the 3-nSPU's platform, optional; same 8-byte layout as the sensor's):
  TPDO1 (0x180 + node): x, y, z of the platform point P in {0} (i16, TRACKER_M_PER_COUNT), status (u8), counter (u8)
  TPDO2 (0x280 + node): rotation vector r of R = exp([r]x) (i16, TRACKER_RAD_PER_COUNT), status (u8), counter (u8)
  One sample is the pair with the same counter. 20 um and 0.1 mrad a count (ranges +-0.65 m, +-3.27 rad):
  a tenth of the execution's tolerances (1 mm, 10 mrad) and below a tracker's noise.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

from controller.core.cycle_data import SENSOR_FORCE_SATURATED, SENSOR_TORQUE_SATURATED, TRACKER_SATURATED
from controller.errors import InputError
from drivers.pdo_mapping import PdoLayout, PdoMappingError


class FrameError(InputError):
    """A received frame does not decode; the message names the frame and the problem."""


DRIVE_RPDO = struct.Struct("<Hi")
DRIVE_TPDO = struct.Struct("<Hi")
SENSOR_TPDO = struct.Struct("<hhhBB")

FORCE_N_PER_COUNT = 0.01
TORQUE_NM_PER_COUNT = 0.001
INT16_MAX = 32767
INT32_MAX = 2**31 - 1

TRACKER_M_PER_COUNT = 2.0e-5
TRACKER_RAD_PER_COUNT = 1.0e-4

# Sensor status bits.


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
            raise ValueError(
                f"position {value} does not fit in an int32 at {self.counts_per_unit} counts/unit"
            )
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


def saturating_i16(value: float, per_count: float) -> tuple[int, bool]:
    counts = round(value / per_count)
    if counts > INT16_MAX:
        return INT16_MAX, True
    if counts < -INT16_MAX:
        return -INT16_MAX, True
    return counts, False


def encode_sensor_frame(
    values: tuple[float, float, float], per_count: float, status: int, counter: int
) -> bytes:
    """One sensor TPDO; values beyond the i16 range saturate and set the status bit."""
    c0, s0 = saturating_i16(values[0], per_count)
    c1, s1 = saturating_i16(values[1], per_count)
    c2, s2 = saturating_i16(values[2], per_count)
    if s0 or s1 or s2:
        status |= SENSOR_FORCE_SATURATED if per_count == FORCE_N_PER_COUNT else SENSOR_TORQUE_SATURATED
    return SENSOR_TPDO.pack(c0, c1, c2, status & 0xFF, counter & 0xFF)


def decode_sensor_frame(data: bytes | bytearray, per_count: float) -> tuple[float, float, float, int, int]:
    if len(data) != SENSOR_TPDO.size:
        raise FrameError(f"sensor TPDO must have {SENSOR_TPDO.size} data bytes, got {len(data)}")
    x, y, z, status, counter = SENSOR_TPDO.unpack(data)
    return x * per_count, y * per_count, z * per_count, status, counter


# -- codecs built from a device's PDO mapping (drivers/pdo_mapping.py) -----------------------

CONTROLWORD = (0x6040, 0)
TARGET_POSITION = (0x607A, 0)
STATUSWORD = (0x6041, 0)
POSITION_ACTUAL = (0x6064, 0)
TORQUE_ACTUAL = (0x6077, 0)  # per thousand of the rated torque 0x6076 (CiA 402); a linear motor's force
RATED_TORQUE = (0x6076, 0)  # [mN m], for a linear motor [mN]
SENSOR_FORCE_OBJECT = 0x2000  # sub 1..3: Fx, Fy, Fz (drivers/eds/force_sensor.eds)
SENSOR_TORQUE_OBJECT = 0x2001  # sub 1..3: Tx, Ty, Tz
SENSOR_STATUS_OBJECT = (0x2002, 0)
SENSOR_COUNTER_OBJECT = (0x2003, 0)


class DriveCodec:
    """A drive's RPDO and TPDO as mapped at set-up: struct layouts and slots computed once.

    The RPDO must carry the controlword and the target position, the TPDO the statusword and
    the position actual value, in any order; the TPDO may carry more: the torque actual value
    0x6077 is decoded as the drive's effort [N] (``effort_n_per_count``: the rated force 0x6076
    over a thousand), anything else is decoded and not used. An RPDO with other objects is
    refused: the controller would have nothing to write into them.
    """

    def __init__(
        self,
        rpdo: PdoLayout,
        tpdo: PdoLayout,
        where: str,
        rpdo_cob_id: int = 0,
        tpdo_cob_id: int = 0,
        effort_n_per_count: float = 0.0,
    ) -> None:
        self.rpdo, self.tpdo = rpdo, tpdo
        self.rpdo_cob_id, self.tpdo_cob_id = rpdo_cob_id, tpdo_cob_id
        self._cw, self._target = rpdo.slot(*CONTROLWORD), rpdo.slot(*TARGET_POSITION)
        self._sw, self._position = tpdo.slot(*STATUSWORD), tpdo.slot(*POSITION_ACTUAL)
        if self._cw < 0 or self._target < 0 or len(rpdo.objects) != 2:
            raise PdoMappingError(
                f"{where} RPDO mapping {', '.join(map(str, rpdo.objects)) or 'empty'}: must "
                f"map exactly the controlword 0x6040 and the target position 0x607A"
            )
        if self._sw < 0 or self._position < 0:
            raise PdoMappingError(
                f"{where} TPDO mapping {', '.join(map(str, tpdo.objects)) or 'empty'}: must "
                f"map the statusword 0x6041 and the position actual value 0x6064"
            )
        self._effort = tpdo.slot(*TORQUE_ACTUAL)
        self.has_effort = self._effort >= 0 and effort_n_per_count > 0.0
        self.effort_n_per_count = effort_n_per_count if self.has_effort else math.nan
        self._rpdo_first_is_cw = self._cw == 0
        self._rpdo_packer = rpdo.packer
        self._tpdo_packer = tpdo.packer

    def pack_rpdo_into(self, buffer: bytearray, controlword: int, target_counts: int) -> None:
        if self._rpdo_first_is_cw:
            self._rpdo_packer.pack_into(buffer, 0, controlword, target_counts)
        else:
            self._rpdo_packer.pack_into(buffer, 0, target_counts, controlword)

    def decode_tpdo(self, data: bytes | bytearray) -> tuple[int, int, float]:
        """(statusword, position counts, effort [N]: NaN where the TPDO does not map 0x6077)."""
        if len(data) != self._tpdo_packer.size:
            raise FrameError(f"drive TPDO must have {self._tpdo_packer.size} data bytes, got {len(data)}")
        values = self._tpdo_packer.unpack(data)
        effort = values[self._effort] * self.effort_n_per_count if self.has_effort else math.nan
        return values[self._sw], values[self._position], effort


class SensorFrameCodec:
    """One force/torque sensor TPDO as mapped at set-up: three axes of one object, status, counter."""

    def __init__(self, tpdo: PdoLayout, where: str, cob_id: int = 0) -> None:
        self.layout = tpdo
        self.cob_id = cob_id
        indices = {
            obj.index for obj in tpdo.objects if obj.index in (SENSOR_FORCE_OBJECT, SENSOR_TORQUE_OBJECT)
        }
        if len(indices) != 1:
            raise PdoMappingError(
                f"{where} mapping {', '.join(map(str, tpdo.objects)) or 'empty'}: must map the "
                f"three axes of either 0x2000 (force) or 0x2001 (torque)"
            )
        axis_object = indices.pop()
        self.is_force = axis_object == SENSOR_FORCE_OBJECT
        self.per_count = FORCE_N_PER_COUNT if self.is_force else TORQUE_NM_PER_COUNT
        self._axes = tuple(tpdo.slot(axis_object, k) for k in (1, 2, 3))
        self._status, self._counter = tpdo.slot(*SENSOR_STATUS_OBJECT), tpdo.slot(*SENSOR_COUNTER_OBJECT)
        if min(self._axes) < 0 or self._status < 0 or self._counter < 0:
            raise PdoMappingError(
                f"{where} mapping {', '.join(map(str, tpdo.objects))}: must map "
                f"0x{axis_object:04X}sub1..3, the status 0x2002 and the counter 0x2003"
            )
        self._packer = tpdo.packer

    def decode(self, data: bytes | bytearray) -> tuple[float, float, float, int, int]:
        if len(data) != self._packer.size:
            raise FrameError(f"sensor TPDO must have {self._packer.size} data bytes, got {len(data)}")
        v = self._packer.unpack(data)
        k = self.per_count
        ax, ay, az = self._axes
        return v[ax] * k, v[ay] * k, v[az] * k, v[self._status], v[self._counter]


def encode_tracker_frames(
    position_m: tuple[float, float, float],
    rotation_vector_rad: tuple[float, float, float],
    status: int,
    counter: int,
) -> tuple[bytes, bytes]:
    """The tracker's two TPDOs for one sample; a coordinate beyond the i16 range saturates and sets the status bit."""
    frames = []
    for values, per_count in (
        (position_m, TRACKER_M_PER_COUNT),
        (rotation_vector_rad, TRACKER_RAD_PER_COUNT),
    ):
        counts = [saturating_i16(v, per_count) for v in values]
        if any(sat for _, sat in counts):
            status |= TRACKER_SATURATED
        frames.append(counts)
    return tuple(
        SENSOR_TPDO.pack(*(c for c, _ in f), status & 0xFF, counter & 0xFF)  # type: ignore[return-value]
        for f in frames
    )


def decode_tracker_frame(data: bytes | bytearray, per_count: float) -> tuple[float, float, float, int, int]:
    """One tracker TPDO: three coordinates in SI units, status, counter."""
    if len(data) != SENSOR_TPDO.size:
        raise FrameError(f"pose tracker TPDO must have {SENSOR_TPDO.size} data bytes, got {len(data)}")
    x, y, z, status, counter = SENSOR_TPDO.unpack(data)
    return x * per_count, y * per_count, z * per_count, status, counter
