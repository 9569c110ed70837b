"""The client side of the queryables and of the liveliness tokens: ``cheope list``, ``status``,
``stop`` and ``command``.

A tool addresses a robot by id, or, given none, the only controller it reaches: with none
or several it says so in one line instead of guessing (issue 18: ``cheope stop`` must not
stop whichever controller happens to answer first). "The only one" is judged only on the whole
view: a tool that did not connect to every endpoint it was given refuses too. The open goes on
with the endpoints that answered within its wait; a controller whose process is stopped, or that a
busy machine kept from answering that long, was then missing from the view, and a tool given two
controllers' endpoints sent its command to the other one, the only one it saw (a stopped peer
is not connected, measured with eclipse-zenoh 1.10; once connected, its liveliness tokens are in
the tool's session and a query lists them at once).
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, TypeVar

import zenoh
from google.protobuf.message import DecodeError, Message

from controller.cli_output import printable
from controller.messages import cheope_pb2 as pb
from controller.monitoring.robot_identity import live_robot_ids
from controller.monitoring.zenoh_session import (
    MonitoringConnectionError,
    MonitorKeys,
    SessionSettings,
    connected,
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


def resolve(
    session: zenoh.Session, settings: SessionSettings, target: Target, timeout_s: float
) -> MonitorKeys:
    """The keys of the robot ``target`` names; without an id, of the only one reachable, judged on
    the whole view (module text): every endpoint given connected."""
    if isinstance(target, MonitorKeys):
        return target
    if target.robot_id is not None:
        return MonitorKeys.for_robot(target.key_prefix, target.robot_id)
    reached, given = connected(session), len(set(settings.connect))
    if reached < given:
        raise MonitoringConnectionError(
            f"reached {reached} of the {given} endpoints given ({_where(settings)}): a controller "
            "behind one not reached could be the one meant; choose one with --robot-id"
        )
    ids = live_robot_ids(session, target.key_prefix, timeout_s=timeout_s)
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


_Reply = TypeVar("_Reply", bound=Message)


def decode_reply(message: type[_Reply], data: bytes, key: str) -> _Reply:
    """A peer's answer on ``key`` as ``message``; ``MonitoringConnectionError`` naming the key when
    it is none (before, protobuf's ``DecodeError`` ended ``cheope list``, ``status`` and ``stop``
    with a traceback)."""
    try:
        reply: _Reply = message.FromString(data)
    except DecodeError as err:
        raise MonitoringConnectionError(
            f"{key} answered with {len(data)} bytes that are no {message.DESCRIPTOR.full_name} ({err})"
        ) from err
    return reply


def status_config(status: pb.Status, key: str) -> dict[str, Any]:
    """The configuration a status carries (``config_json``), or ``MonitoringConnectionError`` naming
    the key when it is not a JSON object."""
    try:
        config = json.loads(status.config_json or "{}")
    except json.JSONDecodeError as err:
        raise MonitoringConnectionError(f"{key}: the status's config_json is not JSON ({err})") from err
    except RecursionError:  # json nests recursively: '{"a":' * 5000 ended `cheope list` with a traceback
        raise MonitoringConnectionError(f"{key}: the status's config_json nests too deeply") from None
    if not isinstance(config, dict):
        raise MonitoringConnectionError(
            f"{key}: the status's config_json is a JSON {type(config).__name__}, not an object"
        )
    return config


def task_kind(config: dict[str, Any]) -> str:
    """The task a status's configuration names ("" when it names none a tool can show)."""
    task = config.get("task")
    kind = task.get("kind", "") if isinstance(task, dict) else ""
    return kind if isinstance(kind, str) else ""


def query_status(settings: SessionSettings, target: Target, timeout_s: float = 2.0) -> pb.Status:
    """Ask the controller's ``status`` queryable once; its configuration is checked to be a JSON object."""
    with tool_session(settings) as session:
        keys = resolve(session, settings, target, timeout_s)
        status = decode_reply(pb.Status, _one_reply(session, settings, keys.status, timeout_s), keys.status)
        own_status(status, keys)
        status_config(status, keys.status)
        return status


def own_status(status: pb.Status, keys: MonitorKeys) -> None:
    """``MonitoringConnectionError`` when the status on ``keys.status`` is another robot's: a peer
    that serves the key shows its own (an outside tester's "PWNED") as the robot asked for."""
    robot_id = keys.prefix.rsplit("/", 1)[1]
    if status.robot_id != robot_id:
        raise MonitoringConnectionError(
            f"{keys.status} answered with the status of robot {printable(status.robot_id, 80)!r}, "
            f"not {robot_id!r}: another process serves that key"
        )


def send_command(
    settings: SessionSettings, target: Target, name: str, value: float = 0.0, timeout_s: float = 2.0
) -> tuple[str, pb.CommandReply]:
    """Send one command (``stop``, ``pause``, ``resume``, ``reset``, ``set_force``); the robot id and its answer."""
    cmd = pb.Command(name=name, value=value)
    with tool_session(settings) as session:
        keys = resolve(session, settings, target, timeout_s)
        reply = _one_reply(
            session, settings, keys.command, timeout_s, cmd.SerializeToString(), encoding_for("Command")
        )
        return keys.prefix.rsplit("/", 1)[1], decode_reply(pb.CommandReply, reply, keys.command)


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
                reply = decode_reply(
                    pb.CommandReply,
                    _one_reply(session, settings, keys.command, timeout_s, cmd, encoding_for("Command")),
                    keys.command,
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
                st = decode_reply(
                    pb.Status, _one_reply(session, settings, keys.status, timeout_s), keys.status
                )
                own_status(st, keys)
                task = task_kind(status_config(st, keys.status))
            except MonitoringConnectionError:
                # alive but silent (busy, rate-limited) or answering what is no status: listed without details
                out.append(ControllerListing(robot_id))
                continue
            out.append(
                ControllerListing(
                    robot_id, st.mode, task, st.uptime_s, tuple(st.listen_endpoints), st.software_version
                )
            )
    return out
