"""The simulated devices' PDOs: what each drive and the sensor send and accept, as mapped over SDO.

One ``SimulatedPdos`` per simulator (process or in-process loopback) holds every device's
``DevicePdos`` (``pdo_parameters.py``), built from the configured EDS files. At a SYNC it packs
each device's valid TPDOs from the device's current values, with a packer rebuilt only when a
master enables a new mapping; an RPDO is unpacked with the mapping in force and its mapped
objects applied to the drive (controlword 0x6040, target position 0x607A).
"""

from __future__ import annotations

from collections.abc import Callable, Collection
from dataclasses import dataclass
from pathlib import Path

from canopen import SdoAbortedError

from controller.config import Config
from controller.errors import CheopeError
from controller.sim_config.quirk_specs import Quirk
from drivers.node_setup import DRIVE_EDS, SENSOR_EDS, device_description_path, naming_the_file
from drivers.pdo_codec import CONTROLWORD, RATED_TORQUE, TARGET_POSITION, DriveCodec, saturating_i16
from drivers.pdo_mapping import (
    PdoDirection,
    layout,
    load_device_description,
    objects_from_references,
    planned_pdo,
    remap_writes,
)
from sim_backend.drive import SimulatedDrive
from sim_backend.force_sensor import SimulatedForceSensor
from sim_backend.pdo_parameters import DevicePdo, DevicePdos, value_packer
from sim_backend.quirks import quirks_of


@dataclass
class _Tpdo:
    pdo: DevicePdo
    pack: Callable[[], bytes] | None


def _drive_objects(drive: SimulatedDrive, rated_n: float) -> dict[tuple[int, int], Callable[[], int]]:
    """The drive's mappable objects a TPDO reads (drivers/eds/cheope_drive.eds); ``rated_n`` is its
    rated force 0x6076, of which the torque actual value 0x6077 counts thousandths."""
    counts = drive.params.counts_per_unit
    per_count = rated_n / 1000.0
    return {
        (0x6077, 0): lambda: saturating_i16(drive.effort_n, per_count)[0] if per_count > 0 else 0,
        (0x6041, 0): drive.statusword,
        (0x6064, 0): drive.position_counts,
        (0x606C, 0): lambda: round(drive.velocity * counts),
        (0x6061, 0): lambda: drive.mode_of_operation,
        (0x603F, 0): lambda: drive.error_code,
        (0x607A, 0): lambda: round((drive.received_target + drive.encoder_offset) * counts),
        (0x6040, 0): lambda: drive.last_controlword,
    }


def _reader(values: dict[tuple[int, int], int], key: tuple[int, int]) -> Callable[[], int]:
    return lambda: values.get(key, 0)


def device_pdos_from_file(eds: Path, node_id: int) -> DevicePdos:
    """A device's PDOs as its EDS file describes them; a damaged file is one line naming it."""
    with naming_the_file(eds):
        return DevicePdos.from_description(load_device_description(eds, node_id), node_id)


class PdoWriteRefusedError(CheopeError):
    """A write of the remap procedure a simulated device refused (what set-up would be told by SDO)."""

    def __init__(self, node_id: int, index: int, subindex: int, value: int, abort: SdoAbortedError) -> None:
        super().__init__(f"node {node_id}: writing 0x{index:04X}sub{subindex} = 0x{value:X} refused: {abort}")
        self.index, self.code = index, abort.code


