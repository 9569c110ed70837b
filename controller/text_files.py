"""Reading a user's text file (a TOML configuration, an EDS device description) with one-line errors.

Whatever is at the path, the caller gets the text or an ``InputError`` (of the caller's class)
naming the file and what is wrong with it: nothing there, a directory, unreadable, too large
(``/dev/zero``), empty, UTF-16, not UTF-8, binary. Both formats are UTF-8 (TOML by its specification; CiA 306 EDS
files are ASCII, a subset); a UTF-8 byte-order mark is allowed.
"""

from __future__ import annotations

import codecs
from pathlib import Path

from controller.errors import InputError

_UTF16_BOMS = (codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE)  # UTF-32 LE starts like UTF-16 LE
_ALLOWED_CONTROLS = "\t\r\n"
# The largest text file read: a configuration is a few kB, a vendor's EDS file a few hundred. A
# bound, because whatever is at the path is read: /dev/zero given as --config read until memory
# was exhausted (5.2 GB in 16 s). Anything larger is refused before more of it is read.
MAX_TEXT_FILE_BYTES = 4 * 1024 * 1024


def read_text_file(
    path: Path, what: str, error: type[InputError] = InputError, limit_bytes: int = MAX_TEXT_FILE_BYTES
) -> str:
    """The text of ``path``; ``what`` begins each message ("configuration file", "device description").

    At most ``limit_bytes`` are read, from a regular file, a pipe (``--config <(...)``) or a device
    alike; more is refused with the bound in the message."""
    where = f"{what} {path}"
    if path.is_dir():
        raise error(f"{where} is a directory, not a file")
    try:
        with path.open("rb") as f:
            data = f.read(limit_bytes + 1)
    except FileNotFoundError:
        raise error(f"{where} does not exist") from None
    except OSError as err:
        raise error(f"{where} cannot be read: {err.strerror or err}") from None
    if len(data) > limit_bytes:
        raise error(
            f"{where} is larger than {limit_bytes // (1024 * 1024)} MiB, more than any {what} is "
            "(is it the file meant?)"
        )
    if not data.strip():
        raise error(f"{where} is empty")
    if data.startswith(_UTF16_BOMS):
        raise error(f"{where} is UTF-16 text; save it as UTF-8")
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as err:
        line, column = text_position(data, err.start)
        raise error(
            f"{where} is not UTF-8 text: byte 0x{data[err.start]:02X} at line {line}, column {column}; "
            "save it as UTF-8"
        ) from None
    control = next((k for k, ch in enumerate(text) if ch < " " and ch not in _ALLOWED_CONTROLS), None)
    if control is not None:
        line, column = text_position(text, control)
        raise error(
            f"{where} is not a text file: control character 0x{ord(text[control]):02X} at line {line}, "
            f"column {column}"
        )
    return text


def text_position(text: str | bytes, offset: int) -> tuple[int, int]:
    """1-based line and column of ``offset`` in ``text``."""
    if isinstance(text, bytes):
        text = text[:offset].decode("latin-1")  # one character per byte: the same offsets
    before = text[:offset]
    return before.count("\n") + 1, offset - (before.rfind("\n") + 1) + 1


def one_line(value: object, limit: int = 160) -> str:
    """``value`` as one line of at most ``limit`` characters (a parser's message may span lines)."""
    text = " ".join(str(value).split())
    return text if len(text) <= limit else text[: limit - 3] + "..."
