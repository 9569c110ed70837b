"""The monitoring part of the ``cheope`` command line (called from controller/cli.py).

Controller side (``demo``, ``run``): ``--zenoh-connect``, ``--zenoh-config``,
``--allow-remote-commands``, ``--robot-id`` become ``--set monitoring.*`` overrides. Client side:
``list``, ``monitor``, ``status``, ``stop`` and ``command``; and ``router``, a Zenoh router
for many controllers on one machine or network.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
from dataclasses import asdict
from typing import TYPE_CHECKING, TypeVar

from controller.cli_arguments import positive_count, positive_seconds
from controller.cli_output import printable
from controller.config import ConfigError
from controller.monitoring.command_gate import ALWAYS_ACCEPTED, GATED_COMMANDS
from controller.monitoring.zenoh_session import (
    DEFAULT_CONNECT,
    DEFAULT_ROUTER_LISTEN,
    MonitoringConnectionError,
    MonitorKeys,
    check_endpoint,
    client_settings,
    monitor_settings,
)

if TYPE_CHECKING:
    from controller.monitoring.commands import RobotSelector

# The caller's parser class (cheope's own ArgumentParser subclass): _SubParsersAction is invariant in it.
ParserT = TypeVar("ParserT", bound=argparse.ArgumentParser)

# "No controller" is one answer whoever asks: list here, status and stop through MonitoringConnectionError
# (a DeviceError: cheope's exit code 2 in controller/cli.py).
EXIT_NO_CONTROLLER = 2


def add_controller_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("remote monitoring (Zenoh)")
    g.add_argument(
        "--zenoh-connect",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="also connect to this Zenoh router or peer, e.g. tcp/192.168.1.10:7447 (repeatable)",
    )
    g.add_argument(
        "--zenoh-config", metavar="FILE", help="Zenoh JSON5 configuration file (TLS, access control)"
    )
    g.add_argument(
        "--allow-remote-commands",
        action="store_true",
        help="accept remote pause, resume, reset and set_force (a remote stop is always accepted)",
    )
    g.add_argument(
        "--robot-id",
        help="this controller's id under cheope/ (default: <host>-<4 hex digits>); "
        "refused at start when a live controller reachable holds it",
    )


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
    if getattr(args, "robot_id", None):
        sets.append(f"monitoring.robot_id={json.dumps(args.robot_id)}")
    return sets


def _client_options(
    p: argparse.ArgumentParser,
    timeout: bool = True,
    robot_id: str | None = None,
    robot_help: str = "the controller's robot id (default: the only controller reachable; "
    "`cheope list` shows them)",
) -> None:
    if robot_id != "":
        p.add_argument("--robot-id", default=robot_id, help=robot_help)
    p.add_argument(
        "--key-prefix",
        default="cheope",
        type=_key_prefix,
        help="the controller's monitoring.key_prefix (default cheope)",
    )
    p.add_argument(
        "--zenoh-connect",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help=f"where the controller (or a router) listens (default {DEFAULT_CONNECT}; repeatable)",
    )
    p.add_argument(
        "--zenoh-config", metavar="FILE", help="Zenoh JSON5 configuration file (TLS, access control)"
    )
    if timeout:
        p.add_argument(
            "--timeout", type=positive_seconds, default=2.0, help="seconds to wait for the answer (default 2)"
        )


def _key_prefix(text: str) -> str:
    """``--key-prefix``: chunks as ``monitoring.key_prefix`` takes them (an empty one or a wildcard
    reached Zenoh as an invalid key expression)."""
    try:
        MonitorKeys.for_robot(text, "robot")
    except ConfigError:
        raise argparse.ArgumentTypeError(
            f"{text!r}: chunks of letters, digits, '-', '_', '.' separated by '/' (no wildcard)"
        ) from None
    return text


def _endpoints(args: argparse.Namespace) -> tuple[str, ...]:
    for e in args.zenoh_connect:
        check_endpoint(e, "--zenoh-connect")
    return tuple(args.zenoh_connect)


def _target(args: argparse.Namespace) -> RobotSelector:
    """The one robot of ``--robot-id`` (checked before connecting: one id, no wildcard), or the only
    one reachable."""
    from controller.monitoring.commands import RobotSelector

    if args.robot_id is not None:
        try:
            MonitorKeys.for_robot(args.key_prefix, args.robot_id)
        except ConfigError as err:
            every = "; cheope stop --all stops every controller reachable" if args.command == "stop" else ""
            raise ConfigError(
                f"--robot-id {args.robot_id!r}: names one robot by its id (letters, digits, '-', '_', "
                f"'.'; no wildcard: a command reaches one robot){every}"
            ) from err
    return RobotSelector(args.key_prefix, args.robot_id)


def cmd_list(args: argparse.Namespace) -> int:
    from controller.monitoring.commands import list_controllers

    settings = client_settings(_endpoints(args), args.zenoh_config or "", args.timeout)
    try:
        found = list_controllers(settings, args.key_prefix, args.timeout)
    except MonitoringConnectionError as err:  # nothing listens at any endpoint given
        print(f"cheope list: no controller found: {err}", file=sys.stderr)
        return EXIT_NO_CONTROLLER
    if not found:
        print(
            f"cheope list: no controller found under {args.key_prefix}/*/ (connected to "
            f"{', '.join(settings.connect)})",
            file=sys.stderr,
        )
        return EXIT_NO_CONTROLLER
    if args.json:
        print(json.dumps([{**asdict(c), "listen_endpoints": list(c.listen_endpoints)} for c in found]))
        return 0
    print(f"{'robot id':<24} {'mode':<12} {'task':<10} {'up [s]':>9}  listening on")
    for c in found:
        up = f"{c.uptime_s:9.1f}" if c.uptime_s is not None else f"{'-':>9}"
        endpoints = printable(", ".join(c.listen_endpoints)) or "-"  # the peer's text, made safe to print
        print(
            f"{c.robot_id:<24} {printable(c.mode) or '?':<12} {printable(c.task) or '-':<10} {up}  {endpoints}"
        )
    return 0


def cmd_monitor(args: argparse.Namespace) -> int:
    from controller.monitoring.monitor_view import run_monitor

    settings = monitor_settings(_endpoints(args), args.zenoh_config or "")
    keys = MonitorKeys.for_robot(args.key_prefix, args.robot_id, allow_wildcard=True)
    with contextlib.suppress(KeyboardInterrupt):
        run_monitor(
            settings,
            keys,
            args.json,
            sys.stdout,
            args.duration,
            args.count,
            notice=lambda line: print(f"cheope monitor: {line}", file=sys.stderr, flush=True),
        )
    return 0


def cmd_status(args: argparse.Namespace) -> int:
    from google.protobuf.json_format import MessageToDict

    from controller.monitoring.commands import query_status, status_config

    status = query_status(
        client_settings(_endpoints(args), args.zenoh_config or "", args.timeout),
        _target(args),
        timeout_s=args.timeout,
    )
    d = MessageToDict(
        status,
        preserving_proto_field_name=True,
        always_print_fields_with_no_presence=True,
        unquote_int64_if_possible=True,
    )
    d.pop("config_json")
    d["config"] = status_config(status, f"the status of {status.robot_id or 'the controller'}")
    if args.json:
        print(json.dumps(d))
        return 0
    # every text of the answer is the peer's: made safe to print (cli_output.printable)
    print(f"robot               {status.robot_id} (cheope-controller {printable(status.software_version)})")
    print(f"mode                {printable(status.mode)}, up {status.uptime_s:.1f} s")
    print(f"listening on        {printable(', '.join(status.listen_endpoints)) or '-'}")
    print(f"remote commands     {'enabled' if status.commands_enabled else 'stop only'}")
    counters = ", ".join(f"{k} {v}" for k, v in sorted(status.counters.items()))
    print("counters            " + printable(counters, limit=2000))
    print("versions            " + printable(", ".join(status.versions), limit=2000))
    print(f"configuration       {len(status.config_json)} bytes of JSON (--json prints it)")
    return 0


def _command(args: argparse.Namespace, name: str, value: float) -> int:
    from controller.monitoring.commands import send_command

    robot_id, reply = send_command(
        client_settings(_endpoints(args), args.zenoh_config or "", args.timeout),
        _target(args),
        name=name,
        value=value,
        timeout_s=args.timeout,
    )
    _print_answer(args, [(robot_id, reply.accepted, reply.message)], name)
    return 0 if reply.accepted else 1


def _print_answer(args: argparse.Namespace, answers: list[tuple[str, bool, str]], name: str) -> None:
    """Each robot's answer: a line each (refusals on stderr), or with --json one JSON array on stdout."""
    if getattr(args, "json", False):
        print(
            json.dumps([{"robot_id": r, "command": name, "accepted": a, "message": m} for r, a, m in answers])
        )
        return
    for robot_id, accepted, message in answers:
        print(
            ("accepted by " if accepted else "refused by ") + f"{robot_id}: {printable(message)}",
            file=sys.stdout if accepted else sys.stderr,
        )


