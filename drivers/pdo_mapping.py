"""PDO communication and mapping parameters (CiA 301 §7.5.2.35-38) and the byte layouts they define.

Shared by both sides of the bus: the controller writes a ``PdoConfig`` to a device at start
(``drivers/node_setup.py``) and builds its cyclic codecs from what it reads back; a simulated
device keeps the same parameters as written over SDO and packs its PDOs with the same
``PdoLayout``. The layout is a ``struct.Struct`` built once per mapping: a cycle only packs and
unpacks a tuple.

A mapping entry is the UNSIGNED32 ``index << 16 | subindex << 8 | length in bits`` (CiA 301
§7.5.2.36); the entries of a PDO are laid out in order, little-endian, byte-aligned (this
project maps no bit fields: every mapped length must be a whole number of bytes).
"""

from __future__ import annotations

import configparser
import contextlib
import enum
import io
import logging
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import canopen
from canopen.objectdictionary import ObjectDictionaryError, ODVariable

from controller.errors import InputError
from controller.text_files import one_line, read_text_file

log = logging.getLogger(__name__)

COB_ID_INVALID = 0x80000000  # bit 31 of a PDO COB-ID: the PDO does not exist (CiA 301 Table 70)
COB_ID_NO_RTR = 0x40000000  # bit 30: no remote frame for this PDO
COB_ID_MASK = 0x7FF  # 11-bit identifiers only (bit 29 clear)
MAX_CLASSICAL_PDO_BYTES = 8
MAX_MAPPED_OBJECTS = 8  # at most eight entries in one classical PDO (one byte each at the least)
TRANSMISSION_SYNCHRONOUS = 1  # CiA 301 Table 71: synchronous, every SYNC


class PdoMappingError(InputError):
    """A mapping cannot be built or laid out; the message names the node, object and value."""


class DeviceDescriptionError(PdoMappingError):
    """An EDS file that cannot be read, decoded or parsed; one line naming the file and the fault."""


class PdoDirection(enum.Enum):
    RECEIVE = "RPDO"  # the device receives it (0x1400 / 0x1600 + n - 1)
    TRANSMIT = "TPDO"  # the device transmits it (0x1800 / 0x1A00 + n - 1)


@dataclass(frozen=True)
class MappedObject:
    index: int
    subindex: int
    bit_length: int

    @property
    def entry(self) -> int:
        return (self.index << 16) | (self.subindex << 8) | self.bit_length

    @classmethod
    def from_entry(cls, entry: int) -> MappedObject:
        return cls((entry >> 16) & 0xFFFF, (entry >> 8) & 0xFF, entry & 0xFF)

    def __str__(self) -> str:
        return f"0x{self.index:04X}sub{self.subindex} ({self.bit_length} bit)"


@dataclass(frozen=True)
class PdoConfig:
    """One PDO's communication and mapping parameters, as written to and read back from a device."""

    direction: PdoDirection
    number: int  # 1-based: RPDO1 is 0x1400 / 0x1600
    cob_id: int
    transmission_type: int
    objects: tuple[MappedObject, ...]

    @property
    def communication_index(self) -> int:
        return (0x1400 if self.direction == PdoDirection.RECEIVE else 0x1800) + self.number - 1

    @property
    def mapping_index(self) -> int:
        return self.communication_index + 0x200

    @property
    def name(self) -> str:
        return f"{self.direction.value}{self.number}"

    def with_objects(self, objects: tuple[MappedObject, ...]) -> PdoConfig:
        return PdoConfig(self.direction, self.number, self.cob_id, self.transmission_type, objects)


def struct_char(var: ODVariable) -> str:
    """The ``struct`` code of a mappable variable (canopen's own struct for its data type)."""
    packer = ODVariable.STRUCT_TYPES.get(var.data_type) if var.data_type is not None else None
    fmt = getattr(packer, "format", "")
    fmt = fmt.lstrip("<") if isinstance(fmt, str) else ""
    if len(fmt) != 1:  # "<h", "B"; the 24-, 40-, 48- and 56-bit types have no struct code
        raise PdoMappingError(
            f"object 0x{var.index:04X}sub{var.subindex} has data type "
            f"0x{var.data_type or 0:04X}, which this project cannot map"
        )
    return fmt


