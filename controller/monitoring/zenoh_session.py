"""Zenoh sessions of the controller and of its monitors: key names, configuration, opening.

Defaults keep everything on this machine: the controller's session listens on a loopback
endpoint (``tcp/127.0.0.1:7448``; 7447 is left to a local ``zenohd`` router), multicast and
gossip scouting are off, and nothing is connected unless configured (``--zenoh-connect`` or
a Zenoh JSON5 file with ``--zenoh-config``). A configuration file is the base; the keys it
leaves unset (mode, listen endpoints, scouting) get the loopback defaults, and
``--zenoh-connect`` endpoints are added to the ones it lists.

Key expressions, under ``<key_prefix>/<robot_id>/`` (``cheope/<host>-<suffix>/`` by default, robot_identity.py):
``state`` (MonitorState), ``events`` (Event), ``alive`` (liveliness token), ``status``
(queryable answering Status), ``command`` (queryable taking Command, answering CommandReply),
``schema`` (queryable answering the ``google.protobuf.FileDescriptorSet`` of cheope.proto: a
client decodes every payload without the repository).

Events go out through zenoh-ext's advanced publisher: it keeps the last ``EVENT_HISTORY`` of them
for subscribers that join late, and numbers them, with a heartbeat, so that a subscriber learns
of every event it missed (``declare_event_subscriber``: the history at once, and a count of what
went missing). Any plain Zenoh subscriber still receives the events as before.
"""

from __future__ import annotations

import json
import logging
import re
import socket
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from functools import cache
from pathlib import Path
from typing import Protocol

import zenoh
import zenoh.ext

from controller.config import ConfigError
from controller.errors import DeviceError
from controller.monitoring.local_controllers import local_endpoints
from controller.text_files import read_text_file

log = logging.getLogger(__name__)

DEFAULT_LISTEN = "tcp/127.0.0.1:7448"
DEFAULT_CONNECT = DEFAULT_LISTEN  # where monitors look for a controller on this machine
DEFAULT_ROUTER_LISTEN = "tcp/127.0.0.1:7447"  # zenohd's port: `cheope router` or a zenohd on this machine
PROTO_PACKAGE = "cheope.v1"
_CHUNK = re.compile(r"[A-Za-z0-9_.\-]+")


def is_key_chunk(text: str) -> bool:
    """Whether ``text`` is one chunk of a key this product declares (a prefix's part, a robot id)."""
    return _CHUNK.fullmatch(text) is not None


_ENDPOINT = re.compile(r"^(?P<proto>[a-z0-9\-]+)/(?P<addr>[^#?]+)(?P<rest>[#?].*)?$")
_IP_PROTOCOLS = ("tcp", "udp", "tls", "quic", "ws")
_LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "[::1]")


class MonitoringConnectionError(DeviceError, ConnectionError):
    """A Zenoh session could not be opened or nothing answered; the message says where."""


def encoding_for(message_name: str) -> zenoh.Encoding:
    """``application/protobuf;cheope.v1.<Message>``: the payload type, for any Zenoh client."""
    return zenoh.Encoding.APPLICATION_PROTOBUF.with_schema(f"{PROTO_PACKAGE}.{message_name}")


@dataclass(frozen=True)
class MonitorKeys:
    """The key expressions of one robot (``robot_id="*"`` on the monitor side: every robot)."""

    prefix: str

    @classmethod
    def for_robot(cls, key_prefix: str, robot_id: str, allow_wildcard: bool = False) -> MonitorKeys:
        chunks = key_prefix.split("/")
        if not key_prefix or not all(is_key_chunk(c) for c in chunks):
            raise ConfigError(
                f"monitoring.key_prefix = {key_prefix!r}: use chunks of letters, digits, "
                "'-', '_', '.' separated by '/'"
            )
        if not (is_key_chunk(robot_id) or (allow_wildcard and robot_id == "*")):
            raise ConfigError(f"monitoring.robot_id = {robot_id!r}: use letters, digits, '-', '_', '.'")
        return cls(f"{key_prefix}/{robot_id}")

    @property
    def state(self) -> str:
        return f"{self.prefix}/state"

    @property
    def events(self) -> str:
        return f"{self.prefix}/events"

    @property
    def alive(self) -> str:
        return f"{self.prefix}/alive"

    @property
    def status(self) -> str:
        return f"{self.prefix}/status"

    @property
    def command(self) -> str:
        return f"{self.prefix}/command"

    @property
    def schema(self) -> str:
        return f"{self.prefix}/schema"


