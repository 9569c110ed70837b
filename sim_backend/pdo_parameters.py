"""A simulated device's PDO communication and mapping parameters, as a CANopen slave keeps them.

A master writes them over SDO (``DevicePdos.write`` is called from the canopen ``LocalNode``'s
write callback before the value is stored); an invalid write is refused with the SDO abort
code CiA 301 gives for it, so nothing invalid is ever stored or used. The device packs its
TPDOs and unpacks its RPDOs with the layout of the mapping in force (``drivers.pdo_mapping``),
rebuilt only when a mapping is enabled.

The remap procedure (CiA 301 §7.5.2.36): make the PDO invalid (COB-ID bit 31 set), set the
number of mapped objects (sub 0) to 0, write the entries, set sub 0 to their number, make the
PDO valid again. Aborts:
- 0x08000022 an entry or a non-zero count written while the PDO is valid, or an entry written
  while the count is not 0 (the procedure was not followed: state of the device);
- 0x06040041 an entry naming an object that does not exist, is not mappable, has another
  length, or is mapped in the wrong direction;
- 0x06040042 the mapped objects would exceed the 8 bytes of a PDO;
- 0x06090031 a count above the entries this device has;
- 0x06090030 a transmission type this device does not support, or a COB-ID it cannot take
  (another identifier while valid, an extended or reserved identifier).
"""

from __future__ import annotations

import operator
import struct
from collections.abc import Callable
from dataclasses import dataclass, field

import canopen
from canopen import SdoAbortedError

from drivers.pdo_mapping import (
    COB_ID_INVALID,
    COB_ID_MASK,
    COB_ID_NO_RTR,
    MAX_CLASSICAL_PDO_BYTES,
    MappedObject,
    PdoConfig,
    PdoDirection,
    PdoLayout,
    PdoMappingError,
    find_variable,
    layout,
    pdo_from_description,
    remap_writes,
)

ABORT_CANNOT_MAP = 0x06040041
ABORT_PDO_LENGTH = 0x06040042
ABORT_VALUE_RANGE = 0x06090030
ABORT_VALUE_TOO_HIGH = 0x06090031
ABORT_DEVICE_STATE = 0x08000022
ABORT_READ_ONLY = 0x06010002

# CiA 301 Table 71. RPDO: 0-240 act on the next SYNC, 254/255 at once; TPDO: 1-240 every nth
# SYNC. Acyclic synchronous (0), RTR-only and event-driven TPDOs are not simulated.
RPDO_TRANSMISSION_TYPES = frozenset((*range(241), 254, 255))
TPDO_TRANSMISSION_TYPES = frozenset(range(1, 241))


@dataclass
class DevicePdo:
    """One PDO of a device: its parameters as written, and the layout of its enabled mapping."""

    config: PdoConfig
    capacity: int  # mapping entries the device has (sub-indices 1..capacity)
    entries: list[int]
    count: int
    valid: bool = True
    layout: PdoLayout | None = None
    syncs: int = 0  # SYNCs since this TPDO was last sent (transmission type n: every nth)

    def due_on_sync(self) -> bool:
        """Called once per SYNC for a TPDO: whether it goes out on this one."""
        if (
            not self.valid
            or self.layout is None
            or self.config.transmission_type not in TPDO_TRANSMISSION_TYPES
        ):
            return False  # an event-driven default (254/255) is not simulated: such a TPDO stays silent
        self.syncs += 1
        if self.syncs >= self.config.transmission_type:
            self.syncs = 0
            return True
        return False