@dataclass(frozen=True)
class PdoLayout:
    """The byte layout of one mapped PDO: a struct built once, and which slot holds which object."""

    objects: tuple[MappedObject, ...]
    packer: struct.Struct

    @property
    def size(self) -> int:
        return self.packer.size

    def slot(self, index: int, subindex: int = 0) -> int:
        """Position of an object in the unpacked tuple; -1 when it is not mapped."""
        for k, obj in enumerate(self.objects):
            if (obj.index, obj.subindex) == (index, subindex):
                return k
        return -1


def layout(objects: tuple[MappedObject, ...], od: canopen.ObjectDictionary, where: str) -> PdoLayout:
    """The layout of ``objects`` with the data types of ``od``; ``where`` names the PDO in errors."""
    chars = []
    for obj in objects:
        var = find_variable(od, obj.index, obj.subindex)
        if var is None:
            raise PdoMappingError(f"{where}: {obj} is not in the device description")
        char = struct_char(var)
        if struct.calcsize("<" + char) * 8 != obj.bit_length:
            raise PdoMappingError(
                f"{where}: {obj} has {struct.calcsize('<' + char) * 8} bits in the "
                f"device description, mapped with {obj.bit_length}"
            )
        chars.append(char)
    packer = struct.Struct("<" + "".join(chars))
    if packer.size > MAX_CLASSICAL_PDO_BYTES:
        raise PdoMappingError(
            f"{where}: mapping {', '.join(map(str, objects))} takes {packer.size} bytes, "
            f"a PDO carries at most {MAX_CLASSICAL_PDO_BYTES}"
        )
    return PdoLayout(objects, packer)


def find_variable(od: canopen.ObjectDictionary, index: int, subindex: int) -> ODVariable | None:
    try:
        entry = od[index]
    except KeyError:
        return None
    if isinstance(entry, ODVariable):
        return entry if subindex == 0 else None
    try:
        var = entry[subindex]
    except KeyError:
        return None
    return var if isinstance(var, ODVariable) else None


def load_device_description(eds: Path, node_id: int) -> canopen.ObjectDictionary:
    """The object dictionary of the EDS file ``eds`` for ``node_id`` (canopen's EDS import).

    Every way a file can be wrong is a ``DeviceDescriptionError`` naming the file: not there, a
    directory, unreadable, empty, not UTF-8 text, not INI syntax, a section twice, no objects.
    """
    text = read_text_file(eds, "device description", DeviceDescriptionError)
    with _held_log_records("canopen.objectdictionary") as warnings:
        od = _parse_device_description(eds, text, node_id)
    if len(od) == 0:
        raise DeviceDescriptionError(
            f"device description {eds} describes no objects (no [1000]-style sections)"
        )
    for record in warnings:  # only for a file that loads: a refused one gets its one line alone
        log.warning("device description %s: %s", eds, record.getMessage())
    return od


@contextlib.contextmanager
def _held_log_records(logger_name: str) -> Iterator[list[logging.LogRecord]]:
    """Keep what ``logger_name`` logs inside the block from the handlers; the records are yielded."""
    records: list[logging.LogRecord] = []
    handler = _ListHandler(records)
    logger = logging.getLogger(logger_name)
    propagate = logger.propagate
    logger.addHandler(handler)
    logger.propagate = False
    try:
        yield records
    finally:
        logger.removeHandler(handler)
        logger.propagate = propagate


class _ListHandler(logging.Handler):
    def __init__(self, records: list[logging.LogRecord]) -> None:
        super().__init__(logging.WARNING)
        self.records = records

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(record)


def _parse_device_description(eds: Path, text: str, node_id: int) -> canopen.ObjectDictionary:
    """canopen's EDS import of ``text``; its parser's exceptions become one line naming ``eds``."""
    where = f"device description {eds}"
    stream = io.StringIO(text)
    stream.name = (
        str(eds) if eds.suffix.lower() in (".eds", ".dcf") else f"{eds}.eds"
    )  # canopen picks by suffix
    try:
        return canopen.import_od(stream, node_id)
    except configparser.MissingSectionHeaderError as err:
        raise DeviceDescriptionError(
            f"{where}: line {err.lineno} comes before any [section] header: {one_line(err.line)}"
        ) from None
    except configparser.DuplicateSectionError as err:
        raise DeviceDescriptionError(
            f"{where}: line {err.lineno}: section [{err.section}] appears twice"
        ) from None
    except configparser.DuplicateOptionError as err:
        raise DeviceDescriptionError(
            f"{where}: line {err.lineno}: key {err.option} appears twice in section [{err.section}]"
        ) from None
    except configparser.ParsingError as err:
        lineno, line = err.errors[0]
        raise DeviceDescriptionError(
            f"{where}: line {lineno} is not KEY=VALUE: {one_line(line)} (a truncated or damaged file?)"
        ) from None
    except (configparser.Error, ObjectDictionaryError, KeyError, ValueError, IndexError, TypeError) as err:
        # canopen reads the sections without checking them: a missing key (NoOptionError), a
        # value that is no number (ValueError), a sub-object without its parent (KeyError)
        raise DeviceDescriptionError(
            f"{where} is not a valid device description: {one_line(getattr(err, 'message', None) or err)}"
        ) from None


