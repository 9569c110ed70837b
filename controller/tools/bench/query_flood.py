"""Benchmark: late cycles of a running controller with and without a flood of garbage Zenoh queries.

    .venv/bin/python -m controller.tools.bench.query_flood [--windows 3] [--window-s 5] [--rate 1000] [--realtime]

Starts a controller (controller.tools.sim_controller: the production loop, law and publisher on
the in-process simulated devices; normal scheduler, what ``--no-realtime`` gives ``cheope run``,
or with ``--realtime`` the loop thread as ``cheope run`` asks by default), then alternates windows without and with a flood: ``--rate`` queries a
second from this process, half to ``status``, half to ``command`` with a random payload, none
waited for. The late cycles of each window are the difference of the loop's own counter
(``MonitorState.loop.late_cycles``: wake-up more than 10 % of a period after the deadline)
between the window's first and last state sample. Prints one line per window, then the
median and range of each kind, and the controller's query counters. A benchmark that prints
figures, not a test: on a shared two-core machine the numbers move with everything else.
"""

from __future__ import annotations

import argparse
import json
import os
import secrets
import signal
import statistics
import subprocess
import sys
import threading
import time

from controller.monitoring.commands import query_status
from controller.monitoring.monitor_view import MonitorClient, StateUpdate
from controller.monitoring.zenoh_session import (
    MonitorKeys,
    SessionSettings,
    client_settings,
    free_loopback_port,
    monitor_settings,
    open_session,
)

ROBOT = "flood-bench"


def _flood(endpoint: str, keys: MonitorKeys, rate_hz: float, stop: threading.Event, sent: list[int]) -> None:
    session, _ = open_session(SessionSettings(mode="client", connect=(endpoint,), connect_timeout_ms=5000))
    period = 1.0 / rate_hz
    nxt = time.monotonic()
    try:
        while not stop.is_set():
            key = keys.status if sent[0] % 2 else keys.command
            session.get(key, lambda _reply: None, payload=secrets.token_bytes(16), timeout=1.0)
            sent[0] += 1
            nxt += period
            delay = nxt - time.monotonic()
            if delay > 0:
                time.sleep(delay)
    finally:
        session.close()


def _late_in_window(client: MonitorClient, window_s: float) -> tuple[int, int]:
    """(late cycles, cycles) between the first and the last state sample of a window."""
    first = last = None
    end = time.monotonic() + window_s
    while time.monotonic() < end:
        u = client.next_update(0.2)
        if isinstance(u, StateUpdate):
            first = first or u.msg
            last = u.msg
    if first is None or last is None:
        raise RuntimeError("no state sample from the controller in a window")
    return last.loop.late_cycles - first.loop.late_cycles, last.cycle - first.cycle


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m controller.tools.bench.query_flood")
    ap.add_argument("--windows", type=int, default=3, help="windows of each kind (alternating)")
    ap.add_argument("--window-s", type=float, default=5.0)
    ap.add_argument("--rate", type=float, default=1000.0, help="flood: queries per second")
    ap.add_argument(
        "--controller-root",
        metavar="DIR",
        help="run the controller from this checkout (e.g. a worktree of an older commit, to compare)",
    )
    ap.add_argument(
        "--realtime",
        action="store_true",
        help="the controller's loop thread under SCHED_FIFO 80 on the last CPU (cheope run's default)",
    )
    args = ap.parse_args(argv)
    ep = f"tcp/127.0.0.1:{free_loopback_port()}"
    keys = MonitorKeys.for_robot("cheope", ROBOT)
    duration = 2 * args.windows * args.window_s + 30
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "controller.tools.sim_controller",
            "--max-duration",
            str(duration),
            "--set",
            f'monitoring.listen="{ep}"',
            "--set",
            f'monitoring.robot_id="{ROBOT}"',
            "--set",
            "task.path.laps=1000",
            "--set",
            "loop.max_missing_s=0.025",
            "--set",
            "loop.max_bus_silence_s=0.025",
            "--set",
            'safety.on_late_cycles="warn"',
            "--set",
            "actuators.sync_watchdog_s=0.5",
            *(["--realtime"] if args.realtime else []),
        ],
        stdout=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
        cwd=args.controller_root,
    )
    rows: dict[str, list[float]] = {"no flood": [], "flood": []}
    try:
        assert proc.stdout is not None and proc.stdout.readline().startswith("READY")
        with MonitorClient(monitor_settings((ep,)), keys) as client:
            _late_in_window(client, 2.0)  # warm-up
            for w in range(2 * args.windows):
                kind = "flood" if w % 2 else "no flood"
                stop, sent = threading.Event(), [0]
                flooder = (
                    threading.Thread(target=_flood, args=(ep, keys, args.rate, stop, sent))
                    if kind == "flood"
                    else None
                )
                if flooder is not None:
                    flooder.start()
                late, cycles = _late_in_window(client, args.window_s)
                stop.set()
                if flooder is not None:
                    flooder.join()
                rows[kind].append(late)
                print(
                    f"window {w + 1}: {kind:<8} late cycles {late:5d} of {cycles:5d}"
                    + (f", {sent[0]} queries sent ({sent[0] / args.window_s:.0f}/s)" if flooder else ""),
                    flush=True,
                )
        st = query_status(client_settings((ep,)), keys, timeout_s=5.0)
    finally:
        proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=60)
    for kind, vals in rows.items():
        print(
            f"{kind:<8}: late cycles per {args.window_s:g} s window median {statistics.median(vals):g}, "
            f"range {min(vals):g}-{max(vals):g} ({len(vals)} windows)"
        )
    print(
        f"controller loop thread: {json.loads(out.splitlines()[-1]).get('realtime', '?') if out.strip() else '?'}"
    )
    print(
        "controller counters: "
        + ", ".join(
            f"{k} {st.counters[k]}" for k in ("status_queries", "commands_accepted", "commands_refused")
        )
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
