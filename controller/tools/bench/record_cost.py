"""The recorder's cost on the loop's thread: one cycle's record, compiled beside interpreted.

    .venv/bin/python -m controller.tools.bench.record_cost [--task contour] [--passes 21]

Runs the task in simulated time and keeps every 50th cycle of a window of it (the contour's
tracking). Then, pass after pass in turn so that all see the same host, for each kept cycle:

- ``loop``: what the recorder does on the loop's thread, the cycle's values
  (``logs.cycle_encoding.cycle_values``) pickled, with the module as this process imports it
  (compiled by mypyc where the build is fresh). With the task fields' names in every cycle: the
  recorder sends them only when they change (``logs.recorder``), so this is the cost of a cycle
  whose names changed, the most a record costs (``tests/tools/bench_record_pickle.py`` gives
  both);
- ``loop_interpreted``: the same with the module's source loaded as a second module, interpreted;
- ``writer``: the ``/cycle`` Protobuf built from those values and serialised
  (``logs.messages.cycle_pb``), which the writer's process does.

The Protobuf of both modules' values must be equal, or the figure is refused. Prints JSON: the
median, min and max over the passes of each one's mean time a cycle, and the loop's ratio.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import pickle
import sys
import time
from pathlib import Path
from typing import Any

from controller.compiled_law import LAW_BUILD
from controller.tools.bench.cycle_work import task_config
from logs.messages import cycle_pb

WINDOWS = {"path": (800, 1800), "contour": (8000, 16000)}  # cycles: the path's lap, the contour's tracking
EVERY = 50


def _interpreted_encoding() -> Any:
    """logs/cycle_encoding.py from its source, as a module of its own (the compiled one stays imported)."""
    import logs.cycle_encoding as compiled

    source = Path(compiled.__file__ or "").with_name("cycle_encoding.py")
    spec = importlib.util.spec_from_file_location("cycle_encoding_interpreted", source)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses and typing look their module up
    spec.loader.exec_module(module)
    return module


def record_cost(task: str, passes: int) -> dict[str, object]:
    import logs.cycle_encoding as compiled
    from controller.shell.simulated_rig import SimulatedRig

    cfg = task_config(task, [])
    rig = SimulatedRig(cfg)
    first, last = WINDOWS[task]
    kept: list[tuple[int, float, Any, Any, Any, Any]] = []

    class Keep:
        def on_cycle(
            self, k: int, t: float, inputs: Any, state: Any, outputs: Any, events: Any, timing: Any
        ) -> None:
            if first <= k < last and k % EVERY == 0:
                kept.append((k, t, inputs, state, outputs, timing))

    rig.run((Keep(),), max_duration_s=(last + 1) * cfg.period_s)
    phase = rig.law.task.phase_name
    interpreted = _interpreted_encoding()
    values = [compiled.cycle_values(*c, phase) for c in kept]
    for c, v in zip(kept, values, strict=True):
        if cycle_pb(v) != cycle_pb(interpreted.cycle_values(*c, phase)):
            raise SystemExit(f"cycle {c[0]}: the compiled and the interpreted records differ")

    def loop_us(module: Any) -> float:
        t0 = time.perf_counter()
        for c in kept:
            pickle.dumps(module.cycle_values(*c, phase), pickle.HIGHEST_PROTOCOL)
        return (time.perf_counter() - t0) / len(kept) * 1e6

    def writer_us() -> float:
        t0 = time.perf_counter()
        for v in values:
            cycle_pb(v).SerializeToString()
        return (time.perf_counter() - t0) / len(kept) * 1e6

    runs: dict[str, list[float]] = {"loop": [], "loop_interpreted": [], "writer": []}
    for _ in range(passes):
        runs["loop"].append(loop_us(compiled))
        runs["loop_interpreted"].append(loop_us(interpreted))
        runs["writer"].append(writer_us())
    out: dict[str, object] = {
        "task": task,
        "law": LAW_BUILD.describe(),
        "cycles": len(kept),
        "passes": passes,
    }
    medians = {}
    for name, times in runs.items():
        times.sort()
        medians[name] = times[len(times) // 2]
        out[f"{name}_us"] = {
            "median": round(medians[name], 1),
            "min": round(times[0], 1),
            "max": round(times[-1], 1),
        }
    out["loop_ratio_of_medians"] = round(medians["loop"] / medians["loop_interpreted"], 3)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="record_cost", description=__doc__.split("\n\n")[0])
    ap.add_argument("--task", choices=sorted(WINDOWS), default="contour")
    ap.add_argument("--passes", type=int, default=21)
    args = ap.parse_args(argv)
    print(json.dumps(record_cost(args.task, args.passes), indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
