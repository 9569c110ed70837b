"""``cheope ros2``: the command line of the ROS 2 bridge (bridge.py). Imports no ROS at parse time."""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
from pathlib import Path
from typing import TypeVar

from controller.cli_arguments import seconds_or_zero
from controller.errors import InputError
from controller.monitoring.cli_commands import _client_options, _endpoints

ParserT = TypeVar("ParserT", bound=argparse.ArgumentParser)


def _notice(line: str) -> None:
    print(f"cheope ros2: {line}", file=sys.stderr, flush=True)


# ROS 2 namespace rules (rcl's validation): absolute or relative, tokens of letters, digits and '_'
# that do not start with a digit, separated by single '/'
_NAMESPACE = re.compile(r"^/?([A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*)?$")


def cmd_ros2(args: argparse.Namespace) -> int:
    from controller.ros2.bridge import check_ros2, run_live, run_replay

    if not args.namespace or not _NAMESPACE.match(args.namespace):
        raise InputError(
            f"--namespace {args.namespace!r}: use names of letters, digits and '_' (not starting with "
            "a digit) separated by '/', e.g. /cheope/robot_1"
        )
    check_ros2()
    if args.replay is not None:
        if not (math.isfinite(args.speed) and args.speed >= 0.0):
            raise InputError(f"--speed {args.speed!r}: must be a finite number >= 0 (0: as fast as possible)")
        path = Path(args.replay)
        if not path.is_file():
            raise InputError(f"--replay {args.replay!r}: no such file")
        n = run_replay(path, args.namespace, args.speed, args.wait_subscriber, _notice)
        _report(args, n)
        return 0
    from controller.monitoring.zenoh_session import client_settings, monitor_settings

    endpoints = _endpoints(args)
    n = run_live(
        client_settings(endpoints, args.zenoh_config or "", args.timeout),
        monitor_settings(endpoints, args.zenoh_config or ""),
        args.key_prefix,
        args.robot_id,
        args.namespace,
        args.timeout,
        _notice,
    )
    _report(args, n)
    return 0


def _report(args: argparse.Namespace, samples: int) -> None:
    """What the bridge did, at its end: a line on stderr, or one JSON object on stdout."""
    if args.json:
        print(json.dumps({"samples_published": samples}))
    else:
        _notice(f"{samples} samples published")


def add_subcommand(sub: argparse._SubParsersAction[ParserT]) -> None:
    from controller.ros2.bridge import DEFAULT_NAMESPACE

    p = sub.add_parser(
        "ros2",
        help="publish a controller's state (or a recording) as ROS 2 topics in ROS time, with its URDF, "
        "/diagnostics, /rosout, /tf, and stop/pause/resume/reset services; needs the ros2 extra",
    )
    _client_options(p)
    p.add_argument(
        "--namespace",
        default=DEFAULT_NAMESPACE,
        help=f"ROS 2 namespace of the topics and the services (default {DEFAULT_NAMESPACE})",
    )
    p.add_argument(
        "--replay",
        metavar="FILE",
        help="publish this recording (.mcap) instead of a live controller, with /clock",
    )
    p.add_argument(
        "--speed",
        type=float,
        default=1.0,
        help="--replay: the recording's pace times this (default 1; 0: as fast as possible)",
    )
    p.add_argument(
        "--wait-subscriber",
        type=seconds_or_zero,
        default=0.0,
        metavar="SECONDS",
        help="--replay: wait up to this long for a ROS 2 subscriber before starting (default 0)",
    )
    p.add_argument(
        "--json", action="store_true", help="at the end, print what was published as one JSON object"
    )
    p.set_defaults(func=cmd_ros2)
