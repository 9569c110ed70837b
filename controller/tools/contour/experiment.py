"""The paper's contour-tracking experiment, end to end (seed 001 §7), with its comparison.

Two runs against the same simulated hardware: first the hybrid force/velocity contour
tracking (five laps, increasing then constant speed), then the same contour done with plain
position control along the nominal circle, the circle the operator believes the contour
to be (``task.contour.expected_centre_m`` and ``expected_radius_m``), pressed in by
``comparison_press_m`` so that it would touch with about the force setpoint if the disk were
where it is expected. The simulated disk is off by a few millimetres (``sim.workpiece.centre_m``),
as a workpiece placed by hand is: the comparison shows what force control buys. It runs under the
configured safety like any move near a workpiece: a path meant to touch (``task.path.contact =
"pressing"``), reached by a guarded move at the contour's search speed; where position control
presses the displaced disk past ``safety.max_contact_force_n`` the contact guard backs it off,
and the comparison reports how far it got.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import cast

import msgspec

from controller.assembly import build_robot
from controller.config import Config, ConfigError
from controller.core.ports import CompliantStructure, CycleObserver, missing_capability
from controller.experiments import Experiment
from controller.realtime import RealtimeOptions
from controller.shell.service import run_controller
from controller.tasks.builtin import PathSection
from controller.tools.contour.report import ContourObserver, contour_summary, plot_contour
from drivers.bus import BusSpec


def structure_robot(cfg: Config) -> CompliantStructure:
    """The configured robot, whose structure (Jacobian, masses, stiffness) the experiment's report
    reads: the stiffness along the contour's normal, the ellipsoids of its plots (Cheope's, seed 001)."""
    robot = build_robot(cfg)
    lacks = missing_capability(robot, CompliantStructure)
    if lacks:
        raise ConfigError(
            f"the contour experiment reads the robot's structure, and robot.kind = {cfg.robot.kind!r} lacks {lacks}"
        )
    return cast(CompliantStructure, robot)


def comparison_config(cfg: Config) -> Config:
    c = cfg.task.model("contour")
    path = PathSection(
        center_m=(c.expected_centre_m[0], c.expected_centre_m[1], c.height_m),
        radius_m=c.expected_radius_m - c.comparison_press_m,
        speed_m_s=c.lap_speeds_m_s[-1],
        laps=1.0,
        ramp_s=0.5,
        check_samples=cfg.task.model("path").check_samples,
        # it is meant to touch: pressing along the circle, a guarded move to its start at the contour's search speed
        contact="pressing",
        move_speed_m_s=c.search_speed_m_s,
    )
    # the same workpiece under position control: announced as such, though the path task alone expects free space
    sim = msgspec.structs.replace(cfg.sim, environment="workpiece")
    return msgspec.structs.replace(
        cfg,
        task=msgspec.structs.replace(cfg.task, kind="path", models={**cfg.task.models, "path": path}),
        sim=sim,
    )


def run_contour_experiment(
    cfg: Config,
    spec: BusSpec,
    plot_dir: Path | None,
    max_duration_s: float = 600.0,
    stop_event: threading.Event | None = None,
    realtime: RealtimeOptions | None = None,
    observers: tuple[CycleObserver, ...] = (),
    true_force: Callable[[float], Sequence[float]] | None = None,
) -> dict[str, object]:
    c = cfg.task.model("contour")
    robot = structure_robot(cfg)
    stiffness = robot.actuator_stiffness_n_m

    force_obs, laps = contour_lap_report(cfg, true_force)
    summary = run_controller(
        cfg, spec, max_duration_s, stop_event, observers=(force_obs, *observers), realtime=realtime
    )
    summary["contour"] = laps()

    pos_obs: ContourObserver | None = None
    if summary["final_mode"] != "DONE":
        # The comparison's path task starts from wherever the tool is, with the contact guard off:
        # after a fault the tool is still in contact, and its move to the path's start went through
        # the disk (6 080 N of true contact force after a 0.2-s stall of the demo: the SYNC
        # watchdog's quick stop left the tool on the rim). Nothing to compare with anyway.
        summary["position_control_comparison"] = {
            "skipped": f"the contour run ended {summary['final_mode']}, with the tool where it stopped"
        }
    elif stop_event is None or not stop_event.is_set():
        cmp_cfg = comparison_config(cfg)
        pos_obs = ContourObserver(c.force_setpoint_n, c.expected_centre_m, 1, true_force)
        cmp = run_controller(
            cmp_cfg, spec, max_duration_s, stop_event, observers=(pos_obs, *observers), realtime=realtime
        )
        summary["position_control_comparison"] = {
            "final_mode": cmp["final_mode"],
            "fault_reason": cmp["fault_reason"],
            # the comparison's own run starts its own pollers: their CPU time is not the contour's
            **({"idle_poll": cmp["idle_poll"]} if "idle_poll" in cmp else {}),
            "radius_m": cmp_cfg.task.model("path").radius_m,
            "speed_m_s": cmp_cfg.task.model("path").speed_m_s,
            **contour_summary(pos_obs, robot, stiffness, c.height_m, None),
        }
    if plot_dir is not None:
        _plot(summary, cfg, plot_dir, force_obs, pos_obs)
    return summary


def contour_lap_report(
    cfg: Config, true_force: Callable[[float], Sequence[float]] | None = None
) -> tuple[ContourObserver, Callable[[], dict[str, object]]]:
    """The force error per lap, in the normal's direction, as the demo reports it (``summary["contour"]``),
    measured and, where ``true_force`` tells it (the simulator), true."""
    c = cfg.task.model("contour")
    obs = ContourObserver(c.force_setpoint_n, c.expected_centre_m, len(c.lap_speeds_m_s), true_force)
    robot = structure_robot(cfg)
    return obs, lambda: contour_summary(
        obs, robot, robot.actuator_stiffness_n_m, c.height_m, c.lap_speeds_m_s
    )


def _plot(
    summary: dict[str, object],
    cfg: Config,
    plot_dir: Path,
    force_obs: ContourObserver,
    pos_obs: ContourObserver | None = None,
) -> None:
    """Fig. 8-9 of the force-controlled run and, when there is one, of the comparison, into
    ``summary["plots"]``. A plot that cannot be written (a full disk: the start's check of
    ``--output-dir`` cannot foresee it) is named in ``summary["plots_error"]``: the run's summary
    is printed all the same (an outside tester lost a whole run's table to ENOSPC, exit 2)."""
    c = cfg.task.model("contour")
    robot = structure_robot(cfg)
    stiffness = robot.actuator_stiffness_n_m
    masses = robot.masses
    plots: list[Path] = []
    try:
        plots += plot_contour(
            force_obs, robot, stiffness, masses, c.height_m, plot_dir, "force control", c.lap_speeds_m_s
        )
        if pos_obs is not None and pos_obs.t:
            plots += plot_contour(pos_obs, robot, stiffness, masses, c.height_m, plot_dir, "position control")
    except OSError as err:
        summary["plots_error"] = f"cannot write the plots in {plot_dir}: {err.strerror or err}"
    summary["plots"] = [str(p) for p in plots]


def run_simulated_time(
    cfg: Config, max_duration_s: float = 600.0, plot_dir: Path | None = None
) -> dict[str, object]:
    """The force-controlled laps against the in-process devices in simulated time.

    Deterministic and free of the machine's timing: the reference to compare a run over a
    bus with (``cheope demo --task contour --simulated-time``).
    """
    from controller.shell.run_summary import RunRecorder, simulated_time_summary
    from controller.shell.simulated_rig import SimulatedRig

    c = cfg.task.model("contour")
    robot = structure_robot(cfg)  # refused at start, not after the run, when it lacks a structure
    rig = SimulatedRig(cfg)
    exchange = rig.exchange
    obs = ContourObserver(
        c.force_setpoint_n,
        c.expected_centre_m,
        len(c.lap_speeds_m_s),
        # in simulated time the loop observes a cycle right after its step: the plant is at its SYNC
        lambda _stepped_s: exchange.plant.force_n.tolist(),
    )
    ended = RunRecorder()
    final, stats = rig.run((obs, ended), max_duration_s)
    summary: dict[str, object] = {
        **simulated_time_summary(final, ended, stats, exchange.counters, exchange.faults),
        "contour": contour_summary(
            obs,
            robot,
            robot.actuator_stiffness_n_m,
            c.height_m,
            c.lap_speeds_m_s,
        ),
    }
    if plot_dir is not None:
        _plot(summary, cfg, plot_dir, obs)
    return summary


CONTOUR = Experiment(
    run_contour_experiment, run_simulated_time, contour_lap_report
)  # entry point cheope.experiments: contour