def cmd_stop(args: argparse.Namespace) -> int:
    if not args.all:
        return _command(args, "stop", 0.0)
    from controller.monitoring.commands import stop_every_robot

    if args.robot_id is not None:
        raise ConfigError("--all stops every controller reachable; --robot-id names one: give one of them")
    settings = client_settings(_endpoints(args), args.zenoh_config or "", args.timeout)
    answers = stop_every_robot(settings, args.key_prefix, args.timeout)
    if not answers:
        print(
            f"cheope stop: no controller found under {args.key_prefix}/*/ (connected to "
            f"{', '.join(settings.connect)})",
            file=sys.stderr,
        )
        return EXIT_NO_CONTROLLER
    _print_answer(args, answers, "stop")
    return 0 if all(accepted for _, accepted, _ in answers) else 1


def cmd_command(args: argparse.Namespace) -> int:
    return _command(args, args.name, args.value)


def cmd_router(args: argparse.Namespace) -> int:
    from controller.monitoring.router import run_router

    listen = tuple(args.listen) or (DEFAULT_ROUTER_LISTEN,)
    for e in listen:
        check_endpoint(e, "--listen")
    if args.json:  # READY <endpoints> as one JSON object
        return run_router(
            listen,
            args.zenoh_config or "",
            lambda line: print(json.dumps({"ready": line.split()[1:]}), flush=True),
        )
    return run_router(listen, args.zenoh_config or "", lambda line: print(line, flush=True))


