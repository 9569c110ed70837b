"""Work per cycle: a deterministic figure of what one control cycle costs the loop's thread.

    .venv/bin/python -m controller.tools.bench.cycle_work [--task path] [--skip 800] [--cycles 1000] [--instructions [--by-function N] [--callgrind-out FILE]]

Timing figures move with everything else on the machine; this one does not, so that a change that
makes the cycle costlier shows as a number, run after run (``cheope bench`` prints it beside its
wall-clock figures; ``tests/unit/test_cycle_work.py`` holds it to the budget of
docs/measurements/speed.md).

1. A reference run of the task on the in-process simulated devices in simulated time
   (``sim_backend.loopback``) records what the devices put on the bus in answer to each frame the
   controller sent, and the controller's outputs of every cycle.
2. The measured run: the same law, the production exchange (``drivers.cyclic_exchange``) over a
   scripted bus that answers every frame as the devices did, the loop shell on simulated time,
   and the observers of a run on the bus (the run summary's, and the recording's loop side, whose
   records go to /dev/null instead of a writer process): the controller's side of each cycle and
   nothing else, no simulated device. Its outputs must equal the reference run's, bit for bit:
   otherwise the figure would be of other cycles, and it is refused.
3. Counted over the cycles ``[skip, skip + cycles)`` of the measured run (the path task's lap, the
   contour's tracking), with the automatic garbage collector off:
   - Python function calls, C function calls and bytecodes per cycle (``sys.setprofile``,
     ``sys.settrace`` with opcode events), in total and by part of the cycle (the exchange's send
     and collect, the law's step, the observers, the loop shell around them);
   - the garbage the cycle leaves: tracked objects (the collector's young count, which starts a
     collection at 700) more at the end of the window than at its start, per cycle, in a run
     without the counting hooks: a steady cycle leaves none, so the collector has nothing to do;
   - with ``--instructions``, in a second process under valgrind's callgrind (no counting hooks
     there): machine instructions per cycle, between two markers (``os.getsid``, ``--dump-before``);
     with ``--by-function N`` also the N compiled functions of the law that cost the most of them.

The counts depend only on the code and the configuration (``PYTHONHASHSEED=0`` under callgrind,
whose count also moves by a fraction of a percent with the address layout).
"""

from __future__ import annotations

import argparse
import gc
import itertools
import json
import math
import os
import pickle
import re
import shutil
import subprocess
import sys
import tempfile
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import FrameType
from typing import Any

import can

from controller.compiled_law import LAW_BUILD, run_interpreted
from controller.tools.bench.exchange_hook import WrappedExchange

PARTS = ("loop", "send", "collect", "step", "observers")
DEFAULT_TASK_WINDOWS = {"path": (800, 1000), "contour": (3200, 500)}  # (skip, cycles): the lap, the tracking
# The budget of a cycle at the default configuration, over the default window: about 1.3 times the
# figures of docs/measurements/speed.md, so that a change that makes the cycle 1.4 times costlier
# fails tests/unit/test_cycle_work.py and becomes a decision (raise the budget there and in the docs).
BUDGET_PER_CYCLE = {
    # 15 500 / 335 and 23 500 / 605 until the law checked each task reference and the measured pose
    # on the path (a decision: +2 749 bytecodes on each task; docs: speed.md); 15 000 and 23 000 until
    # records.replace copied a record field by field
    "path": {"bytecodes": 18500, "c_calls": 410},
    "contour": {"bytecodes": 26500, "c_calls": 690},  # 22 500 until the restart after a hold-up (+210)
}
MAX_TRACKED_OBJECTS_LEFT_PER_CYCLE = 1.5  # a young collection (700) at most every ~470 cycles
_MARKER = "getsid"  # the libc function callgrind dumps before: os.getsid(0) marks the window's ends
_HERE = os.path.abspath(__file__)
_REPO = str(Path(__file__).resolve().parents[2])  # the callgrind process imports the same code as this one


@dataclass
class Script:
    """What the devices answered in the reference run: for each frame the controller sent (in order)
    the frames they put on the bus, and for each cycle what was there before the cycle's send."""

    before_send: list[list[can.Message]] = field(default_factory=list)
    per_send: list[list[can.Message]] = field(default_factory=list)
    outputs: list[tuple[tuple[float, ...], tuple[int, ...]]] = field(default_factory=list)  # targets, words
    duration_s: float = 0.0  # the runs' max_duration_s: both are stopped at the same cycle


