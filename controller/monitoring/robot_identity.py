"""Robot ids that tell controllers apart: a unique default, and a start refused on a taken id.

Issue 18: every controller was ``cheope-1``, so ``cheope status`` answered from another
user's demo and ``cheope stop`` would have stopped it. Decision:

- ``monitoring.robot_id = ""`` (the default) draws ``<host>-<4 hex digits>``: the host names
  the machine in ``cheope list``, the suffix separates the controllers on one machine (one
  in 65 536 draws collide, and a collision is seen and redrawn, see below);
- before a controller declares its liveliness token ``<prefix>/<id>/alive`` it asks every
  session it reaches (its connect endpoints, a router, the peers connected to it) for that
  token. A configured id that is live elsewhere refuses the start (``RobotIdTakenError``,
  exit code 2): two controllers with one id would answer each other's ``cheope stop``. A
  drawn id draws again.

Two controllers of one user on one machine also see each other's announcement
(local_controllers.py): by default a controller only listens, so no liveliness query of the
other one reaches it, and before that check a second ``cheope run --robot-id X`` took the id
of a running ``X`` and answered its ``cheope stop`` (an outside tester's finding). Two
controllers starting at the same instant can both pass the check (a window of a few
milliseconds); controllers of other machines or users that are not connected to this one
cannot be seen at all: ``cheope list`` shows the same.
"""

from __future__ import annotations

import re
import secrets
import socket

import zenoh

from controller.errors import RefusedError
from controller.monitoring.local_controllers import announced_elsewhere
from controller.monitoring.zenoh_session import is_key_chunk

ALIVE_TIMEOUT_S = 1.0  # how long a liveliness query waits for the sessions it reaches
_NOT_IN_AN_ID = re.compile(r"[^A-Za-z0-9_.\-]+")
_DRAWS = 4


class RobotIdTakenError(RefusedError):
    """A configured ``monitoring.robot_id`` is already held by a live controller."""


def default_robot_id(host: str | None = None) -> str:
    """``<host>-<4 hex digits>``; the host name reduced to the characters a key chunk allows."""
    name = _NOT_IN_AN_ID.sub("-", (host if host is not None else socket.gethostname()).split(".")[0]).strip(
        "-"
    )
    return f"{name or 'host'}-{secrets.token_hex(2)}"


def resolve_robot_id(configured: str) -> str:
    return configured or default_robot_id()


def live_robot_ids(
    session: zenoh.Session, key_prefix: str, robot_id: str = "*", timeout_s: float = ALIVE_TIMEOUT_S
) -> list[str]:
    """The ids whose token ``<key_prefix>/<robot_id>/alive`` is live among the sessions reached (sorted)."""
    ids = set()
    depth = key_prefix.count("/") + 1
    for reply in session.liveliness().get(f"{key_prefix}/{robot_id}/alive", timeout=timeout_s):
        if reply.ok is not None:
            chunks = str(reply.ok.key_expr).split("/")
            # a token no controller declares (cheope/*/alive, cheope/**, "a b") names no robot a
            # tool can address: before, its id ended `cheope list` and `stop --all` for every robot
            if len(chunks) == depth + 2 and is_key_chunk(chunks[depth]):
                ids.add(chunks[depth])
    return sorted(ids)


def claim_robot_id(
    session: zenoh.Session, key_prefix: str, robot_id: str, drawn: bool, timeout_s: float = ALIVE_TIMEOUT_S
) -> str:
    """``robot_id`` if no session reached holds it and no other controller of this user on this
    machine announces it; a drawn id is redrawn, a configured one refused."""
    for _ in range(_DRAWS):
        pid = announced_elsewhere(robot_id)
        if pid is None and not live_robot_ids(session, key_prefix, robot_id, timeout_s):
            return robot_id
        if not drawn:
            holder = (
                f"the controller of process {pid} on this machine announces it"
                if pid is not None
                else f"a live controller holds {key_prefix}/{robot_id}/alive"
            )
            raise RobotIdTakenError(
                f"monitoring.robot_id = {robot_id!r} is taken: {holder} "
                "(`cheope list` shows the controllers reachable); choose another id "
                "(--set monitoring.robot_id=...) or leave it empty for a unique one"
            )
        robot_id = default_robot_id()
    raise RobotIdTakenError(
        f"{_DRAWS} drawn robot ids under {key_prefix}/ were all taken; set monitoring.robot_id"
    )
