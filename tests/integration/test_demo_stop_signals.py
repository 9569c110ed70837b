"""``cheope demo --simulated-time`` stopped by SIGTERM, SIGHUP or SIGINT: the run stops as over a
bus (the law brakes, the drives are disabled, DONE), its summary is printed and the exit code is a
stopped run's, 0. SIGTERM and SIGHUP ended the process with no word and no summary (exit -15 and
-1), SIGINT with "interrupted" and no summary (an outside tester's finding).

The demo's stderr is a terminal here, so that its progress line is drawn: its first words come
after the signals are routed (controller/cli.py), and the test signals once it has read them.
"""

from __future__ import annotations

import contextlib
import json
import os
import select
import signal
import subprocess
import sys
import time

import pytest

pytestmark = pytest.mark.integration

STARTED = b"in simulated time"  # the progress line's text once the run is under way
WAIT_S = 120.0  # for the line, and for the end: a bound for a hung process, not a timing


def _read_until(fd: int, marker: bytes, proc: subprocess.Popen[bytes]) -> bytes:
    seen = b""
    deadline = time.monotonic() + WAIT_S
    while marker not in seen:
        assert proc.poll() is None, f"the demo ended before its run started: {seen!r}"
        left = deadline - time.monotonic()
        assert left > 0, f"no {marker!r} on the demo's terminal: {seen!r}"
        ready, _, _ = select.select([fd], [], [], left)
        if ready:
            seen += os.read(fd, 4096)
    return seen


def _default_hang_up() -> None:
    signal.signal(signal.SIGHUP, signal.SIG_DFL)  # under nohup the demo would ignore it from start


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP, signal.SIGINT], ids=lambda s: s.name)
def test_a_stop_signal_ends_a_simulated_time_demo_with_its_summary(sig: signal.Signals) -> None:
    leader, follower = os.openpty()
    proc = subprocess.Popen(
        [sys.executable, "-m", "controller", "demo", "--simulated-time", "--duration", "600", "--json"],
        stdout=subprocess.PIPE,
        stderr=follower,
        stdin=subprocess.DEVNULL,
        preexec_fn=_default_hang_up,
    )
    os.close(follower)
    try:
        _read_until(leader, STARTED, proc)
        proc.send_signal(sig)
        out, _ = proc.communicate(timeout=WAIT_S)
    finally:
        if proc.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(proc.pid, signal.SIGKILL)
            proc.wait()
        with contextlib.suppress(OSError):
            while os.read(leader, 4096):  # what the demo said after the signal
                pass
        os.close(leader)
    assert proc.returncode == 0, out
    summary = json.loads(out)
    assert summary["final_mode"] == "DONE" and summary["fault_reason"] == ""
    assert summary["task_finished"] is False and summary["cycles"] > 0  # stopped, not at its end
