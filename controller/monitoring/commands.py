"""The client side of the queryables and of the liveliness tokens: ``cheope list``, ``status``,
``stop`` and ``command``.

A tool addresses a robot by id, or, given none, the only controller it reaches: with none
or several it says so in one line instead of guessing (issue 18: ``cheope stop`` must not
stop whichever controller happens to answer first).
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import zenoh

from controller.messages import cheope_pb2 as pb
from controller.monitoring.robot_identity import live_robot_ids
from controller.monitoring.zenoh_session import (
    MonitoringConnectionError,
    MonitorKeys,
    SessionSettings,
    encoding_for,
    open_tool_session,
)


@dataclass(frozen=True)
class RobotSelector:
    """A robot under ``key_prefix``: by id, or (``robot_id=None``) the only one reachable."""

    key_prefix: str = "cheope"
    robot_id: str | None = None


Target = MonitorKeys | RobotSelector


def _where(settings: SessionSettings) -> str:
    return ", ".join(settings.connect) or "the configured endpoints"


@contextmanager
def tool_session(settings: SessionSettings) -> Iterator[zenoh.Session]:
    session = open_tool_session(settings)
    try:
        yield session
    finally:
        session.close()


def resolve(session: zenoh.Session, settings: SessionSettings, target: Target) -> MonitorKeys:
    if isinstance(target, MonitorKeys):
        return target
    if target.robot_id is not None:
        return MonitorKeys.for_robot(target.key_prefix, target.robot_id)
    ids = live_robot_ids(session, target.key_prefix)
    if not ids:
        raise MonitoringConnectionError(
            f"no controller found under {target.key_prefix}/*/ (connected to {_where(settings)})"
        )
    if len(ids) > 1:
        raise MonitoringConnectionError(
            f"{len(ids)} controllers reachable ({', '.join(ids)}): choose one with --robot-id"
        )
    return MonitorKeys.for_robot(target.key_prefix, ids[0])


def _one_reply(
    session: zenoh.Session,
    settings: SessionSettings,
    key: str,
    timeout_s: float,
    payload: bytes | None = None,
    encoding: zenoh.Encoding | None = None,
) -> bytes:
    if payload is not None:
        replies = session.get(key, timeout=timeout_s, payload=payload, encoding=encoding)
    else:
        replies = session.get(key, timeout=timeout_s)
    for reply in replies:
        if reply.ok is not None:
            return reply.ok.payload.to_bytes()
        err = reply.err  # not None when ok is None
        detail = err.payload.to_bytes() if err is not None else b""
        if detail != b"Timeout":  # Zenoh's own end of a get that waited for more answers
            raise MonitoringConnectionError(f"{key} answered with an error: {detail!r}")
    raise MonitoringConnectionError(
        f"no controller answered on {key} within {timeout_s:g} s (connected to {_where(settings)})"
    )


def query_status(settings: SessionSettings, target: Target, timeout_s: float = 2.0) -> pb.Status:
    """Ask the controller's ``status`` queryable once."""
    with tool_session(settings) as session:
        keys = resolve(session, settings, target)
        return pb.Status.FromString(_one_reply(session, settings, keys.status, timeout_s))


def send_command(
    settings: SessionSettings, target: Target, name: str, value: float = 0.0, timeout_s: float = 2.0
) -> tuple[str, pb.CommandReply]:
    """Send one command (``stop``, ``pause``, ``resume``, ``reset``, ``set_force``); the robot id and its answer."""
    cmd = pb.Command(name=name, value=value)
    with tool_session(settings) as session:
        keys = resolve(session, settings, target)
        reply = _one_reply(
            session, settings, keys.command, timeout_s, cmd.SerializeToString(), encoding_for("Command")
        )
        return keys.prefix.rsplit("/", 1)[1], pb.CommandReply.FromString(reply)


def stop_every_robot(
    settings: SessionSettings, key_prefix: str = "cheope", timeout_s: float = 2.0
) -> list[tuple[str, bool, str]]:
    """``cheope stop --all``: a stop to each live controller by its own id (no wildcard key: the
    controllers refuse one); (robot id, accepted, message) each, a robot that did not answer refused."""
    out = []
    cmd = pb.Command(name="stop").SerializeToString()
    with tool_session(settings) as session:
        for robot_id in live_robot_ids(session, key_prefix, timeout_s=timeout_s):
            keys = MonitorKeys.for_robot(key_prefix, robot_id)
            try:
                reply = pb.CommandReply.FromString(
                    _one_reply(session, settings, keys.command, timeout_s, cmd, encoding_for("Command"))
                )
            except MonitoringConnectionError as err:
                out.append((robot_id, False, str(err)))
                continue
            out.append((robot_id, reply.accepted, reply.message))
    return out


@dataclass(frozen=True)
class ControllerListing:
    """One line of ``cheope list``: a live controller and what its status said (empty if it did not answer)."""

    robot_id: str
    mode: str = ""
    task: str = ""
    uptime_s: float | None = None
    listen_endpoints: tuple[str, ...] = ()
    software_version: str = ""


def list_controllers(
    settings: SessionSettings, key_prefix: str = "cheope", timeout_s: float = 2.0
) -> list[ControllerListing]:
    """Every controller whose liveliness token is live among the sessions reached, with its status."""
    out = []
    with tool_session(settings) as session:
        for robot_id in live_robot_ids(session, key_prefix, timeout_s=timeout_s):
            keys = MonitorKeys.for_robot(key_prefix, robot_id)
            try:
                st = pb.Status.FromString(_one_reply(session, settings, keys.status, timeout_s))
            except MonitoringConnectionError:  # alive but silent (busy, rate-limited): listed without details
                out.append(ControllerListing(robot_id))
                continue
            task = json.loads(st.config_json or "{}").get("task", {}).get("kind", "")
            out.append(
                ControllerListing(
                    robot_id, st.mode, task, st.uptime_s, tuple(st.listen_endpoints), st.software_version
                )
            )
    return out
