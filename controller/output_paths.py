"""Checking where a command will write before it does any work.

``cheope demo --plot /proc/1/nope`` (now --output-dir) failed after the whole 80-s run, ``cheope replay REC --rerun
/proc/1/x.rrd`` with a traceback: an output that cannot be written is found at start, with one
line naming the option, the path and why (``InputError``, exit code 2). A directory is created
(with its parents) and a file is created in it and removed again, which is what writing needs;
an output file's directory is checked the same way, the file itself left alone.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

from controller.errors import InputError


class OutputPathError(InputError):
    """An output directory or file named on the command line cannot be written."""


def _unwritable(directory: Path) -> str:
    """Why no file can be written in ``directory`` (created if missing), or ''."""
    try:
        directory.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=".cheope-write-check-", dir=directory)
        os.close(fd)
        os.unlink(probe)
    except OSError as err:
        return err.strerror or str(err)
    return ""


def check_output_dir(path: str | Path, option: str) -> Path:
    """``path`` as a directory this process can write files into (created if missing)."""
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise OutputPathError(f"{option} {p}: is not a directory")
    why = _unwritable(p)
    if why:
        raise OutputPathError(f"{option} {p}: cannot write there: {why}")
    return p


def check_output_file(path: str | Path, option: str) -> Path:
    """``path`` as a file this process can create or overwrite (its directory is created if missing)."""
    p = Path(path)
    if p.is_dir():
        raise OutputPathError(f"{option} {p}: is a directory, not a file")
    if p.exists() and not os.access(p, os.W_OK):
        raise OutputPathError(f"{option} {p}: exists and cannot be overwritten (no write permission)")
    why = _unwritable(p.parent)
    if why:
        raise OutputPathError(f"{option} {p}: cannot write in {p.parent}: {why}")
    return p


def existing_output_error(command: str, path: Path) -> OutputPathError:
    """The one refusal of an output file that is there already: a command that writes a new file
    (``logs recover``, ``logs export``) never overwrites one, which may be another recording."""
    return OutputPathError(f"{command}: {path} already exists; pass another output file")


def refuse_existing_output(command: str, path: Path) -> None:
    """Refuse ``path`` before any work when it exists (a dangling symbolic link included)."""
    if path.exists() or path.is_symlink():
        raise existing_output_error(command, path)


def publish_new_file(command: str, written: Path, path: Path) -> None:
    """Give the finished file ``written`` (in ``path``'s directory) the name ``path``, unless a file
    took that name meanwhile: a hard link fails then where a rename would replace it. ``written``
    is gone afterwards either way."""
    try:
        try:
            os.link(written, path)
        except FileExistsError:
            raise
        except OSError:  # no hard links there (vfat, some network file systems): a copy, created new
            with open(written, "rb") as src, open(path, "xb") as dst:
                shutil.copyfileobj(src, dst)
    except FileExistsError as err:
        raise existing_output_error(command, path) from err
    except OSError as err:
        raise OutputPathError(f"{command}: cannot create {path}: {err.strerror or err}") from err
    finally:
        written.unlink(missing_ok=True)
