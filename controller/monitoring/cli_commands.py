"""The monitoring part of the ``cheope`` command line (called from controller/cli.py).

Controller side (``demo``, ``run``): ``--zenoh-connect``, ``--zenoh-config``,
``--allow-remote-commands`` become ``--set monitoring.*`` overrides. Client side: ``monitor``,
``status``, ``stop`` and ``command``.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import TypeVar

from controller.monitoring.zenoh_session import (
    DEFAULT_CONNECT,
    MonitorKeys,
    SessionSettings,
    check_endpoint,
    client_settings,
    monitor_settings,
)

# The caller's parser class (cheope's own ArgumentParser subclass): _SubParsersAction is invariant in it.
ParserT = TypeVar("ParserT", bound=argparse.ArgumentParser)


def add_controller_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("remote monitoring (Zenoh)")
    g.add_argument("--zenoh-connect", action="append", default=[], metavar="ENDPOINT",
                   help="also connect to this Zenoh router or peer, e.g. tcp/192.168.1.10:7447 (repeatable)")
    g.add_argument("--zenoh-config", metavar="FILE", help="Zenoh JSON5 configuration file (TLS, access control)")
    g.add_argument("--allow-remote-commands", action="store_true",
                   help="accept remote pause, resume and set_force (a remote stop is always accepted)")


def monitoring_overrides(args: argparse.Namespace) -> list[str]:
    """``--set`` overrides equivalent to the options of add_controller_options (none if absent)."""
    sets = []
    connect = getattr(args, "zenoh_connect", None)
    if connect:
        for e in connect:
            check_endpoint(e, "--zenoh-connect")
        sets.append(f"monitoring.connect={json.dumps(','.join(connect))}")
    if getattr(args, "zenoh_config", None):
        sets.append(f"monitoring.config_file={json.dumps(args.zenoh_config)}")
    if getattr(args, "allow_remote_commands", False):
        sets.append("monitoring.allow_remote_commands=true")
    return sets


def _client_options(p: argparse.ArgumentParser, timeout: bool = True) -> None:
    p.add_argument("--robot-id", default="cheope-1", help="the controller's monitoring.robot_id (default cheope-1)")
    p.add_argument("--key-prefix", default="cheope", help="the controller's monitoring.key_prefix (default cheope)")
    p.add_argument("--zenoh-connect", action="append", default=[], metavar="ENDPOINT",
                   help=f"where the controller (or a router) listens (default {DEFAULT_CONNECT}; repeatable)")
    p.add_argument("--zenoh-config", metavar="FILE", help="Zenoh JSON5 configuration file (TLS, access control)")
    if timeout:
        p.add_argument("--timeout", type=float, default=2.0, help="seconds to wait for the answer")


def _endpoints(args: argparse.Namespace) -> tuple[str, ...]:
    for e in args.zenoh_connect:
        check_endpoint(e, "--zenoh-connect")
    return tuple(args.zenoh_connect)


def _one_shot(args: argparse.Namespace) -> tuple[SessionSettings, MonitorKeys]:
    return (client_settings(_endpoints(args), args.zenoh_config or "", args.timeout),
            MonitorKeys.for_robot(args.key_prefix, args.robot_id))


def cmd_monitor(args: argparse.Namespace) -> int:
    from controller.monitoring.monitor_view import run_monitor

    settings = monitor_settings(_endpoints(args), args.zenoh_config or "")
    keys = MonitorKeys.for_robot(args.key_prefix, args.robot_id, allow_wildcard=True)
    try:
        run_monitor(settings, keys, args.json, sys.stdout, args.duration, args.count)
    except KeyboardInterrupt:
        pass
    return 0


def cmd_status(args: argparse.Namespace) -> int:
    from google.protobuf.json_format import MessageToDict

    from controller.monitoring.commands import query_status

    status = query_status(*_one_shot(args), timeout_s=args.timeout)
    d = MessageToDict(status, preserving_proto_field_name=True, always_print_fields_with_no_presence=True,
                      unquote_int64_if_possible=True)
    d["config"] = json.loads(d.pop("config_json") or "{}")
    if args.json:
        print(json.dumps(d))
        return 0
    print(f"robot               {status.robot_id} (cheope-controller {status.software_version})")
    print(f"mode                {status.mode}, up {status.uptime_s:.1f} s")
    print(f"listening on        {', '.join(status.listen_endpoints) or '-'}")
    print(f"remote commands     {'enabled' if status.commands_enabled else 'stop only'}")
    print("counters            " + ", ".join(f"{k} {v}" for k, v in sorted(status.counters.items())))
    print("versions            " + ", ".join(status.versions))
    print(f"configuration       {len(status.config_json)} bytes of JSON (--json prints it)")
    return 0


def _command(args: argparse.Namespace, name: str, value: float) -> int:
    from controller.monitoring.commands import send_command

    reply = send_command(*_one_shot(args), name=name, value=value, timeout_s=args.timeout)
    print(("accepted: " if reply.accepted else "refused: ") + reply.message,
          file=sys.stdout if reply.accepted else sys.stderr)
    return 0 if reply.accepted else 1


def cmd_stop(args: argparse.Namespace) -> int:
    return _command(args, "stop", 0.0)


def cmd_command(args: argparse.Namespace) -> int:
    return _command(args, args.name, args.value)


def add_subcommands(sub: argparse._SubParsersAction[ParserT]) -> None:
    p = sub.add_parser("monitor", help="live view of a running controller over Zenoh")
    _client_options(p, timeout=False)
    p.add_argument("--json", action="store_true", help="one JSON object per line (state, event, liveliness)")
    p.add_argument("--duration", type=float, help="exit after this many seconds")
    p.add_argument("--count", type=int, help="exit after this many state samples")
    p.set_defaults(func=cmd_monitor)
    p = sub.add_parser("status", help="ask a running controller for its status once")
    _client_options(p)
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_status)
    p = sub.add_parser("stop", help="bring a running controller's robot to a controlled stop")
    _client_options(p)
    p.set_defaults(func=cmd_stop)
    p = sub.add_parser("command", help="send pause, resume or set_force (refused unless the controller "
                                       "was started with --allow-remote-commands)")
    _client_options(p)
    p.add_argument("name", choices=("pause", "resume", "set_force", "stop"))
    p.add_argument("value", type=float, nargs="?", default=0.0, help="set_force: the force setpoint [N]")
    p.set_defaults(func=cmd_command)
