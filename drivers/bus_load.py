"""Bus-load budget of the cyclic traffic, classical CAN and CAN FD, with worst-case stuffing.

Frame lengths (11-bit identifiers), ISO 11898-1:2015:

Classical CAN, n data bytes: SOF 1 + ID 11 + RTR 1 + IDE 1 + r0 1 + DLC 4 + data 8n + CRC 15
form the 34 + 8n bits subject to bit stuffing; then CRC delimiter 1, ACK 2, EOF 7 and the
3-bit intermission: 47 + 8n bits unstuffed. Worst-case stuffing adds floor((34 + 8n - 1) / 4)
bits (one stuff bit after every four equal bits, the stuff bit itself starting the next run):
111 bits unstuffed and 135 bits worst case for 8 bytes.

CAN FD, n data bytes padded to the next valid FD length: arbitration phase at the nominal
rate SOF 1 + ID 11 + RRS 1 + IDE 1 + FDF 1 + res 1 + BRS 1 = 17 bits; data phase (at the data
rate when BRS is set) ESI 1 + DLC 4 + data 8n, then the CRC field of stuff count 4 + CRC 17
(n <= 16) or 21 bits with its fixed stuff bits (6 or 7) and the CRC delimiter 1; back at the
nominal rate ACK 2 + EOF 7 + intermission 3 = 12 bits. Dynamic stuffing covers SOF..data:
floor((17 + 5 + 8n - 1) / 4) bits, counted here at the rate of the phase they fall in
(in proportion to the bits of each phase).
"""

from __future__ import annotations

from dataclasses import dataclass

from controller.errors import InputError

FD_LENGTHS = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)


class BusLoadError(InputError):
    """The configured traffic does not fit the bus within the allowed load."""


def fd_padded_length(n_bytes: int) -> int:
    for length in FD_LENGTHS:
        if n_bytes <= length:
            return length
    raise ValueError(f"a CAN FD frame carries at most 64 data bytes, got {n_bytes}")


def classical_frame_bits(n_bytes: int, worst_case_stuffing: bool = True) -> int:
    if not 0 <= n_bytes <= 8:
        raise ValueError(f"a classical CAN frame carries 0..8 data bytes, got {n_bytes}")
    stuffable = 34 + 8 * n_bytes
    stuff = (stuffable - 1) // 4 if worst_case_stuffing else 0
    return 47 + 8 * n_bytes + stuff


def fd_frame_time_s(
    n_bytes: int,
    nominal_bit_s: float,
    data_bit_s: float,
    bitrate_switch: bool = True,
    worst_case_stuffing: bool = True,
) -> float:
    n = fd_padded_length(n_bytes)
    arbitration = 17
    data_phase = 1 + 4 + 8 * n
    crc_field = (4 + 17 + 6) if n <= 16 else (4 + 21 + 7)
    tail = 12
    stuff = (arbitration + 5 + 8 * n - 1) // 4 if worst_case_stuffing else 0
    stuff_arb = stuff * arbitration / (arbitration + data_phase)
    stuff_data = stuff - stuff_arb
    fast = data_bit_s if bitrate_switch else nominal_bit_s
    return (arbitration + stuff_arb + tail) / nominal_bit_s + (data_phase + stuff_data + crc_field + 1) / fast


@dataclass(frozen=True)
class FrameSpec:
    """A frame of the budget: its name, data bytes and how often it is sent [Hz]."""

    name: str
    n_bytes: int
    rate_hz: float


@dataclass(frozen=True)
class BusLoad:
    load_fraction: float
    bits_per_second: float  # nominal-bit equivalents, for display
    frames_per_second: float
    frames: tuple[FrameSpec, ...]

    @property
    def percent(self) -> float:
        return 100.0 * self.load_fraction