EVENT_HISTORY = 64  # events an advanced publisher keeps for late subscribers
EVENT_HEARTBEAT_S = 1.0  # how soon a subscriber learns that the last event(s) went missing [s]
SCHEMA_ENCODING = "application/protobuf;google.protobuf.FileDescriptorSet"


def declare_event_publisher(session: zenoh.Session, key: str) -> zenoh.ext.AdvancedPublisher:
    """The events' publisher: congestion DROP (a slow network never blocks the loop), high priority,
    the last ``EVENT_HISTORY`` events cached for late joiners, sequence numbers and a sporadic
    heartbeat for miss detection, and a liveliness token so that subscribers started first find it."""
    return zenoh.ext.declare_advanced_publisher(
        session,
        key,
        encoding=encoding_for("Event"),
        congestion_control=zenoh.CongestionControl.DROP,
        priority=zenoh.Priority.DATA_HIGH,
        cache=zenoh.ext.CacheConfig(EVENT_HISTORY),
        sample_miss_detection=zenoh.ext.MissDetectionConfig(
            heartbeat=None, sporadic_heartbeat=EVENT_HEARTBEAT_S
        ),
        publisher_detection=True,
    )


def declare_event_subscriber(
    session: zenoh.Session,
    key: str,
    on_event: Callable[[zenoh.Sample], None],
    on_miss: Callable[[zenoh.ext.Miss], None],
) -> list[ZenohEntity]:
    """Events of ``key`` (a wildcard robot id too): the cached history of every publisher found, late
    ones included, then each new one; ``on_miss`` when events of a publisher never arrived (``nb`` of
    them, from ``source``: the samples' ``source_info.source_id``). The callbacks run on Zenoh's threads."""
    sub = zenoh.ext.declare_advanced_subscriber(
        session,
        key,
        zenoh.handlers.Callback(on_event, indirect=False),
        history=zenoh.ext.HistoryConfig(detect_late_publishers=True, max_samples=EVENT_HISTORY),
        recovery=zenoh.ext.RecoveryConfig(periodic_queries=None, heartbeat=True),
        subscriber_detection=True,
    )
    try:
        misses = sub.sample_miss_listener(on_miss)
    except zenoh.ZError:
        sub.undeclare()
        raise
    return [sub, misses]


def source_name(source: zenoh.EntityGlobalId) -> str:
    """A publisher's id as text: the same for its samples' ``source_info`` and its misses' ``source``."""
    return f"{source.zid}/{source.eid}"


@cache
def schema_descriptor_set() -> bytes:
    """cheope.proto's messages (the Zenoh payloads and the recording's own) as a serialised
    ``google.protobuf.FileDescriptorSet``: what the ``schema`` queryable answers."""
    from mcap_protobuf.schema import build_file_descriptor_set

    from controller.messages import cheope_pb2 as pb

    data: bytes = build_file_descriptor_set(pb.MonitorState).SerializeToString()
    return data


def split_endpoints(text: str, key: str) -> tuple[str, ...]:
    """``"tcp/a:1, tcp/b:2"`` -> validated endpoints; ``key`` names the setting in errors."""
    eps = tuple(e.strip() for e in text.split(",") if e.strip())
    for e in eps:
        check_endpoint(e, key)
    return eps