def _default(od: canopen.ObjectDictionary, index: int, subindex: int, where: str) -> int:
    var = find_variable(od, index, subindex)
    if var is None or not isinstance(var.default, int):
        raise PdoMappingError(
            f"{where}: the device description has no default for 0x{index:04X}sub{subindex}"
        )
    return var.default


def pdo_from_description(
    od: canopen.ObjectDictionary, direction: PdoDirection, number: int, node_id: int
) -> PdoConfig:
    """A PDO as the EDS's defaults describe it (COB-ID ``$NODEID+...`` resolved by canopen)."""
    probe = PdoConfig(direction, number, 0, 0, ())
    where = f"node {node_id} {probe.name}"
    comm, mapping = probe.communication_index, probe.mapping_index
    cob_id = _default(od, comm, 1, where) & ~COB_ID_INVALID
    count = _default(od, mapping, 0, where)
    objects = tuple(MappedObject.from_entry(_default(od, mapping, k, where)) for k in range(1, count + 1))
    return PdoConfig(direction, number, cob_id, _default(od, comm, 2, where), objects)


def parse_object_reference(text: str) -> tuple[int, int]:
    """``"0x607A"`` or ``"0x2000:1"`` (index, subindex in hex/decimal as Python reads them)."""
    index_text, _, sub_text = text.partition(":")
    try:
        index = int(index_text, 0)
        subindex = int(sub_text, 0) if sub_text else 0
    except ValueError:
        raise PdoMappingError(
            f"mapped object {text!r} is not INDEX or INDEX:SUBINDEX (like 0x607A or 0x2000:1)"
        ) from None
    if not (0 <= index <= 0xFFFF and 0 <= subindex <= 0xFF):
        raise PdoMappingError(f"mapped object {text!r} is outside 0x0000..0xFFFF:0..255")
    return index, subindex


def objects_from_references(
    references: tuple[str, ...], od: canopen.ObjectDictionary, where: str
) -> tuple[MappedObject, ...]:
    """Mapped objects named in the configuration, their lengths from the device description."""
    objects = []
    for text in references:
        index, subindex = parse_object_reference(text)
        var = find_variable(od, index, subindex)
        if var is None:
            raise PdoMappingError(f"{where}: object {text} is not in the device description")
        if not var.pdo_mappable:
            raise PdoMappingError(
                f"{where}: object {text} ({var.name}) is not PDO-mappable in the device description"
            )
        objects.append(MappedObject(index, subindex, len(var)))
    return tuple(objects)


def planned_pdo(
    od: canopen.ObjectDictionary,
    direction: PdoDirection,
    number: int,
    node_id: int,
    references: tuple[str, ...],
) -> PdoConfig:
    """What the master writes: the EDS's default PDO, its objects replaced by the configured ones
    (when any), synchronous (every SYNC: the cycle needs each TPDO once per period)."""
    default = pdo_from_description(od, direction, number, node_id)
    objects = (
        objects_from_references(references, od, f"node {node_id} {default.name}")
        if references
        else default.objects
    )
    config = PdoConfig(direction, number, default.cob_id, TRANSMISSION_SYNCHRONOUS, objects)
    layout(objects, od, f"node {node_id} {config.name}")  # refuses a mapping over 8 bytes before any write
    return config


def remap_writes(config: PdoConfig) -> list[tuple[int, int, int]]:
    """The (index, subindex, value) SDO writes of CiA 301's remap procedure for ``config``: invalid
    (COB-ID bit 31), transmission type, count 0, entries, count, valid again."""
    comm, mapping = config.communication_index, config.mapping_index
    return [
        (comm, 1, config.cob_id | COB_ID_INVALID),
        (comm, 2, config.transmission_type),
        (mapping, 0, 0),
        *((mapping, k, obj.entry) for k, obj in enumerate(config.objects, start=1)),
        (mapping, 0, len(config.objects)),
        (comm, 1, config.cob_id),
    ]
