"""What a correcting plan of the 3-nSPU costs: the reason it is planned off the loop.

    .venv/bin/python tests/tools/bench_correction_planning.py [--repeats 5]

Runs the closed-loop execution in simulated time (the issue 20 mismatch, a start 2 mm off,
the tracker, plans in the step), collects the requests the task made (measured poses), then
times ``plan_correction.correction_plan`` on each, ``--repeats`` times: median, min, max and
the number of 400 Hz periods the median would stall a loop that planned inside the step.
"""

from __future__ import annotations

import argparse
import statistics
import time

from controller.assembly import assemble
from controller.config import load_config
from controller.robot_registry import robot_entry
from controller.robots.nspu.plan_correction import correction_plan
from controller.shell.loop import CycleLoop, SimulatedTime
from sim_backend.loopback import LoopbackExchange

SETTINGS = {
    "sim.nspu.leg_offset_m": [0.0005, -0.0005, 0.0005],
    "sim.nspu.w4_axis_error_rad": [0.001, -0.001, 0.001],
    "sim.nspu.r_axis_error_rad": [-0.001, 0.001, 0.001],
    "sim.nspu.start_offset_m": [0.002, 0.0, 0.0],
    "tracker.enabled": True,
    "robot.nspu.correction_planning": "in_step",
    "recording.enabled": False,
    "monitoring.enabled": False,
}


class Requests:
    def __init__(self) -> None:
        self.by_id: dict[int, tuple[float, ...]] = {}

    def on_cycle(self, cycle, t, inputs, state, outputs, events, timing) -> None:  # type: ignore[no-untyped-def]
        rid = getattr(state.task_state, "request_id", 0)
        if rid:
            self.by_id[rid] = state.task_state.request


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    cfg = load_config(robot_entry("nspu").config_file, SETTINGS)
    clock = SimulatedTime()
    law = assemble(cfg).law
    seen = Requests()
    CycleLoop(
        law,
        LoopbackExchange(cfg, clock.clock),
        cfg.period_s,
        cfg.loop.collect_fraction,
        clock,
        clock.clock,
        observers=(seen,),
    ).run(law.initial_state(), 40.0)
    problem = law.task.correction_planner.problem
    for rid, request in seen.by_id.items():
        times = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            result = correction_plan(problem, request)  # type: ignore[arg-type]
            times.append(time.perf_counter() - t0)
        med = statistics.median(times)
        print(
            f"request {rid}: {result.iterations} iterations; {args.repeats} runs: median {med:.3f} s, "
            f"min {min(times):.3f} s, max {max(times):.3f} s; {med * cfg.loop.rate_hz:.0f} periods at "
            f"{cfg.loop.rate_hz:.0f} Hz"
        )


if __name__ == "__main__":
    main()