class ScriptedBus(can.BusABC):
    """Answers the i-th frame sent with the frames the devices answered it with in the reference run."""

    def __init__(self, script: Script) -> None:
        super().__init__(channel="scripted")
        self.script = script
        self.inbox: deque[can.Message] = deque()
        self.sends = 0
        self._is_shutdown = True

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        i = self.sends
        self.sends = i + 1
        if i < len(self.script.per_send):
            self.inbox.extend(self.script.per_send[i])

    def recv(self, timeout: float | None = None) -> can.Message | None:
        return self.inbox.popleft() if self.inbox else None

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        return self.recv(), False


def task_config(task: str, overrides: Sequence[str] = ()) -> Any:
    """The default configuration running ``task``, without recording and monitoring (the loop's own work)."""
    from controller.config import load_config, parse_override

    values: dict[str, object] = {"task.kind": task, "recording.enabled": False, "monitoring.enabled": False}
    values.update(parse_override(text) for text in overrides)
    return load_config(overrides=values)


class _Outputs:
    """Observer: each cycle's targets and controlwords, kept (``expected`` None) or compared with
    ``expected`` as they come (nothing kept: the measured run's garbage is the loop's own)."""

    def __init__(self, expected: list[tuple[tuple[float, ...], tuple[int, ...]]] | None = None) -> None:
        self.seen: list[tuple[tuple[float, ...], tuple[int, ...]]] = []
        self.expected = expected
        self.cycles = 0
        self.first_difference: int | None = None

    def on_cycle(
        self, cycle: int, t: float, inputs: Any, state: Any, outputs: Any, events: Any, timing: Any
    ) -> None:
        k = self.cycles
        self.cycles = k + 1
        if self.expected is None:
            self.seen.append((tuple(outputs.targets), tuple(outputs.controlwords)))
        elif self.first_difference is None and (
            k >= len(self.expected)
            or self.expected[k] != (tuple(outputs.targets), tuple(outputs.controlwords))
        ):
            self.first_difference = k


def reference_run(task: str, overrides: list[str], cycles: int) -> Script:
    """The task on the in-process devices for ``cycles`` cycles (then a stop): the devices' answers."""
    from controller.assembly import build_law
    from controller.shell.loop import CycleLoop, SimulatedTime
    from sim_backend.loopback import LoopbackExchange

    cfg = task_config(task, overrides)
    clock = SimulatedTime()
    law = build_law(cfg)
    devices = LoopbackExchange(cfg, clock.clock)
    script = Script()
    inbox = devices.bus.inbox
    answer = devices.bus.on_send

    def on_send(msg: can.Message) -> None:
        before = len(inbox)
        answer(msg)
        script.per_send.append(list(itertools.islice(inbox, before, None)))

    devices.bus.on_send = on_send
    devices.exchange = _SendTap(devices.exchange, script, inbox)  # type: ignore[assignment]  # the reference run's tap
    outputs = _Outputs()
    script.duration_s = cycles * cfg.period_s
    CycleLoop(
        law, devices, cfg.period_s, cfg.loop.collect_fraction, clock, clock.clock, observers=(outputs,)
    ).run(law.initial_state(), script.duration_s)
    script.outputs = outputs.seen
    return script


class _SendTap(WrappedExchange):
    """The loopback's exchange, its ``send`` noting the frames waiting before it (after last cycle's
    late ones); the rest is the exchange's (exchange_hook.py)."""

    def __init__(self, exchange: Any, script: Script, inbox: Any) -> None:
        super().__init__(exchange)
        self._script, self._inbox = script, inbox

    def send(self, outputs: Any, send_by_s: float = math.inf) -> bool:
        self._script.before_send.append(list(self._inbox))
        return bool(self.inner.send(outputs, send_by_s))