def add_subcommands(sub: argparse._SubParsersAction[ParserT]) -> None:
    p = sub.add_parser(
        "list", help="every live controller reachable: robot id, mode, task, uptime, endpoints"
    )
    _client_options(p, robot_id="")
    p.add_argument("--json", action="store_true", help="one JSON array")
    p.set_defaults(func=cmd_list)
    p = sub.add_parser("monitor", help="live view of the running controllers over Zenoh")
    _client_options(
        p,
        timeout=False,
        robot_id="*",
        robot_help="the robot to watch (default *: every controller reachable)",
    )
    p.add_argument("--json", action="store_true", help="one JSON object per line (state, event, liveliness)")
    p.add_argument("--duration", type=positive_seconds, help="exit after this many seconds")
    p.add_argument("--count", type=positive_count, help="exit after this many state samples")
    p.set_defaults(func=cmd_monitor)
    p = sub.add_parser("status", help="ask a running controller for its status once")
    _client_options(p)
    p.add_argument("--json", action="store_true", help="print the status as one JSON object")
    p.set_defaults(func=cmd_status)
    p = sub.add_parser("stop", help="bring a running controller's robot to a controlled stop")
    _client_options(p)
    p.add_argument(
        "--all",
        action="store_true",
        help="stop every controller reachable, each by its own id (one command per robot)",
    )
    p.add_argument("--json", action="store_true", help="print the answers as one JSON array")
    p.set_defaults(func=cmd_stop)
    p = sub.add_parser(
        "command",
        help="send pause, resume, reset or set_force (refused unless the controller "
        "was started with --allow-remote-commands), or stop",
    )
    _client_options(p)
    # the publisher's gate is the one list of commands: the CLI cannot drift from it again
    p.add_argument(
        "name",
        choices=(*GATED_COMMANDS, *ALWAYS_ACCEPTED),
        help="the command: stop (always accepted) or one the controller must allow",
    )
    p.add_argument("value", type=float, nargs="?", default=0.0, help="set_force: the force setpoint [N]")
    p.add_argument("--json", action="store_true", help="print the answer as one JSON array")
    p.set_defaults(func=cmd_command)
    p = sub.add_parser(
        "router",
        help="a Zenoh router (router-mode session) that many controllers and the tools "
        "connect to, as zenohd would",
    )
    p.add_argument(
        "--listen",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help=f"where it listens (default {DEFAULT_ROUTER_LISTEN}; repeatable)",
    )
    p.add_argument(
        "--zenoh-config", metavar="FILE", help="Zenoh JSON5 configuration file (TLS, access control)"
    )
    p.add_argument("--json", action="store_true", help="print where it listens as one JSON object")
    p.set_defaults(func=cmd_router)