def compute_bus_load(
    frames: tuple[FrameSpec, ...],
    nominal_bit_s: float,
    fd: bool = False,
    data_bit_s: float | None = None,
    worst_case_stuffing: bool = True,
) -> BusLoad:
    """Fraction of bus time the frames occupy (1.0 = a saturated bus)."""
    if nominal_bit_s <= 0:
        raise ValueError(f"nominal bit rate must be > 0 bit/s, got {nominal_bit_s}")
    busy_s = 0.0
    for f in frames:
        if fd:
            t = fd_frame_time_s(
                f.n_bytes,
                nominal_bit_s,
                data_bit_s or nominal_bit_s,
                bitrate_switch=data_bit_s is not None,
                worst_case_stuffing=worst_case_stuffing,
            )
        else:
            t = classical_frame_bits(f.n_bytes, worst_case_stuffing) / nominal_bit_s
        busy_s += t * f.rate_hz
    return BusLoad(
        load_fraction=busy_s,
        bits_per_second=busy_s * nominal_bit_s,
        frames_per_second=sum(f.rate_hz for f in frames),
        frames=frames,
    )


def cyclic_frames(
    cycle_hz: float,
    n_drives: int,
    sensor: bool,
    heartbeat_hz: float,
    drive_pdo_bytes: int = 6,
    sensor_pdo_bytes: int = 8,
    tracker_hz: float = 0.0,
    drive_tpdo_bytes: int | None = None,
) -> tuple[FrameSpec, ...]:
    """The frames of one configuration of this project (see drivers/pdo_codec.py); the drives'
    TPDO has ``drive_tpdo_bytes`` where its mapping differs from the RPDO's size (Cheope's maps the
    effort 0x6077 too: 8 bytes)."""
    frames = [
        FrameSpec("SYNC", 0, cycle_hz),
        FrameSpec("drive RPDO1", drive_pdo_bytes, cycle_hz * n_drives),
        FrameSpec(
            "drive TPDO1",
            drive_pdo_bytes if drive_tpdo_bytes is None else drive_tpdo_bytes,
            cycle_hz * n_drives,
        ),
    ]
    n_nodes = n_drives + 1  # the controller's own heartbeat
    if sensor:
        frames.append(FrameSpec("sensor TPDO1+2", sensor_pdo_bytes, 2 * cycle_hz))
        n_nodes += 1
    if tracker_hz > 0.0:  # the pose tracker's two TPDOs a sample, at its own rate (no heartbeat)
        frames.append(FrameSpec("tracker TPDO1+2", 8, 2 * tracker_hz))
    frames.append(FrameSpec("heartbeats", 1, heartbeat_hz * n_nodes))
    return tuple(frames)


def measured_bus_load(
    frames: dict[int, int],
    shapes: dict[int, tuple[int, bool, bool]],
    seconds: float,
    nominal_bit_s: float,
    data_bit_s: float,
) -> dict[str, float]:
    """Bus time of frames seen on a bus over ``seconds``, each by its own length and FD/BRS flags.

    ``frames`` counts them by COB-ID, ``shapes`` gives each COB-ID's (data bytes, is_fd, brs).
    """
    busy = 0.0
    classical_on_fd = 0
    for cid, count in frames.items():
        n_bytes, is_fd, brs = shapes[cid]
        if is_fd:
            busy += count * fd_frame_time_s(n_bytes, nominal_bit_s, data_bit_s, bitrate_switch=brs)
        else:
            busy += count * classical_frame_bits(min(n_bytes, 8)) / nominal_bit_s
            classical_on_fd += count
    return {
        "percent": round(100.0 * busy / seconds, 1) if seconds > 0 else 0.0,
        "frames_per_second": round(sum(frames.values()) / seconds, 1) if seconds > 0 else 0.0,
        "classical_frames_per_second": round(classical_on_fd / seconds, 1) if seconds > 0 else 0.0,
    }


def check_bus_load(load: BusLoad, max_load_percent: float) -> None:
    if load.percent > max_load_percent:
        raise BusLoadError(
            f"bus load {load.percent:.1f} % exceeds the limit of {max_load_percent:.1f} % "
            f"({load.frames_per_second:.0f} frames/s); lower the cycle rate, raise the bit rate or use CAN FD"
        )