class _Counter:
    """Python calls, C calls and bytecodes by part of the cycle, while ``on`` (this module's own frames
    are not counted)."""

    def __init__(self) -> None:
        self.on = False
        self.part = "loop"
        self.calls = dict.fromkeys(PARTS, 0)
        self.c_calls = dict.fromkeys(PARTS, 0)
        self.bytecodes = dict.fromkeys(PARTS, 0)

    def switch(self, on: bool) -> None:
        """Counting on or off, from inside the run: the hooks are set only for the window (a traced
        bytecode costs a Python call), the frames already running (the loop's) included."""
        self.on = on
        sys.setprofile(self.profile if on else None)
        sys.settrace(self.trace if on else None)
        frame: FrameType | None = sys._getframe(1)
        while frame is not None:
            if frame.f_code.co_filename != _HERE:
                frame.f_trace_opcodes = on
                frame.f_trace = self._opcode if on else None
            frame = frame.f_back

    def profile(self, frame: Any, event: str, arg: Any) -> None:
        if not self.on or frame.f_code.co_filename == _HERE:
            return
        if event == "call":
            self.calls[self.part] += 1
        elif event == "c_call":
            self.c_calls[self.part] += 1

    def trace(self, frame: Any, event: str, arg: Any) -> Any:
        if frame.f_code.co_filename == _HERE:
            return None
        frame.f_trace_opcodes = True
        return self._opcode

    def _opcode(self, frame: Any, event: str, arg: Any) -> Any:
        if event == "opcode" and self.on:
            self.bytecodes[self.part] += 1
        return self._opcode


class _Parts:
    """The measured run's hooks: which part of the cycle runs, the window's ends, the garbage left."""

    def __init__(self, counter: _Counter | None, skip: int, cycles: int, marker: bool) -> None:
        self.counter = counter
        self.first, self.end = skip, skip + cycles
        self.marker = marker
        self.gc_young: list[int] = []

    def set_part(self, part: str) -> None:
        if self.counter is not None:
            self.counter.part = part

    def boundary(self, cycle: int) -> None:
        """After the last observer of ``cycle``: the window opens before ``first``, closes after ``end - 1``."""
        if cycle == self.first - 1 or cycle == self.end - 1:
            opening = cycle == self.first - 1
            self.gc_young.append(gc.get_count()[0])
            if self.marker:
                os.getsid(0)
            if self.counter is not None:
                self.counter.switch(opening)


class _Exchange:
    def __init__(self, inner: Any, bus: ScriptedBus, script: Script, parts: _Parts) -> None:
        self.inner, self.bus, self.script, self.parts = inner, bus, script, parts
        self.cycle = 0

    def send(self, outputs: Any, send_by_s: float = math.inf) -> bool:
        self.parts.set_part("send")
        if self.cycle < len(self.script.before_send):
            self.bus.inbox.extend(self.script.before_send[self.cycle])
        self.cycle += 1
        in_time: bool = self.inner.send(outputs, send_by_s)
        self.parts.set_part("loop")
        return in_time

    def collect(self, deadline_s: float) -> Any:
        self.parts.set_part("collect")
        feedback = self.inner.collect(deadline_s)
        self.parts.set_part("loop")
        return feedback


class _Law:
    def __init__(self, inner: Any, parts: _Parts) -> None:
        self.inner, self.parts = inner, parts
        self.task = inner.task
        self.config = inner.config

    def step(self, state: Any, inputs: Any, t: float) -> Any:
        self.parts.set_part("step")
        out = self.inner.step(state, inputs, t)
        self.parts.set_part("loop")
        return out


class _PartObserver:
    def __init__(self, parts: _Parts, first: bool) -> None:
        self.parts, self.first = parts, first

    def on_cycle(
        self, cycle: int, t: float, inputs: Any, state: Any, outputs: Any, events: Any, timing: Any
    ) -> None:
        if self.first:
            self.parts.set_part("observers")
        else:
            self.parts.set_part("loop")
            self.parts.boundary(cycle)


