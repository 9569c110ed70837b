"""The ROS 2 bridge ends when asked, whatever rclpy's teardown does (controller/ros2/bridge.py,
``ends_within`` around ``RosPublisher.close``): a block that never returns, even one that holds
the interpreter lock, ends the process with every thread's stack on stderr and exit status 1.

The blocks run in a child process: the deadline ends the process it runs in. The child's deadline
is short; the test only waits for the child's end with a generous bound (tests/waiting.py).
"""

from __future__ import annotations

import subprocess
import sys

from waiting import GENEROUS_S

_PRELUDE = "from controller.ros2.bridge import ends_within\n"


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
        proc.communicate()
        raise AssertionError("the child did not end: ends_within let a hung block run on") from None
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