class SimulatedPdos:
    def __init__(
        self, cfg: Config, drives: list[SimulatedDrive], sensor: SimulatedForceSensor | None
    ) -> None:
        self.drive_ids = tuple(cfg.actuators.node_ids)
        self.sensor_id = cfg.sensor.node_id if sensor is not None else None
        drive_eds = device_description_path(cfg.actuators.eds_file, DRIVE_EDS)
        self.drive_eds = drive_eds
        self.drives = drives
        self.sensor = sensor
        self.drive_pdos = [device_pdos_from_file(drive_eds, n) for n in self.drive_ids]
        self.sensor_pdos = None
        if self.sensor_id is not None:
            sensor_eds = device_description_path(cfg.sensor.eds_file, SENSOR_EDS)
            self.sensor_pdos = device_pdos_from_file(sensor_eds, self.sensor_id)
        self.on_cob_ids_changed: Callable[[], None] | None = None  # the server re-reads its COB-ID tables
        self._drive_tpdos: list[_Tpdo] = []
        self._sensor_tpdos: list[_Tpdo] = []
        self._rpdo_slots: list[tuple[int, int]] = []
        for node_id, device in zip(self.drive_ids, self.drive_pdos):
            if Quirk.FIXED_MAPPING in quirks_of(cfg.sim.drive.quirks, node_id, is_drive=True):
                objects = objects_from_references(
                    cfg.sim.quirk.fixed_tpdo_objects,
                    device.od,
                    f"sim.quirk.fixed_tpdo_objects (node {node_id})",
                )
                tpdo = device.pdo(PdoDirection.TRANSMIT, 1).config
                device.fix(tpdo.with_objects(objects))
        for device in (*self.drive_pdos, *((self.sensor_pdos,) if self.sensor_pdos else ())):
            device.on_change = self._rebuild
        self._rebuild()

    def drive_codec(self, j: int) -> DriveCodec:
        """Drive ``j``'s codec from its mapping as it has it now (what set-up reads where it does not write)."""
        device, node_id = self.drive_pdos[j], self.drive_ids[j]
        rpdo, tpdo = device.pdo(PdoDirection.RECEIVE, 1).config, device.pdo(PdoDirection.TRANSMIT, 1).config
        where = f"node {node_id}"
        return DriveCodec(
            layout(rpdo.objects, device.od, where),
            layout(tpdo.objects, device.od, where),
            where,
            rpdo.cob_id,
            tpdo.cob_id,
        )

    def apply_configured_mapping(self, cfg: Config, read: Collection[int] = ()) -> None:
        """What the controller's set-up writes over SDO (the loopback has no SDO): config + EDS mapping,
        except to the drives in ``read`` (actuators.pdo_mapping = "read": theirs is taken as it is).

        A write a drive refuses (a fixed mapping) raises ``PdoWriteRefusedError`` naming it."""
        for node_id, device in zip(self.drive_ids, self.drive_pdos):
            if node_id in read:
                continue
            for direction, objects in (
                (PdoDirection.RECEIVE, cfg.actuators.rpdo_objects),
                (PdoDirection.TRANSMIT, cfg.actuators.tpdo_objects),
            ):
                for index, subindex, value in remap_writes(
                    planned_pdo(device.od, direction, 1, node_id, objects)
                ):
                    try:
                        device.write(index, subindex, value)
                    except SdoAbortedError as err:
                        raise PdoWriteRefusedError(node_id, index, subindex, value, err) from err
        if self.sensor_pdos is not None and self.sensor_id is not None:
            for number in (1, 2):
                self.sensor_pdos.apply(
                    planned_pdo(self.sensor_pdos.od, PdoDirection.TRANSMIT, number, self.sensor_id, ())
                )

    def _rebuild(self) -> None:
        self._drive_tpdos = []
        self._rpdo_slots = []
        for device, drive in zip(self.drive_pdos, self.drives):
            tpdo = device.pdo(PdoDirection.TRANSMIT, 1)
            rated = device.od.get_variable(*RATED_TORQUE) if RATED_TORQUE[0] in device.od else None
            rated_n = int(rated.default or 0) / 1000.0 if rated is not None else 0.0  # [mN] to [N]
            self._drive_tpdos.append(_Tpdo(tpdo, value_packer(tpdo, _drive_objects(drive, rated_n))))
            rpdo = device.pdo(PdoDirection.RECEIVE, 1)
            lay = rpdo.layout
            self._rpdo_slots.append((lay.slot(*CONTROLWORD), lay.slot(*TARGET_POSITION)) if lay else (-1, -1))
        self._sensor_tpdos = []
        if self.sensor_pdos is not None and self.sensor is not None:
            values = self.sensor.object_values
            getters = {
                key: _reader(values, key)
                for key in [(0x2000, k) for k in (1, 2, 3)]
                + [(0x2001, k) for k in (1, 2, 3)]
                + [(0x2002, 0), (0x2003, 0)]
            }
            for number in (1, 2):
                tpdo = self.sensor_pdos.pdo(PdoDirection.TRANSMIT, number)
                self._sensor_tpdos.append(_Tpdo(tpdo, value_packer(tpdo, getters)))
        if self.on_cob_ids_changed is not None:
            self.on_cob_ids_changed()

    # -- cyclic -----------------------------------------------------------------------------

    def rpdo_cob_ids(self) -> list[int]:
        return [device.pdo(PdoDirection.RECEIVE, 1).config.cob_id for device in self.drive_pdos]

    def receive_rpdo(self, j: int, data: bytes | bytearray) -> bool:
        """Apply drive ``j``'s RPDO; False when it is invalid or does not match the mapping (dropped)."""
        rpdo = self.drive_pdos[j].pdo(PdoDirection.RECEIVE, 1)
        lay = rpdo.layout
        if not rpdo.valid or lay is None or len(data) != lay.size:
            return False
        values = lay.packer.unpack(data)
        cw_slot, target_slot = self._rpdo_slots[j]
        drive = self.drives[j]
        if target_slot >= 0:
            drive.received_target = drive.from_counts(values[target_slot])
            drive.target_received = True
        if cw_slot >= 0:
            drive.on_controlword(values[cw_slot])
        return True

    def drive_tpdos(self) -> list[tuple[int, bytes] | None]:
        """At a SYNC, after the drives latched: each drive's (COB-ID, TPDO1) or None when it sends none."""
        out: list[tuple[int, bytes] | None] = []
        for t in self._drive_tpdos:
            out.append(
                (t.pdo.config.cob_id, t.pack()) if t.pack is not None and t.pdo.due_on_sync() else None
            )
        return out

    def rogue_drive_tpdo(self, j: int, offset: float) -> tuple[int, bytes] | None:
        """Drive ``j``'s TPDO as mapped, reporting ``offset`` [unit] more than the drive: what someone
        else on its COB-ID sends (fault injection). Not a transmission of the drive's own."""
        t = self._drive_tpdos[j]
        if t.pack is None:
            return None
        drive = self.drives[j]
        true_error = drive.reported_position_error
        drive.reported_position_error = true_error + offset
        try:
            return t.pdo.config.cob_id, t.pack()
        finally:
            drive.reported_position_error = true_error

    def sensor_tpdos(self) -> list[tuple[int, bytes]]:
        """At a SYNC: the sensor latches a sample; its valid TPDOs as mapped."""
        if self.sensor is None:
            return []
        self.sensor.latch()
        return [
            (t.pdo.config.cob_id, t.pack())
            for t in self._sensor_tpdos
            if t.pack is not None and t.pdo.due_on_sync()
        ]