def measured_run(
    task: str, overrides: list[str], script: Script, skip: int, cycles: int, count: bool, marker: bool
) -> dict[str, Any]:
    """The controller's side of the reference run's cycles, counted over ``[skip, skip + cycles)``."""
    from controller.assembly import build_law
    from controller.shell.loop import CycleLoop, SimulatedTime
    from controller.shell.run_summary import RunRecorder
    from controller.shell.service import sleeps_through_window
    from controller.shell.thread_usage import thread_usage_readers
    from logs.recorder import SessionRecorder
    from sim_backend.loopback import LoopbackExchange

    cfg = task_config(task, overrides)
    clock = SimulatedTime()
    law = build_law(cfg)
    bus = ScriptedBus(script)
    exchange = LoopbackExchange(
        cfg, clock.clock
    ).exchange  # the production exchange as the devices' run built it
    exchange.bus = bus
    if sleeps_through_window(cfg.period_s):  # as the service reads its answers at this rate
        exchange.window_sleep = clock.sleep_until
    recording = SessionRecorder(os.devnull, clock=clock.clock, phase_name=law.task.phase_name)
    sink = os.open(os.devnull, os.O_WRONLY)
    recording._fd = sink  # the loop's side of recording, into /dev/null: no writer process to wait for
    exchange.frame_sink = recording.on_frame
    counter = _Counter() if count else None
    parts = _Parts(counter, skip, cycles, marker)
    outputs = _Outputs(script.outputs)
    observers = (_PartObserver(parts, True), RunRecorder(), recording, outputs, _PartObserver(parts, False))
    loop = CycleLoop(
        _Law(law, parts),  # type: ignore[arg-type]  # the law, its step marked
        _Exchange(exchange, bus, script, parts),
        cfg.period_s,
        cfg.loop.collect_fraction,
        clock,
        clock.clock,
        observers=observers,
        thread_usage=thread_usage_readers(),  # as the service reads it (thread_usage.py)
    )
    gc.collect()
    gc.freeze()
    was_on = gc.isenabled()
    gc.disable()
    try:
        loop.run(law.initial_state(), script.duration_s)
    finally:
        sys.setprofile(None)
        sys.settrace(None)
        if was_on:
            gc.enable()
        gc.unfreeze()
        os.close(sink)
    if outputs.first_difference is not None or outputs.cycles != len(script.outputs):
        first = outputs.first_difference if outputs.first_difference is not None else outputs.cycles
        raise RuntimeError(
            f"the measured run's outputs differ from the reference run's from cycle {first} on"
        )
    if len(parts.gc_young) != 2:
        raise RuntimeError(f"the run ended before cycle {skip + cycles}: no window to count")
    result: dict[str, Any] = {
        "task": task,
        "skip": skip,
        "cycles": cycles,
        "law": LAW_BUILD.describe(),
        "tracked_objects_left_per_cycle": round((parts.gc_young[1] - parts.gc_young[0]) / cycles, 3),
    }
    if counter is not None:
        for name, table in (
            ("python_calls", counter.calls),
            ("c_calls", counter.c_calls),
            ("bytecodes", counter.bytecodes),
        ):
            result[f"{name}_per_cycle"] = round(sum(table.values()) / cycles, 1)
            result[f"{name}_per_cycle_by_part"] = {p: round(v / cycles, 1) for p, v in table.items()}
    return result


def count_work(task: str, skip: int, cycles: int, overrides: Sequence[str] = ()) -> dict[str, Any]:
    """Interpreter counts per cycle (module text, 3.): the garbage from a run without the counting
    hooks (they allocate), the counts from a second run of the same script with them.

    Of the law's sources: where this process runs the law compiled (controller/compiled_law.py),
    whose bytecodes the interpreter does not see, in a child process that runs it interpreted."""
    if LAW_BUILD.compiled:
        return _count_interpreted(task, skip, cycles, overrides)
    script = reference_run(task, list(overrides), skip + cycles)
    plain = measured_run(task, list(overrides), script, skip, cycles, count=False, marker=False)
    counted = measured_run(task, list(overrides), script, skip, cycles, count=True, marker=False)
    counted["tracked_objects_left_per_cycle"] = plain["tracked_objects_left_per_cycle"]
    return counted


def _count_interpreted(task: str, skip: int, cycles: int, overrides: Sequence[str]) -> dict[str, Any]:
    args = ["--task", task, "--skip", str(skip), "--cycles", str(cycles)]
    result: dict[str, Any] = run_interpreted(
        "controller.tools.bench.cycle_work", [*args, *(a for o in overrides for a in ("--set", o))]
    )
    for added in ("budget_per_cycle", "over_budget"):  # main's, for the default window
        result.pop(added, None)
    return result


