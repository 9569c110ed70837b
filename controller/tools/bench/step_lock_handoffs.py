"""Where the compiled step can hand the interpreter lock to another thread, and how often it does.

    .venv/bin/python -m controller.tools.bench.step_lock_handoffs [--task contour] [--cycles 3000]
        [--switch-interval-us 200 5000]

The step runs compiled (``controller/compiled_law.py``), and compiled code gives the interpreter
lock up only where it runs interpreted code: the interpreter checks, between bytecodes, whether
another thread has waited ``sys.getswitchinterval()`` for the lock, and hands it over if so. The
loop then waits inside its step until that thread lets go; a thread whose vCPU the host paused
lets go after the pause (docs/concepts/realtime.md, "Seen from the loop thread").

Two figures, on the in-process simulated devices in simulated time (no wall clock in the law):

- the interpreted functions a step calls, per step (``sys.setprofile`` during the step only);
- for each switch interval, the steps during which a thread spinning beside the loop ran: it
  wants the lock all the time, as a busy helper would.
"""

from __future__ import annotations

import argparse
import collections
import sys
import threading
from collections.abc import Callable
from types import FrameType
from typing import Any

from controller.tools.bench.step_hook import StepAround, StepHookedLaw


def _run(task: str, cycles: int, around: StepAround) -> int:
    """``cycles`` cycles of ``task`` with ``around`` wrapping each step; the steps it saw."""
    from controller.shell.simulated_rig import SimulatedRig
    from controller.tools.bench.cycle_work import task_config

    cfg = task_config(task)
    rig = SimulatedRig(cfg)
    seen = [0]

    def counted(step: Callable[[Any, Any, float], Any], state: Any, inputs: Any, t: float) -> Any:
        seen[0] += 1
        return around(step, state, inputs, t)

    rig.law = StepHookedLaw(rig.law, counted)  # type: ignore[assignment]  # the same law, its step wrapped
    rig.run((), max_duration_s=cycles * cfg.period_s)
    return seen[0]


def interpreted_calls(task: str, cycles: int) -> dict[str, float]:
    """The interpreted functions the step calls, ``file:function`` -> calls per step, most first."""
    calls: collections.Counter[str] = collections.Counter()

    def profile(frame: FrameType, event: str, arg: object) -> None:
        code = frame.f_code
        if event == "call":
            calls[f"{code.co_filename.rsplit('/', 1)[-1]}:{code.co_name}"] += 1

    def around(step: Callable[[Any, Any, float], Any], state: Any, inputs: Any, t: float) -> Any:
        sys.setprofile(profile)
        try:
            return step(state, inputs, t)
        finally:
            sys.setprofile(None)

    steps = _run(task, cycles, around)
    return {name: n / steps for name, n in calls.most_common()}


def handoffs(task: str, cycles: int, switch_interval_s: float) -> tuple[int, int]:
    """(steps during which a spinning thread ran, steps) at ``switch_interval_s``."""
    spins = [0]
    stop = threading.Event()

    def spin() -> None:
        while not stop.is_set():
            spins[0] += 1

    handed = [0]

    def around(step: Callable[[Any, Any, float], Any], state: Any, inputs: Any, t: float) -> Any:
        before = spins[0]
        out = step(state, inputs, t)
        handed[0] += spins[0] != before
        return out

    spinner = threading.Thread(target=spin, name="spinner", daemon=True)
    previous = sys.getswitchinterval()
    spinner.start()
    sys.setswitchinterval(switch_interval_s)
    try:
        steps = _run(task, cycles, around)
    finally:
        sys.setswitchinterval(previous)
        stop.set()
        spinner.join()
    return handed[0], steps


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--task", default="contour", choices=("path", "contour"))
    parser.add_argument("--cycles", type=int, default=3000)
    parser.add_argument("--switch-interval-us", type=float, nargs="+", default=[200.0, 5000.0])
    args = parser.parse_args(argv)
    from controller.compiled_law import law_build

    print(f"law: {law_build()}")
    print(f"{args.task}: interpreted calls per step")
    for name, per_step in interpreted_calls(args.task, args.cycles).items():
        if per_step >= 0.01:
            print(f"  {per_step:8.2f}  {name}")
    for interval_us in args.switch_interval_us:
        handed, steps = handoffs(args.task, args.cycles, interval_us * 1e-6)
        print(f"switch interval {interval_us:g} us: a spinning thread ran during {handed} of {steps} steps")
    return 0


if __name__ == "__main__":
    sys.exit(main())
