"""The client side of the queryables: ``cheope status`` and ``cheope stop`` / ``cheope command``."""

from __future__ import annotations

import zenoh

from controller.messages import cheope_pb2 as pb
from controller.monitoring.zenoh_session import (
    MonitoringConnectionError,
    MonitorKeys,
    SessionSettings,
    encoding_for,
    open_session,
)


def _one_reply(settings: SessionSettings, key: str, timeout_s: float, payload: bytes | None = None,
               encoding: zenoh.Encoding | None = None) -> bytes:
    session, _ = open_session(settings)
    try:
        if payload is not None:
            replies = session.get(key, timeout=timeout_s, payload=payload, encoding=encoding)
        else:
            replies = session.get(key, timeout=timeout_s)
        for reply in replies:
            if reply.ok is not None:
                return reply.ok.payload.to_bytes()
            err = reply.err  # not None when ok is None
            detail = err.payload.to_bytes() if err is not None else b""
            raise MonitoringConnectionError(f"{key} answered with an error: {detail!r}")
    finally:
        session.close()
    where = ", ".join(settings.connect) or "the configured endpoints"
    raise MonitoringConnectionError(f"no controller answered on {key} within {timeout_s:g} s (connected to {where})")


def query_status(settings: SessionSettings, keys: MonitorKeys, timeout_s: float = 2.0) -> pb.Status:
    """Ask the controller's ``status`` queryable once."""
    return pb.Status.FromString(_one_reply(settings, keys.status, timeout_s))


def send_command(settings: SessionSettings, keys: MonitorKeys, name: str, value: float = 0.0,
                 timeout_s: float = 2.0) -> pb.CommandReply:
    """Send one command (``stop``, ``pause``, ``resume``, ``set_force``) and return the controller's answer."""
    cmd = pb.Command(name=name, value=value)
    return pb.CommandReply.FromString(
        _one_reply(settings, keys.command, timeout_s, cmd.SerializeToString(), encoding_for("Command")))