def check_endpoint(endpoint: str, key: str) -> None:
    m = _ENDPOINT.match(endpoint)
    if m is None:
        raise ConfigError(
            f"{key} = {endpoint!r}: expected a Zenoh endpoint PROTOCOL/ADDRESS, e.g. tcp/127.0.0.1:7448"
        )
    if m["proto"] in _IP_PROTOCOLS:
        host, sep, port = m["addr"].rpartition(":")
        if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
            raise ConfigError(
                f"{key} = {endpoint!r}: expected {m['proto']}/HOST:PORT with a port in 0..65535"
            )


def is_loopback(endpoint: str) -> bool:
    m = _ENDPOINT.match(endpoint)
    if m is None:
        return False
    if m["proto"] in ("unixsock-stream", "unixpipe"):
        return True
    host = m["addr"].rpartition(":")[0]
    return host in _LOOPBACK_HOSTS or host.startswith("127.")


def free_loopback_port() -> int:
    """A TCP port the kernel reports free on 127.0.0.1 (closed again: a tiny race, retried by callers)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass(frozen=True)
class SessionSettings:
    mode: str = "peer"  # "peer", "client" or "router" (cheope router)
    listen: tuple[str, ...] = ()
    connect: tuple[str, ...] = ()
    config_file: str = ""
    on_listen_busy: str = "fail"  # "free_port": replace busy loopback TCP listen ports by free ones
    connect_retry_ms: tuple[int, int] = (200, 1000)  # first and longest retry period of connect endpoints
    connect_timeout_ms: int = -1  # per-attempt timeout at open; -1: do not wait (peers keep retrying)


# The sessions a listening session (the controller's) takes at once; Zenoh's default is 1 000. The
# loop's thread puts each sample to every one of them, and a session that stops draining what it
# is sent grows its queue by a 64-kB batch in that put: 200 live subscriber sessions that stopped
# reading held the loop 26-27 ms in one cycle, 2 300 page faults (2 of 2 runs; with 100 no cycle
# above 10.5 ms, an outside tester's). More monitors than this connect through a router (docs/
# guides/monitoring.md); a --zenoh-config file that sets the key keeps its own number.
MAX_SESSIONS_KEY = "transport/unicast/max_sessions"
MAX_PEER_SESSIONS = 64


def build_zenoh_config(settings: SessionSettings) -> zenoh.Config:
    """The Zenoh configuration: the file (if any), then the loopback defaults for what it leaves unset."""
    if settings.config_file:
        # a bounded read first: Zenoh reads whatever is at the path, /dev/zero until memory runs out
        try:
            read_text_file(Path(settings.config_file), "Zenoh configuration file", ConfigError)
        except ConfigError as err:
            raise ConfigError(f"monitoring.config_file (--zenoh-config): {err}") from None
        try:
            conf = zenoh.Config.from_file(settings.config_file)
        except zenoh.ZError as err:
            raise ConfigError(f"monitoring.config_file = {settings.config_file!r}: {err}") from err
        default_listen = _get(zenoh.Config(), "listen/endpoints")
        set_mode = _get(conf, "mode") is None
        set_listen = _get(conf, "listen/endpoints") == default_listen
        file_connect = _get(conf, "connect/endpoints")  # a list, or None when unset
        connect = [*(file_connect if isinstance(file_connect, list) else []), *settings.connect]
    else:
        conf = zenoh.Config()
        set_mode = set_listen = True
        connect = list(settings.connect)
    if set_mode:
        conf.insert_json5("mode", json.dumps(settings.mode))
    if set_listen:
        conf.insert_json5("listen/endpoints", json.dumps(list(settings.listen)))
    conf.insert_json5("connect/endpoints", json.dumps(connect))
    for key in ("scouting/multicast/enabled", "scouting/gossip/enabled"):
        if _get(conf, key) is None:
            conf.insert_json5(key, "false")
    if _get(conf, "connect/retry") is None:
        lo, hi = settings.connect_retry_ms
        conf.insert_json5(
            "connect/retry",
            json.dumps({"period_init_ms": lo, "period_max_ms": hi, "period_increase_factor": 2}),
        )
    # a client with a timeout too: by Zenoh's default a client tries once and fails, so a one-shot
    # tool (``cheope status``) started while the controller's listener was busy failed at once, not
    # within its timeout (1 of 30 concurrent calls beside 12 monitors, an outside tester). Not -1: a
    # client would then wait at open for ever
    timed_client = settings.mode == "client" and settings.connect_timeout_ms >= 0
    if (settings.mode == "peer" or timed_client) and _get(conf, "connect/timeout_ms") is None:
        conf.insert_json5("connect/timeout_ms", json.dumps(settings.connect_timeout_ms))
    if settings.mode == "peer" and _get(conf, "connect/exit_on_failure") is None:
        conf.insert_json5("connect/exit_on_failure", "false")
    if settings.listen and _get(conf, MAX_SESSIONS_KEY) == _get(zenoh.Config(), MAX_SESSIONS_KEY):
        conf.insert_json5(MAX_SESSIONS_KEY, json.dumps(MAX_PEER_SESSIONS))
    return conf


def listen_endpoints(conf: zenoh.Config) -> tuple[str, ...]:
    """The endpoints a session opened with ``conf`` listens on: its ``listen/endpoints``, which a
    ``--zenoh-config`` file may set (``cheope status`` reported the loopback default beside a
    file's TLS endpoint), per mode where the file gives them per mode."""
    endpoints = _get(conf, "listen/endpoints")
    if isinstance(endpoints, dict):
        endpoints = endpoints.get(str(_get(conf, "mode") or "peer"), [])
    return tuple(str(e) for e in endpoints) if isinstance(endpoints, list) else ()


def _get(conf: zenoh.Config, key: str) -> object:
    return json.loads(conf.get_json(key))  # get_json returns JSON text ("null" when unset)


def _with_free_ports(listen: tuple[str, ...]) -> tuple[str, ...]:
    out = []
    for e in listen:
        if e.startswith("tcp/") and is_loopback(e):
            host = e[4:].rpartition(":")[0]
            e = f"tcp/{host}:{free_loopback_port()}"
        out.append(e)
    return tuple(out)


def open_session(settings: SessionSettings) -> tuple[zenoh.Session, tuple[str, ...]]:
    """Open a session; returns it and the endpoints it listens on.

    With ``on_listen_busy="free_port"`` a loopback TCP listen port already in use (another
    controller on this machine, a concurrent test run) is replaced by a free one, with a warning.
    """
    conf = build_zenoh_config(settings)
    try:
        return zenoh.open(conf), listen_endpoints(conf)
    except zenoh.ZError as err:
        busy = "Address already in use" in str(err)
        if not (busy and settings.on_listen_busy == "free_port"):
            raise MonitoringConnectionError(_describe(settings, err)) from err
    for _ in range(3):
        listen = _with_free_ports(settings.listen)
        conf = build_zenoh_config(replace(settings, listen=listen))
        try:
            session = zenoh.open(conf)
        except zenoh.ZError as err:
            if "Address already in use" in str(err):
                continue
            raise MonitoringConnectionError(_describe(settings, err)) from err
        log.warning(
            "monitoring: %s is in use; listening on %s instead", ", ".join(settings.listen), ", ".join(listen)
        )
        return session, listen_endpoints(conf)
    raise MonitoringConnectionError(f"cannot listen on {', '.join(settings.listen)}: address in use")


def _describe(settings: SessionSettings, err: Exception) -> str:
    first = str(err).split(" at /", 1)[0]  # zenoh appends Rust source locations
    where = (
        ", ".join(
            f"{k} {', '.join(v)}"
            for k, v in (("listen", settings.listen), ("connect", settings.connect))
            if v
        )
        or "no endpoints"
    )
    hint = (
        " (is the controller running, and listening there? see monitoring.listen)"
        if settings.mode == "client" and "connect" in first.lower()
        else ""
    )
    return f"cannot open a Zenoh session ({settings.mode}; {where}): {first.strip().rstrip('!')}{hint}"


def client_settings(
    connect: tuple[str, ...] = (), config_file: str = "", timeout_s: float = 2.0
) -> SessionSettings:
    """Settings of the one-shot tools (``cheope list``, ``status``, ``stop``, ``command``): a peer that
    listens nowhere and connects to every endpoint given (controllers, routers), not only the first as
    a Zenoh client would; the open waits up to ``timeout_s`` for all of them, then goes on with those
    that answered. Without endpoints: this user's controllers on this machine (local_controllers.py),
    else ``DEFAULT_CONNECT``."""
    endpoints = connect or local_endpoints() or (DEFAULT_CONNECT,)
    # one endpoint: a client (a Zenoh router answers a peer's liveliness queries only for its clients,
    # measured with eclipse-zenoh 1.10); several: a peer, which connects to each of them
    return SessionSettings(
        mode="client" if len(endpoints) == 1 else "peer",
        listen=(),
        connect=endpoints,
        config_file=config_file,
        connect_timeout_ms=int(timeout_s * 1000),
    )


def connected(session: zenoh.Session) -> int:
    """How many peers and routers the session is connected to."""
    info = session.info
    return len(info.peers_zid()) + len(info.routers_zid())


def open_tool_session(settings: SessionSettings, poll_s: float = 0.02) -> zenoh.Session:
    """A one-shot tool's session, connected to at least one of its endpoints (else the error names them).

    Zenoh's open returns after its scouting delay (0.5 s) whether the connections are up or not
    (on a loaded machine a connection took longer); so wait for them here, up to the connect timeout.
    """
    session, _ = open_session(settings)
    deadline = time.monotonic() + max(0.0, settings.connect_timeout_ms / 1000)
    while connected(session) < len(set(settings.connect)) and time.monotonic() < deadline:
        time.sleep(poll_s)  # nothing signals a new connection in zenoh's Python API
    if settings.connect and connected(session) == 0:
        session.close()
        raise MonitoringConnectionError(
            f"nothing answers at {', '.join(settings.connect)}: no controller or router "
            "listens there (see monitoring.listen, --zenoh-connect)"
        )
    return session


def monitor_settings(connect: tuple[str, ...] = (), config_file: str = "") -> SessionSettings:
    """Settings of ``cheope monitor``: a peer that listens nowhere and keeps retrying its connect endpoints
    (default: this user's controllers on this machine, else ``DEFAULT_CONNECT``: local_controllers.py)."""
    return SessionSettings(
        mode="peer",
        listen=(),
        connect=connect or local_endpoints() or (DEFAULT_CONNECT,),
        config_file=config_file,
        connect_retry_ms=(200, 1000),
    )


class ZenohEntity(Protocol):
    """A declared publisher, subscriber, queryable or liveliness token."""

    def undeclare(self) -> None: ...


def close_session(session: zenoh.Session | None, entities: Sequence[ZenohEntity]) -> None:
    """Undeclare ``entities`` (newest first), then close ``session``: the order Zenoh needs.

    A step Zenoh does not complete (``zenoh.ZError``: "close operation timed out!" with 300 live
    subscribers that no longer drained what it sent them, an outside tester's) is named in a
    warning and the rest go on: the session's end is the run's last step, and raising there lost
    the run's summary and the demo's comparison run after a run that had gone well. What Zenoh
    still holds goes with the process."""
    for e in reversed(entities):
        try:
            e.undeclare()
        except zenoh.ZError as err:
            log.warning("monitoring: Zenoh did not undeclare %s: %s", type(e).__name__, err)
    if session is not None:
        try:
            session.close()
        except zenoh.ZError as err:
            log.warning("monitoring: Zenoh did not close its session (%s); it ends with the process", err)