def over_budget(result: dict[str, Any]) -> list[str]:
    """What of ``count_work``'s ``result`` (default configuration and window) exceeds the budget."""
    budget = BUDGET_PER_CYCLE[result["task"]]
    over = [
        f"{name} per cycle {result[f'{name}_per_cycle']} > budget {limit}"
        for name, limit in budget.items()
        if result[f"{name}_per_cycle"] > limit
    ]
    left = result["tracked_objects_left_per_cycle"]
    if abs(left) > MAX_TRACKED_OBJECTS_LEFT_PER_CYCLE:
        over.append(f"tracked objects left per cycle {left} > {MAX_TRACKED_OBJECTS_LEFT_PER_CYCLE}")
    return over


def count_instructions(
    task: str,
    skip: int,
    cycles: int,
    overrides: Sequence[str] = (),
    valgrind: str | None = None,
    by_function: int = 0,
    keep_dump: Path | None = None,
) -> dict[str, Any]:
    """Machine instructions per cycle under callgrind; ``{"instructions_per_cycle": None, ...}`` without valgrind.

    ``by_function``: also the compiled law's ``by_function`` costliest functions, inclusive, per cycle
    (``compiled_functions_per_cycle``, from ``callgrind_annotate``): where a cycle's instructions go.
    ``keep_dump``: the window's callgrind dump is copied there, for ``callgrind_annotate`` to read."""
    valgrind = valgrind or shutil.which("valgrind")
    if valgrind is None:
        return {"instructions_per_cycle": None, "why": "valgrind not found (apt-get install valgrind)"}
    script = reference_run(task, list(overrides), skip + cycles)
    with tempfile.TemporaryDirectory(prefix="cheope-work-") as tmp:
        script_path = Path(tmp) / "script.pickle"
        script_path.write_bytes(pickle.dumps(script))
        instructions, window = callgrind_window(
            [
                "controller.tools.bench.cycle_work",
                "--child",
                str(script_path),
                "--task",
                task,
                "--skip",
                str(skip),
                "--cycles",
                str(cycles),
                *(a for o in overrides for a in ("--set", o)),
            ],
            Path(tmp) / "callgrind.out",
            valgrind,
        )
        functions = compiled_functions_per_cycle(window, cycles, by_function) if by_function else {}
        if keep_dump is not None:
            shutil.copyfile(window, keep_dump)
    return {
        "instructions_per_cycle": round(instructions / cycles),
        "tool": "valgrind --tool=callgrind",
        **({"compiled_functions_per_cycle": functions} if by_function else {}),
        **(
            {
                "compiled_functions_why": "callgrind_annotate not found"
                if shutil.which("callgrind_annotate") is None
                else f"no compiled function in the dump (the law ran {LAW_BUILD.describe()})"
            }
            if by_function and not functions
            else {}
        ),
    }


def callgrind_window(module_args: Sequence[str], out: Path, valgrind: str) -> tuple[int, Path]:
    """``python -m *module_args`` under callgrind, its counts dumped at each ``os.getsid`` marker into
    ``out``.N: the instructions between the first two markers (the window) and that dump's path.
    The child imports this checkout and the venv's packages as this process does."""
    cmd = [
        valgrind,
        "--tool=callgrind",
        f"--dump-before={_MARKER}",
        f"--callgrind-out-file={out}",
        "--trace-children=no",
        # the interpreter itself, not the venv's link to it (valgrind does not follow the link): the
        # venv's packages and this checkout by path
        os.path.realpath(sys.executable),
        "-m",
        *module_args,
    ]
    env = {**os.environ, "PYTHONHASHSEED": "0", "PYTHONPATH": os.pathsep.join([_REPO, *sys.path])}
    run = subprocess.run(cmd, capture_output=True, text=True, env=env, check=False)
    if run.returncode != 0:
        raise RuntimeError(f"callgrind run failed ({run.returncode}): {run.stderr[-2000:]}")
    window = Path(f"{out}.2")  # part 1: start to the first marker; part 2: the window
    match = re.search(r"^summary:\s*(\d+)", window.read_text(), re.M) if window.exists() else None
    if match is None:
        raise RuntimeError(f"no callgrind dump of the window ({window.name}): {run.stderr[-2000:]}")
    return int(match.group(1)), window


