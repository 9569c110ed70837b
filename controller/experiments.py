"""A task's experiment: what ``cheope demo`` runs for a task instead of the plain service run.

The paper's contour experiment (seed 001 §7) runs the laps, compares them with position control
and reports per lap; a plug-in task can bring its own the same way. An ``Experiment`` is declared
by task kind under the entry-point group ``cheope.experiments`` (``controller/plugins.py``; the
built-in one in ``pyproject.toml``), so no command branches on the task's kind.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from controller.plugins import EXPERIMENTS_GROUP, Hooks

if TYPE_CHECKING:
    from controller.config import Config
    from controller.core.ports import CycleObserver


@dataclass(frozen=True)
class Experiment:
    # (cfg, spec, plot_dir, max_duration_s, stop_event, realtime, observers, *, true_force) -> summary,
    # with the simulator already started on ``spec`` (controller/shell/demo.py); ``true_force(t)`` is
    # the simulator's true contact force [N] of its latest SYNC by ``t`` (sim_backend/true_force_tap.py)
    over_bus: Callable[..., dict[str, object]]
    # (cfg, max_duration_s, plot_dir) -> summary, against the in-process devices in simulated
    # time (``cheope demo --simulated-time``); None: the experiment has no such run
    simulated_time: Callable[[Config, float, Path | None], dict[str, object]] | None = None
    # cfg -> (an observer for a run of the task, the summary of what it saw): the per-lap report the
    # bench adds to its runs over the bus (``cheope bench --task KIND``); None: no such report
    lap_report: Callable[[Config], tuple[CycleObserver, Callable[[], dict[str, object]]]] | None = None


EXPERIMENTS = Hooks(EXPERIMENTS_GROUP, "Experiment", Experiment)


def experiment_for(task_kind: str) -> Experiment | None:
    found: Experiment | None = EXPERIMENTS.get(task_kind)
    return found
