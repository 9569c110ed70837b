"""Shared fixtures. Every test is checked for leaked child processes and non-daemon threads."""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path

import pytest

from controller.config import Config, load_config


def _children() -> set[int]:
    me = str(os.getpid())
    kids = set()
    for pid in os.listdir("/proc"):
        if not pid.isdigit():
            continue
        try:
            with open(f"/proc/{pid}/stat") as fh:
                fields = fh.read().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if fields[1] == me and fields[0] != "Z":
            kids.add(int(pid))
    return kids


@pytest.fixture(autouse=True, scope="session")
def recordings_in_a_temporary_directory(tmp_path_factory):
    """Sessions recorded by the tests (and their subprocesses) go to a temporary XDG data home, and
    the controllers they start announce themselves in a temporary runtime directory
    (controller/monitoring/local_controllers.py), unseen by the tools of anything else on the machine."""
    names = ("XDG_DATA_HOME", "XDG_RUNTIME_DIR")
    old = {name: os.environ.get(name) for name in names}
    os.environ["XDG_DATA_HOME"] = str(tmp_path_factory.mktemp("xdg-data"))
    runtime = tmp_path_factory.mktemp("xdg-runtime")
    runtime.chmod(0o700)
    os.environ["XDG_RUNTIME_DIR"] = str(runtime)
    yield
    for name, value in old.items():
        if value is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = value


@pytest.fixture(autouse=True, scope="session")
def signal_relay_started():
    """controller/signal_relay.py's thread is one a process, started by the first stop signal routed
    and kept (a daemon): started before the tests, so that the first one to run a command that
    routes them in this process (``main(["demo", "--simulated-time", ...])``) is not taken for its leak."""
    from controller.signal_relay import route_signals

    route_signals((), lambda _signum: None)


@pytest.fixture(autouse=True)
def no_leaks():
    """Fail a test that leaves a child process or a thread running (STYLE.md principle 8)."""
    threads_before = set(threading.enumerate())
    kids_before = _children()
    yield
    deadline = time.monotonic() + 3.0
    while time.monotonic() < deadline:
        threads = [t for t in threading.enumerate() if t not in threads_before and t.is_alive()]
        kids = _children() - kids_before
        if not threads and not kids:
            return
        time.sleep(0.05)
    assert not kids, f"test left child processes running: {sorted(kids)}"
    assert not threads, f"test left threads running: {[t.name for t in threads]}"


@pytest.fixture
def cfg() -> Config:
    return load_config()


@pytest.fixture
def repo_root() -> Path:
    return Path(__file__).resolve().parent.parent


# Tests that run the controller and the simulator as processes over a bus (real-time loops that spin
# to their deadlines): marked ``bus_processes``, so that ``make test-all`` runs them one at a time
# after the in-process tests, which run in two workers (pytest-xdist). Beside a second worker they
# failed: two at once starved each other's simulator (15-21 missing drive frames a run), and one
# beside a CPU-bound test lost its simulator for 10 cycles (issue 37's stall) or found the monitoring
# port taken. Tried again on 2026-12-07 (404 passed in one run of two workers, 402 and 361 of 362 in
# two more): each run takes the machine's one CPU shield, which moves every normal task off its
# loop's CPU, the other worker's too, and a run started under it faulted with its loop on the CPU left.
BUS_PROCESS_TESTS = (
    "tests/integration/",
    "tests/tools/test_tutorial.py",
    "tests/tools/test_bench.py",
    "tests/unit/test_nspu_integration.py",
    "tests/protocol/test_kernel_sync.py",
    "tests/protocol/test_realtime_after_startup.py",
    "tests/protocol/test_sim_answer_path.py",
)


@pytest.hookimpl(tryfirst=True)  # before -m deselects by marker
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    root = Path(__file__).resolve().parents[1]
    for item in items:
        if item.path.resolve().relative_to(root).as_posix().startswith(BUS_PROCESS_TESTS):
            item.add_marker(pytest.mark.bus_processes)