@dataclass
class DevicePdos:
    """Every PDO of one simulated device, built from its EDS's defaults."""

    od: canopen.ObjectDictionary
    node_id: int
    pdos: dict[int, DevicePdo] = field(default_factory=dict)  # by communication and mapping index
    on_change: Callable[[], None] | None = None  # a mapping was enabled or a PDO made (in)valid
    fixed: bool = False  # its mappings refuse every write (0x06010002); the communication parameters do not

    @classmethod
    def from_description(cls, od: canopen.ObjectDictionary, node_id: int) -> DevicePdos:
        device = cls(od, node_id)
        for direction, base in ((PdoDirection.RECEIVE, 0x1600), (PdoDirection.TRANSMIT, 0x1A00)):
            for k in range(512):
                mapping = od.get(base + k)
                if mapping is None:
                    continue
                config = pdo_from_description(od, direction, k + 1, node_id)
                subindices = getattr(mapping, "subindices", {})  # a record; an EDS may declare a variable
                capacity = max((s for s in subindices if s > 0), default=0)
                if len(config.objects) > capacity:
                    raise PdoMappingError(
                        f"node {node_id} {config.name}: 0x{base + k:04X} maps "
                        f"{len(config.objects)} objects and has {capacity} entries"
                    )
                entries = [0] * capacity
                for j, obj in enumerate(config.objects):
                    entries[j] = obj.entry
                pdo = DevicePdo(config, capacity, entries, len(config.objects))
                pdo.layout = layout(config.objects, od, f"node {node_id} {config.name}")
                device.pdos[config.communication_index] = device.pdos[config.mapping_index] = pdo
        return device

    def pdo(self, direction: PdoDirection, number: int) -> DevicePdo:
        base = 0x1400 if direction == PdoDirection.RECEIVE else 0x1800
        return self.pdos[base + number - 1]

    # -- SDO reads and writes ---------------------------------------------------------------

    def read(self, index: int, subindex: int) -> int | None:
        """A PDO parameter as the device has it (None: not one of its PDO parameters)."""
        pdo = self.pdos.get(index)
        if pdo is None:
            return None
        c = pdo.config
        if index == c.communication_index:
            if subindex == 1:
                return c.cob_id | (0 if pdo.valid else COB_ID_INVALID)
            return c.transmission_type if subindex == 2 else None
        if subindex == 0:
            return pdo.count
        return pdo.entries[subindex - 1] if 1 <= subindex <= pdo.capacity else None

    def write(self, index: int, subindex: int, value: int) -> None:
        """Check and apply an SDO write to a PDO parameter; raises SdoAbortedError to refuse it."""
        pdo = self.pdos.get(index)
        if pdo is None:
            return
        if self.fixed and index == pdo.config.mapping_index:
            raise SdoAbortedError(ABORT_READ_ONLY)  # a fixed mapping: its entries are read-only
        if index == pdo.config.communication_index:
            self._write_communication(pdo, subindex, value)
        else:
            self._write_mapping(pdo, subindex, value)

    def _write_communication(self, pdo: DevicePdo, subindex: int, value: int) -> None:
        c = pdo.config
        if subindex == 1:
            # bit 30 (no RTR) is accepted and ignored: this device never answers remote frames
            cob_id, valid = value & ~(COB_ID_INVALID | COB_ID_NO_RTR), not value & COB_ID_INVALID
            if cob_id & ~COB_ID_MASK or not 0x001 <= cob_id <= 0x7FF:
                raise SdoAbortedError(ABORT_VALUE_RANGE)  # extended (bit 29) or reserved identifier
            if pdo.valid and valid and cob_id != c.cob_id:
                raise SdoAbortedError(ABORT_VALUE_RANGE)  # CiA 301: change the id only while invalid
            if valid and pdo.count == 0:
                raise SdoAbortedError(ABORT_DEVICE_STATE)  # nothing mapped: no PDO to create
            pdo.config = PdoConfig(c.direction, c.number, cob_id, c.transmission_type, c.objects)
            pdo.valid = valid
            self._changed()
        elif subindex == 2:
            allowed = (
                RPDO_TRANSMISSION_TYPES if c.direction == PdoDirection.RECEIVE else TPDO_TRANSMISSION_TYPES
            )
            if value not in allowed:
                raise SdoAbortedError(ABORT_VALUE_RANGE)
            pdo.config = PdoConfig(c.direction, c.number, c.cob_id, value, c.objects)
            pdo.syncs = 0

    def _write_mapping(self, pdo: DevicePdo, subindex: int, value: int) -> None:
        if pdo.valid:
            raise SdoAbortedError(ABORT_DEVICE_STATE)  # remap only an invalid PDO
        if subindex == 0:
            if value > pdo.capacity:
                raise SdoAbortedError(ABORT_VALUE_TOO_HIGH)
            if value == 0:
                pdo.count, pdo.layout = 0, None
                return
            if pdo.count != 0:
                raise SdoAbortedError(ABORT_DEVICE_STATE)  # set the count to 0 first
            objects = tuple(MappedObject.from_entry(e) for e in pdo.entries[:value])
            for obj in objects:
                self._check_mappable(pdo, obj)
            bits = sum(obj.bit_length for obj in objects)
            if bits > 8 * MAX_CLASSICAL_PDO_BYTES:
                raise SdoAbortedError(ABORT_PDO_LENGTH)
            try:
                new_layout = layout(objects, self.od, f"node {self.node_id} {pdo.config.name}")
            except PdoMappingError:
                raise SdoAbortedError(ABORT_CANNOT_MAP) from None
            pdo.count, pdo.layout = value, new_layout
            pdo.config = pdo.config.with_objects(objects)
            self._changed()
        else:
            if pdo.count != 0:
                raise SdoAbortedError(ABORT_DEVICE_STATE)
            if subindex > pdo.capacity:
                raise SdoAbortedError(ABORT_VALUE_RANGE)
            self._check_mappable(pdo, MappedObject.from_entry(value))
            pdo.entries[subindex - 1] = value

    def _check_mappable(self, pdo: DevicePdo, obj: MappedObject) -> None:
        var = find_variable(self.od, obj.index, obj.subindex)
        if var is None or not var.pdo_mappable or len(var) != obj.bit_length:
            raise SdoAbortedError(ABORT_CANNOT_MAP)
        # an RPDO writes the object, a TPDO reads it (CiA 301: mapped in the wrong direction)
        if pdo.config.direction == PdoDirection.RECEIVE and not var.writable:
            raise SdoAbortedError(ABORT_CANNOT_MAP)
        if pdo.config.direction == PdoDirection.TRANSMIT and not var.readable:
            raise SdoAbortedError(ABORT_CANNOT_MAP)

    def _changed(self) -> None:
        if self.on_change is not None:
            self.on_change()

    # -- the set-up a master would do, for the in-process loopback ---------------------------

    def apply(self, config: PdoConfig) -> None:
        """Write ``config`` through the remap procedure, as a master's SDO writes would."""
        for index, subindex, value in remap_writes(config):
            self.write(index, subindex, value)

    def fix(self, config: PdoConfig) -> None:
        """Give the PDO ``config`` for good: a device whose mapping is fixed (quirk fixed_mapping)."""
        self.apply(config)
        self.fixed = True


def value_packer(
    pdo: DevicePdo, getters: dict[tuple[int, int], Callable[[], int]]
) -> Callable[[], bytes] | None:
    """A function packing the current values of a TPDO's mapped objects; None when not mapped."""
    if pdo.layout is None:
        return None
    packer: struct.Struct = pdo.layout.packer
    reads = tuple(getters.get((o.index, o.subindex), _zero) for o in pdo.layout.objects)
    pack, call = packer.pack, operator.call
    return lambda: pack(*map(call, reads))  # map in C: no generator frame per value (issue 37)


def _zero() -> int:
    return 0
