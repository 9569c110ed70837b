"""The ROS 2 bridge ends when asked (controller/ros2/bridge.py).

- A stop signal sets the bridge's ``done`` event from controller/signal_relay.py's thread, never
  in the handler: a CI run's replay bridge got SIGTERM inside ``done.wait`` while that held the
  event's lock, and its handler's ``done.set()`` waited for that lock for ever.
- rclpy's teardown runs under ``ends_within``: a block that never returns, even one that holds
  the interpreter lock, ends the process with every thread's stack on stderr and exit status 1.

Each case runs in a child process (a hang or the deadline ends the process it runs in); the test
only waits for the child's end with a generous bound (tests/waiting.py).
"""

from __future__ import annotations

import subprocess
import sys

from waiting import GENEROUS_S

_PRELUDE = "from controller.ros2.bridge import _ended_by_stop_signals, ends_within\n"


def _run(body: str) -> subprocess.CompletedProcess[str]:
    proc = subprocess.Popen(
        [sys.executable, "-c", _PRELUDE + body],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        out, err = proc.communicate(timeout=GENEROUS_S)
    except subprocess.TimeoutExpired:
        proc.kill()
        _, err = proc.communicate()
        raise AssertionError(f"the child did not end: {err[-2000:]}") from None
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, err)


def test_a_block_that_never_returns_ends_the_process_with_its_stacks():
    r = _run(
        "import threading\n"
        "def teardown_that_hangs():\n"
        "    threading.Event().wait()\n"
        "with ends_within(0.5):\n"
        "    teardown_that_hangs()\n"
        "print('returned')\n"
    )
    assert r.returncode == 1, r.stderr
    assert "returned" not in r.stdout
    assert "Timeout (0:00:00.500000)!" in r.stderr
    assert "teardown_that_hangs" in r.stderr  # where it hung, named


def test_a_block_that_holds_the_interpreter_lock_is_ended_too():
    # a thread of Python could not end it: it would wait for the lock the block never gives up
    r = _run(
        "import sys\n"
        "sys.setswitchinterval(1e6)\n"
        "def spins_holding_the_lock():\n"
        "    while True:\n"
        "        pass\n"
        "with ends_within(0.5):\n"
        "    spins_holding_the_lock()\n"
    )
    assert r.returncode == 1, r.stderr
    assert "spins_holding_the_lock" in r.stderr


def test_a_block_that_returns_in_time_leaves_the_process_alone():
    # the watchdog is cancelled, not merely not yet due: the child lives on past the deadline
    r = _run("import time\nwith ends_within(3.0):\n    pass\ntime.sleep(4.0)\nprint('returned')\n")
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "returned"
    assert "Timeout" not in r.stderr


def test_sigterm_inside_a_wait_on_the_stop_event_ends_the_bridge():
    # where SIGTERM found the replay bridge: in the main thread, inside done.wait, holding the
    # event's own lock (threading.Event._cond); the handler runs at the loop's next bytecodes
    r = _run(
        "import os, signal\n"
        "with _ended_by_stop_signals() as done:\n"
        "    with done._cond:\n"
        "        os.kill(os.getpid(), signal.SIGTERM)\n"
        "        for _ in range(100_000):\n"
        "            pass\n"
        "    done.wait()\n"
        "print('ended')\n"
    )
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "ended"


def test_every_stop_signal_ends_the_bridge_and_its_handlers_are_given_back():
    r = _run(
        "import os, signal\n"
        "signal.signal(signal.SIGHUP, signal.SIG_DFL)\n"  # a suite started under nohup ignores it
        "before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}\n"
        "for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):\n"
        "    with _ended_by_stop_signals() as done:\n"
        "        os.kill(os.getpid(), sig)\n"
        "        done.wait()\n"
        "    print(sig.name, 'ended')\n"
        "print(before == {s: signal.getsignal(s) for s in before})\n"
    )
    assert r.returncode == 0, r.stderr
    assert r.stdout.split("\n")[:4] == ["SIGINT ended", "SIGTERM ended", "SIGHUP ended", "True"]
