"""The guardian's watch for tracers of the controller (controller/shell/tracer_watch.py), on a /proc
written in a temporary directory: what it names, and how it counts the looks."""

from __future__ import annotations

from pathlib import Path

from controller.shell.tracer_watch import TracerWatch, tracer_pid

STATUS = (
    "Name:\tpython\nState:\tS (sleeping)\nTgid:\t{pid}\nPid:\t{tid}\nTracerPid:\t{tracer}\nUid:\t0\t0\t0\t0\n"
)


def _thread(proc: Path, pid: int, tid: int, tracer: int) -> None:
    task = proc / str(pid) / "task" / str(tid)
    task.mkdir(parents=True, exist_ok=True)
    (task / "status").write_text(STATUS.format(pid=pid, tid=tid, tracer=tracer))


def _process(proc: Path, pid: int, comm: str) -> None:
    (proc / str(pid)).mkdir(parents=True, exist_ok=True)
    (proc / str(pid) / "comm").write_text(comm + "\n")


def test_tracer_pid_is_read_from_a_status() -> None:
    assert tracer_pid(STATUS.format(pid=7, tid=8, tracer=4321)) == 4321
    assert tracer_pid(STATUS.format(pid=7, tid=8, tracer=0)) == 0
    assert tracer_pid("Name:\tpython\n") == 0  # no such field: no tracer


def test_a_tracer_of_any_thread_is_named_once_a_look(tmp_path: Path) -> None:
    now = [0.0]
    _process(tmp_path, 900, "strace")
    _thread(tmp_path, 100, 100, 0)
    _thread(tmp_path, 100, 101, 900)  # strace -f: every thread traced, one tracer
    _thread(tmp_path, 100, 102, 900)
    watch = TracerWatch([100, 200], tmp_path, clock=lambda: now[0])  # 200: gone already
    watch.scan()
    now[0] = 1.0
    _thread(tmp_path, 100, 101, 0)  # detached from one thread, still on the other
    watch.scan()
    now[0] = 2.0
    _thread(tmp_path, 100, 102, 0)  # gone
    watch.scan()
    assert watch.report() == [{"pid": 900, "name": "strace", "seen_s": [0.0, 1.0], "looks": 2}]


def test_an_untraced_process_names_none_and_a_gone_tracer_is_named_by_its_pid(tmp_path: Path) -> None:
    _thread(tmp_path, 100, 100, 0)
    watch = TracerWatch([100], tmp_path)
    watch.scan()
    assert watch.report() == []
    _thread(tmp_path, 100, 100, 555)  # its /proc entry gone before the look
    watch.scan()
    assert [(t["pid"], t["name"]) for t in watch.report()] == [(555, "?")]
