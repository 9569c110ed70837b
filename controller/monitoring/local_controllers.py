"""The controllers of this user on this machine: where each one's Zenoh session listens.

Every controller on a machine would otherwise be found at one default port (``tcp/127.0.0.1:7448``,
the first to take it; the others listen on free ports), so a tool without ``--zenoh-connect``
showed whichever controller held it, another user's too. So each controller announces its own
endpoints in a file of its own, ``<robot_id>.json`` in this user's runtime directory
(``$XDG_RUNTIME_DIR/cheope``, else ``/tmp/cheope-<uid>``; mode 0700, refused when another user owns
it), written at start and removed at the end; a file whose process is gone is stale and removed
by the next reader. The tools (``cheope list``, ``monitor``, ``status``, ``stop``, ``command``,
``ros2``) connect to the endpoints of these files when no ``--zenoh-connect`` is given, and to the
default port only when there is none: scoped to this user's controllers unless asked otherwise.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import tempfile
from pathlib import Path

log = logging.getLogger(__name__)


def runtime_directory() -> Path:
    """This user's directory of announcements (not created)."""
    base = os.environ.get("XDG_RUNTIME_DIR")
    if base and Path(base).is_dir():
        return Path(base) / "cheope"
    return Path(tempfile.gettempdir()) / f"cheope-{os.getuid()}"


def _own_directory() -> Path | None:
    """The runtime directory, created 0700 when missing; None when it is not this user's alone."""
    d = runtime_directory()
    try:
        d.mkdir(mode=0o700, parents=True, exist_ok=True)
        st = d.stat()
    except OSError as err:
        log.warning("monitoring: cannot use %s to announce this controller: %s", d, err.strerror or err)
        return None
    if not _this_users_alone(st):
        log.warning(
            "monitoring: %s is not this user's alone (owner %d, mode %o): not used", d, st.st_uid, st.st_mode
        )
        return None
    return d


def _this_users_alone(st: os.stat_result) -> bool:
    """A directory of this user that no one else may write to: the only one whose files are trusted."""
    return st.st_uid == os.getuid() and not st.st_mode & 0o077


def announce(robot_id: str, endpoints: tuple[str, ...]) -> Path | None:
    """Write ``<robot_id>.json`` (this process, its listen endpoints); the file, or None when none could be."""
    d = _own_directory()
    if d is None or not endpoints:
        return None
    path = d / f"{robot_id}.json"
    tmp = d / f".{robot_id}.{os.getpid()}.tmp"
    try:
        tmp.write_text(json.dumps({"robot_id": robot_id, "pid": os.getpid(), "listen": list(endpoints)}))
        tmp.replace(path)  # whole or not at all, for a reader at the same moment
    except OSError as err:
        log.warning("monitoring: cannot announce this controller in %s: %s", d, err.strerror or err)
        tmp.unlink(missing_ok=True)
        return None
    return path


def withdraw(path: Path | None) -> None:
    """Remove this process's announcement (another process's file of the same name stays)."""
    if path is None:
        return
    try:
        if json.loads(path.read_text()).get("pid") == os.getpid():
            path.unlink()
    except (OSError, ValueError):
        pass


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # a process of another user holds the pid now: not the announcer
        return False
    return True


def local_endpoints() -> tuple[str, ...]:
    """One listen endpoint (its first) of each of this user's live controllers on this machine (stale
    files removed). One, not all: Zenoh keeps one session per peer, so a second endpoint of the same
    controller reaches nobody more, and a tool judges "the only controller" by having reached every
    endpoint it connects to (commands.py)."""
    d = runtime_directory()
    out: list[str] = []
    try:
        files = sorted(d.glob("*.json"))
    except OSError:
        return ()
    for f in files:
        try:
            entry = json.loads(f.read_text())
            pid, listen = int(entry["pid"]), [str(e) for e in entry["listen"]]
        except (OSError, ValueError, KeyError, TypeError):
            continue  # being written, or not ours to judge
        if not _alive(pid):
            f.unlink(missing_ok=True)
            continue
        if listen and listen[0] not in out:
            out.append(listen[0])
    return tuple(out)


def announced_elsewhere(robot_id: str) -> int | None:
    """The pid of another live process of this user that announces ``robot_id`` on this machine;
    None when none does (a stale file is removed). A controller that only listens is reached by no
    liveliness query of another one (robot_identity.py): this file is how two of them on one
    machine see each other."""
    d = runtime_directory()
    try:
        st = d.stat()
    except OSError:
        return None
    if not _this_users_alone(st):
        return None  # another user's or shared (as announce refuses it): its files prove nothing
    path = d / f"{robot_id}.json"
    try:
        pid = int(json.loads(path.read_text())["pid"])
    except (OSError, ValueError, KeyError, TypeError):
        return None  # none, being written, or not ours to judge
    if pid == os.getpid():
        return None
    if not _alive(pid):
        with contextlib.suppress(OSError):
            path.unlink(missing_ok=True)
        return None
    return pid