# callgrind_annotate's inclusive line of a function mypyc compiled: "1,234 (5.6%)  file.c:CPyDef_mod___Cls___name [lib]"
# (no percentage with --show-percs=no). Only the line with the object ([lib]) is the function's own
# entry: the others of its name are its lines' shares by the source file they came from (headers
# it inlined, the .c file by its absolute path), not counts of the function.
_COMPILED_FUNCTION = re.compile(r"^\s*([\d,]+) (?:\([^)]*\)\s+)?\s*\S*:CPyDef_(\w+) \[[^\]]*\]\s*$")


def compiled_functions_per_cycle(dump: Path, cycles: int, top: int) -> dict[str, int]:
    """The ``top`` compiled functions of a callgrind dump by inclusive instructions per cycle
    (``functions_per_cycle``); {} without ``callgrind_annotate`` (valgrind's package has it)."""
    annotate = shutil.which("callgrind_annotate")
    if annotate is None:
        return {}
    run = subprocess.run(
        [annotate, "--inclusive=yes", "--threshold=100", str(dump)],
        capture_output=True,
        text=True,
        check=False,
    )
    if run.returncode != 0:
        raise RuntimeError(f"callgrind_annotate failed ({run.returncode}): {run.stderr[-2000:]}")
    return functions_per_cycle(run.stdout, cycles, top)


def functions_per_cycle(annotated: str, cycles: int, top: int) -> dict[str, int]:
    """The ``top`` compiled functions of ``callgrind_annotate --inclusive=yes`` output, named
    ``module.Class.method`` (mypyc's C name with its ``___`` separators undone), by instructions per
    cycle. Inclusive: a function's count holds its callees', interpreted ones too."""
    totals: dict[str, int] = {}
    for line in annotated.splitlines():
        match = _COMPILED_FUNCTION.match(line)
        if match is not None:
            name = ".".join(match.group(2).split("___"))
            totals[name] = totals.get(name, 0) + int(match.group(1).replace(",", ""))  # once per object
    ranked = sorted(totals.items(), key=lambda item: item[1], reverse=True)[:top]
    return {name: round(n / cycles) for name, n in ranked}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="cycle_work", description=__doc__.split("\n\n")[0])
    ap.add_argument("--task", default="path", choices=sorted(DEFAULT_TASK_WINDOWS))
    ap.add_argument("--skip", type=int, help="cycles before the counted window (default: the task's)")
    ap.add_argument("--cycles", type=int, help="cycles counted (default: 1000)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="configuration override")
    ap.add_argument("--instructions", action="store_true", help="also instructions per cycle (valgrind)")
    ap.add_argument(
        "--by-function",
        type=int,
        default=0,
        metavar="N",
        help="with --instructions: also the N compiled functions costliest per cycle (inclusive)",
    )
    ap.add_argument(
        "--callgrind-out",
        type=Path,
        metavar="FILE",
        help="with --instructions: keep the window's callgrind dump",
    )
    ap.add_argument("--child", metavar="SCRIPT", help=argparse.SUPPRESS)  # the callgrind process
    args = ap.parse_args(argv)
    if (args.by_function or args.callgrind_out) and not args.instructions:
        ap.error("--by-function and --callgrind-out go with --instructions")
    if args.by_function < 0:
        ap.error(f"--by-function {args.by_function}: a count of functions, 0 or more")
    skip, cycles = DEFAULT_TASK_WINDOWS[args.task]
    skip = args.skip if args.skip is not None else skip
    cycles = args.cycles if args.cycles is not None else cycles
    if args.child:
        script = pickle.loads(Path(args.child).read_bytes())
        measured_run(args.task, args.set, script, skip, cycles, count=False, marker=True)
        return 0
    result = count_work(args.task, skip, cycles, args.set)
    if (skip, cycles) == DEFAULT_TASK_WINDOWS[args.task] and not args.set:
        result["budget_per_cycle"] = BUDGET_PER_CYCLE[args.task]
        result["over_budget"] = over_budget(result)
    if args.instructions:
        result.update(
            count_instructions(
                args.task, skip, cycles, args.set, by_function=args.by_function, keep_dump=args.callgrind_out
            )
        )
    print(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
