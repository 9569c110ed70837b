"""The ``cheope`` command line."""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import math
import os
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn

import can

from controller.cli_arguments import job_count
from controller.cli_output import progress_line, strict_json
from controller.commands import Command, plugin_commands
from controller.config import Config, ConfigError, load_config, parse_override
from controller.errors import CheopeError, RefusedError
from controller.monitoring.cli_commands import add_controller_options, monitoring_overrides
from controller.monitoring.cli_commands import add_subcommands as add_monitoring_subcommands
from controller.output_paths import check_output_dir
from controller.plugins import listing_what_loads
from controller.robot_registry import robot_entry, robot_kinds
from controller.shell.status_line import StatusDisplay, live_status, status_wanted
from controller.signal_relay import stop_event_on_signals, stop_event_while
from controller.tasks.registry import task_kinds
from drivers.bus import BusSpec, parse_bus_spec

if TYPE_CHECKING:
    from controller.core.ports import CycleObserver
    from controller.realtime import RealtimeOptions


def _config_help(robots: tuple[str, ...]) -> str:
    """--config's help: which shipped file each --robot choice loads, and the one without --robot."""
    # each robot's own file (RobotEntry.config_file: the built-ins' in their homes); none: cheope.toml
    files = {kind: _shown(robot_entry(kind).config_file) for kind in robots}
    if len(robots) == 1:
        return f"TOML configuration (default: the robot's shipped {files[robots[0]]})"
    per_robot = ", ".join(f"{name} for --robot {kind}" for kind, name in files.items())
    return f"TOML configuration (default: the shipped file of --robot: {per_robot}; without --robot: cheope.toml)"


def _shown(path: Path | None) -> str:
    """A shipped configuration file as a user finds it: from the project's root, or a plug-in's name."""
    if path is None:
        return "controller/configs/cheope.toml"
    root = Path(__file__).resolve().parents[1]
    return str(path.resolve().relative_to(root)) if path.resolve().is_relative_to(root) else path.name


def _common(ap: argparse.ArgumentParser, bus: bool = True, robots: tuple[str, ...] | None = None) -> None:
    """``robots``: the --robot choices the command accepts (all registered robots when None)."""
    robots = robots or robot_kinds()
    ap.add_argument("--config", help=_config_help(robots))
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a configuration key, e.g. --set loop.rate_hz=1000 (repeatable)",
    )
    ap.add_argument("--rate", type=float, help="loop rate [Hz] (same as --set loop.rate_hz=...)")
    ap.add_argument(
        "--robot",
        choices=robots,
        help="the robot: loads its shipped configuration unless --config is given (then sets robot.kind)",
    )
    if bus:
        ap.add_argument(
            "--bus",
            metavar="INTERFACE[:CHANNEL]",
            help="the CAN bus: socketcan:vcan0, udp_multicast, virtual:x (default: the config's bus.can)",
        )
        ap.add_argument("--can", dest="bus", help=argparse.SUPPRESS)  # the spelling before --bus
        ap.add_argument("--udp-port", type=int, help="UDP port of the udp_multicast bus")
        ap.add_argument("--fd", action="store_true", help="use CAN FD frames")
        ap.add_argument(
            "--inject",
            action="append",
            metavar="FAULT",
            help="simulator fault, KIND[:NODE][=VALUE]@START[+DURATION], e.g. drop:2@3+0.5 "
            "(repeatable; see sim_backend/fault_injection.py)",
        )


def _rt_options(ap: argparse.ArgumentParser) -> None:
    g = ap.add_argument_group(
        "real-time options (Linux). Without any of them the loop asks for SCHED_FIFO 80 on the last CPU "
        "with locked memory (the simulator: SCHED_FIFO 70 on the others) and runs on with one line of "
        "warning where refused; given explicitly they are required"
    )
    g.add_argument("--rt-priority", type=int, metavar="N", help="SCHED_FIFO priority 1..99 for the loop")
    g.add_argument("--cpu", metavar="CPUS", help="CPU affinity, e.g. 1 or 0,1")
    g.add_argument("--lock-memory", action="store_true", help="mlockall: no page faults on the hot path")
    g.add_argument(
        "--cpu-latency-us",
        type=int,
        metavar="US",
        help="hold the CPUs' wake-up latency at most US microseconds while running (PM QoS, "
        "/dev/cpu_dma_latency; 0: no idle state that takes time to leave)",
    )
    g.add_argument(
        "--cpu-shield",
        action="store_true",
        help="keep every normal task of the machine off the loop's --cpu while the loop runs (run, demo; "
        "controller/shell/cpu_shield.py)",
    )
    g.add_argument(
        "--no-cpu-shield",
        action="store_true",
        help="the default options without the CPU shield: other work may share the loop's CPU",
    )
    g.add_argument(
        "--idle-poll",
        action="store_true",
        help="keep the controller's CPUs from halting while the loop runs: a SCHED_IDLE poller on each "
        "(a default on a VM guest that halts idle CPUs at once and has no polling idle state, where "
        "the default is --cpu-latency-us 0 otherwise; alone, with the other defaults in place of that; "
        "controller/shell/idle_poll.py)",
    )
    g.add_argument(
        "--no-idle-poll",
        action="store_true",
        help="the default options without keeping idle CPUs from halting (no poller, no latency limit)",
    )
    g.add_argument("--no-realtime", action="store_true", help="ask for none of them: the normal scheduler")
    g.add_argument(
        "--rt-best-effort",
        action="store_true",
        help="apply the options given where permitted, warn and run on where not",
    )


def _live_options(ap: argparse.ArgumentParser) -> None:
    g = ap.add_argument_group("live views, fed by the recording's writer process (logs/live_views.py)")
    g.add_argument(
        "--rerun",
        nargs="?",
        const="spawn",
        metavar="WHERE",
        help="stream the session to Rerun: spawn (a viewer, the default), serve (gRPC + web viewer "
        "for a browser) or a rerun+http://HOST:PORT/proxy URL",
    )
    g.add_argument(
        "--foxglove",
        nargs="?",
        const="127.0.0.1:8765",
        metavar="HOST:PORT",
        help="serve the session over the Foxglove WebSocket protocol (default 127.0.0.1:8765)",
    )


def _live_overrides(args: argparse.Namespace) -> list[str]:
    sets = []
    if getattr(args, "rerun", None):
        sets.append(f"recording.live_rerun={json.dumps(args.rerun)}")
    if getattr(args, "foxglove", None):
        sets.append(f"recording.live_foxglove={json.dumps(args.foxglove)}")
    return sets


# The real-time options that, given, replace the defaults, and their flags (argparse's names).
_EXPLICIT_REALTIME_FLAGS = (
    ("rt_priority", "--rt-priority"),
    ("cpu", "--cpu"),
    ("lock_memory", "--lock-memory"),
    ("cpu_latency_us", "--cpu-latency-us"),
    ("cpu_shield", "--cpu-shield"),
)


# demo's options that act on what only a run over the bus has (_refuse_realtime_in_simulated_time)
_OVER_THE_BUS_FLAGS = (
    ("bus", "--bus"),
    ("udp_port", "--udp-port"),
    ("fd", "--fd"),
    ("rerun", "--rerun"),
    ("foxglove", "--foxglove"),
    ("zenoh_connect", "--zenoh-connect"),
    ("zenoh_config", "--zenoh-config"),
    ("allow_remote_commands", "--allow-remote-commands"),
    ("robot_id", "--robot-id"),
)


def _given(args: argparse.Namespace, flags: tuple[tuple[str, str], ...]) -> list[str]:
    """The flags of ``flags`` given on the command line: a value (0 and '' too) or a switch set."""
    values = ((getattr(args, name, None), flag) for name, flag in flags)
    return [flag for value, flag in values if value is not None and value is not False]


def _realtime(args: argparse.Namespace, simulator: bool = False) -> RealtimeOptions:
    from controller.realtime import RealtimeError, RealtimeOptions, parse_cpus

    explicit = bool(_given(args, _EXPLICIT_REALTIME_FLAGS))
    if args.no_realtime:
        if explicit or args.idle_poll:
            raise RealtimeError(
                "--no-realtime cannot be combined with --rt-priority, --cpu, --lock-memory, --cpu-latency-us, "
                "--cpu-shield or --idle-poll"
            )
        return RealtimeOptions()
    if args.cpu_shield and args.no_cpu_shield:
        raise RealtimeError("--cpu-shield and --no-cpu-shield contradict each other")
    if args.idle_poll and args.no_idle_poll:
        raise RealtimeError("--idle-poll and --no-idle-poll contradict each other")
    if simulator and (args.idle_poll or args.no_idle_poll):
        flag = "--idle-poll" if args.idle_poll else "--no-idle-poll"
        raise RealtimeError(f"{flag} is the controller's (run, demo): it polls the CPUs it may use")
    if not explicit:  # the defaults, with --idle-poll / --no-idle-poll / --no-cpu-shield changing them
        default = RealtimeOptions.default()
        if args.no_cpu_shield:
            default = dataclasses.replace(default, shield=False)
        if args.idle_poll or args.no_idle_poll:  # the pollers, or nothing, in place of the default remedy
            default = dataclasses.replace(default, idle_poll=args.idle_poll, cpu_latency_us=None)
        return default.for_simulator() if simulator else default
    return RealtimeOptions(
        priority=args.rt_priority,
        cpus=parse_cpus(args.cpu) if args.cpu is not None else (),  # --cpu '': refused, not ignored
        lock_memory=args.lock_memory,
        cpu_latency_us=args.cpu_latency_us,
        shield=args.cpu_shield and not simulator,
        idle_poll=args.idle_poll,
        required=not args.rt_best_effort,
    )


def _overrides(args: argparse.Namespace) -> list[str]:
    sets = list(args.set)
    if args.rate is not None:
        sets.append(f"loop.rate_hz={args.rate}")
    task = getattr(args, "task", None)
    if task:
        sets.insert(0, f'task.kind="{task}"')
    if getattr(args, "robot", None):
        sets.insert(0, f'robot.kind="{args.robot}"')
    if getattr(args, "inject", None):
        sets.append("sim.faults=[" + ", ".join(f'"{f}"' for f in args.inject) + "]")
    if getattr(args, "fd", False):  # the configuration says CAN FD too: the bus load is planned for it
        sets.append("bus.fd=true")
    return sets + monitoring_overrides(args) + _live_overrides(args)


def _config_path(args: argparse.Namespace) -> str | None:
    """--config, else the shipped configuration of --robot (None: the default cheope.toml)."""
    if args.config or not getattr(args, "robot", None):
        config: str | None = args.config
        return config
    shipped = robot_entry(args.robot).config_file
    return str(shipped) if shipped is not None else None


def _config(args: argparse.Namespace) -> Config:
    return load_config(_config_path(args), dict(parse_override(s) for s in _overrides(args)))


def _spec(args: argparse.Namespace, cfg: Config, default_port: int | None = None) -> BusSpec:
    """The bus of the options, else the configuration's (commands without bus options: its alone)."""
    # 0 is a value (refused by parse_bus_spec), not "not given"
    port = next(p for p in (getattr(args, "udp_port", None), default_port, cfg.bus.udp_port) if p is not None)
    return parse_bus_spec(
        getattr(args, "bus", None) or cfg.bus.can, fd=getattr(args, "fd", False) or cfg.bus.fd, udp_port=port
    )


def _longest_cycle_line(summary: dict[str, Any]) -> str:
    """Where the longest cycle's time went (wake-up to the end of its work), and the loop's collections."""
    c, g = summary.get("longest_cycle_us") or {}, summary["garbage_collections"]
    parts = ", ".join(
        f"{name} {c[key]:.0f}"
        for name, key in (
            ("woke late", "wake_error"),
            ("send", "send"),
            ("window", "window"),
            ("collect past window", "collect_over"),
            ("inputs", "inputs"),
            ("step", "step"),
            ("after step", "after_step"),
            ("observers", "observers"),
            ("gc", "gc"),
        )
    )
    usage = (
        f"; awake {c['span'] - c['window']:.0f} us (all but the window's wait), {c['on_cpu']:.0f} on its"
        f" CPU, {c['waits']} wait(s) (the window's sleep among them), {c['preemptions']} preemption(s),"
        f" {c['page_faults']} page fault(s)"
        if "on_cpu" in c  # read over a bus, not in simulated time (controller/shell/thread_usage.py)
        else ""
    )
    head = (
        f"longest cycle       {c['span']:.0f} us (cycle {c['cycle']}: {parts} us{usage}); "
        if c
        else "longest cycle       -; "
    )
    return head + f"{g['count']} collection(s) between cycles, max {g['max_us']:.0f} us"


def _print_summary(summary: dict[str, Any], as_json: bool) -> None:
    if as_json:
        print(strict_json(summary))
        return
    pe, te = summary["period_error_us"], summary["tracking_error_m"]
    lines = [
        f"final mode          {summary['final_mode']}"
        + (f" ({summary['fault_reason']})" if summary["fault_reason"] else ""),
        f"bus                 {summary['bus']}, planned load {summary['bus_load_percent']:.1f} %",
        (
            f"loop rate           {summary['achieved_rate_hz']:.2f} Hz achieved of {summary['nominal_rate_hz']:.0f} Hz, "
            f"{summary['cycles']} cycles"
        ),
        f"period error        p50 {pe['p50']:.0f} us, p99 {pe['p99']:.0f} us, max {pe['max']:.0f} us",
        (
            f"observers           p99 {summary['observers_us']['p99']:.0f} us, "
            f"max {summary['observers_us']['max']:.0f} us (recorder, publisher: they must only hand off)"
        ),
        f"late cycles         {summary['late_cycles']} (overruns {summary['overruns']})",
        _longest_cycle_line(summary),
        f"real-time           {summary.get('realtime', 'none')}",
        f"missing frames      drives {summary['missing_frames']['drive']}, sensor {summary['missing_frames']['sensor']}",
    ]
    if te["rms"] is not None:
        lines.append(
            f"tracking error      RMS {te['rms'] * 1e6:.1f} um, max {te['max'] * 1e6:.1f} um "
            f"({te['samples']} samples)"
        )
    contour = summary.get("contour")
    if contour:
        lines.append(
            "contour tracking    lap  speed cmd/achieved [mm/s]  force error RMS/max [N]  "
            "true error RMS/max [N]  contact losses"
        )
        for lap in contour["laps"]:
            cmd = lap["speed_commanded_m_s"]
            true_rms, true_max = lap.get("true_force_error_rms_n"), lap.get("true_force_error_max_n")
            truth = f"{true_rms:>6.2f} / {true_max:<6.2f}" if true_rms is not None else f"{'-':>6}   {'':<6}"
            lines.append(
                f"                    {lap['lap']:>3}  {cmd * 1000 if cmd else float('nan'):>8.1f} / "
                f"{lap['speed_achieved_m_s'] * 1000:<8.1f}        {lap['force_error_rms_n']:>6.2f} / "
                f"{lap['force_error_max_n']:<6.2f}          {truth}         {lap['contact_losses']}"
            )
        if contour.get("max_true_contact_force_n") is not None:  # the simulator's, whatever the sensor said
            lines.append(f"true contact force  max {contour['max_true_contact_force_n']:.1f} N")
        lines.append(
            f"force error vs normal stiffness: correlation "
            f"{contour['force_error_vs_normal_stiffness_correlation']}, RMS soft half / stiff half "
            f"{contour['force_error_rms_soft_over_stiff']}"
        )
    true_force = summary.get("simulator", {}).get("max_true_contact_force_n")
    if true_force:  # the simulator's, not the measurement: what a disturbed sensor hides
        lines.append(
            "simulator           max true contact force per controller session "
            + ", ".join(f"{f:.1f}" for f in true_force)
            + " N (in the order they ran)"
        )
    cmp = summary.get("position_control_comparison")
    if cmp and cmp.get("skipped"):
        lines.append(f"position control    not run: {cmp['skipped']}")
    elif cmp and cmp.get("laps"):
        lap = cmp["laps"][0]
        lines.append(
            f"position control    same contour at {cmp['speed_m_s'] * 1000:.0f} mm/s: force error RMS "
            f"{lap['force_error_rms_n']:.2f} N, max {lap['force_error_max_n']:.2f} N, "
            f"contact losses {lap['contact_losses']} ({cmp['final_mode']})"
        )
    if "position_error_m" in summary:  # the 3-nSPU: the reached pose against the goal
        plan, lte = summary["plan"], summary["leg_tracking_error_m"]
        lines.append(
            f"plan                {plan['status']}, {plan['iterations']} iterations, error "
            f"{plan['final_error']:.2e}, {plan['planning_time_s']} s; streamed in "
            f"{plan['streamed_duration_s']:.3f} s"
        )
        if lte["rms"] is not None:
            lines.append(f"leg tracking error  RMS {lte['rms'] * 1e6:.1f} um, max {lte['max'] * 1e6:.1f} um")
        if summary["position_error_m"] is not None:
            lines.append(
                f"reached vs goal     position {summary['position_error_m'] * 1e6:.1f} um, angle "
                f"{summary['angle_error_rad'] * 1e3:.3f} mrad (plan's own end error "
                f"{summary['plan_end_position_error_m'] * 1e6:.1f} um, "
                f"{summary['plan_end_angle_error_rad'] * 1e3:.3f} mrad)"
            )
        lines.append(f"why                 {summary['explanation']}")
    for p in summary.get("plots", []):
        lines.append(f"plot                {p}")
    print("\n".join(lines))


def demo_defaults(args: argparse.Namespace) -> argparse.Namespace:
    """Without --task, a robot's demo runs its first task (Cheope's: the paper's contour experiment);
    a --config file keeps its own."""
    if args.task is None and args.config is None:
        return argparse.Namespace(**{**vars(args), "task": robot_entry(args.robot or "cheope").tasks[0]})
    return args


def _status_observers(status: StatusDisplay | None, cfg: Config) -> tuple[CycleObserver, ...]:
    """The live status line's loop observer, when there is a terminal to show it on."""
    if status is None:
        return ()
    from controller.tasks.registry import task_entry

    count = task_entry(cfg.task.kind).laps
    return (status.observer(cfg.period_s, count(cfg.task.model()) if count is not None else None),)


def _check_duration(args: argparse.Namespace) -> None:
    if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
        raise ConfigError(
            f"--duration {args.duration:g}: must be a finite number of seconds > 0 (leave it out to run "
            "until stopped)"
            if args.command == "run"
            else f"--duration {args.duration:g}: must be a finite number of seconds > 0"
        )


def _plot_dir(args: argparse.Namespace) -> Path | None:
    """--output-dir, checked writable at start (not after the run that made the plots)."""
    return check_output_dir(args.output_dir, "--output-dir") if args.output_dir else None


@contextmanager
def _quiet_progress(status: StatusDisplay | None) -> Iterator[Callable[[str], None]]:
    """A progress line on stderr unless the live status line is on the terminal already."""
    if status is not None:
        yield lambda _text: None
        return
    with progress_line("cheope demo") as progress:
        yield progress


def _refuse_realtime_in_simulated_time(args: argparse.Namespace) -> None:
    """Given explicitly, a real-time option is required (the help says so); in simulated time there
    is no loop on the wall clock for it to act on, and it was ignored without a word."""
    from controller.realtime import RealtimeError

    given = _given(args, (*_EXPLICIT_REALTIME_FLAGS, ("idle_poll", "--idle-poll")))
    if given:
        raise RealtimeError(
            f"{', '.join(given)}: --simulated-time runs the loop on a simulated clock, with nothing "
            "to schedule, pin or lock; drop them, or run the demo over the bus (without --simulated-time)"
        )
    # The same for what only a run over the bus has: its bus, its recording's writer (the live views),
    # its Zenoh session. They were taken and ignored without a word (an outside tester, 2026-12-06).
    elsewhere = [
        flag for name, flag in _OVER_THE_BUS_FLAGS if getattr(args, name, None) not in (None, False, [])
    ]
    if elsewhere:
        raise ConfigError(
            f"{', '.join(elsewhere)}: --simulated-time runs the devices in this process, with no bus, "
            "no recording and no remote monitoring for them to act on; drop them, or run the demo over "
            "the bus (without --simulated-time)"
        )


def cmd_demo(args: argparse.Namespace) -> int:
    from controller.shell.demo import random_udp_port, run_demo

    _check_duration(args)
    plot = _plot_dir(args)
    args = demo_defaults(args)  # also for the simulator's overrides: the disk is there for the contour
    cfg = _config(args)
    if args.simulated_time:
        from controller.experiments import experiment_for
        from controller.shell.demo import run_simulated_time
        from controller.shell.simulated_rig import stopped_by

        _refuse_realtime_in_simulated_time(args)

        # the task's experiment in simulated time where it has one (the contour's laps), else the task
        experiment = experiment_for(cfg.task.kind)
        run = experiment.simulated_time if experiment and experiment.simulated_time else run_simulated_time
        # SIGTERM, SIGINT and SIGHUP stop the run as over a bus (below), and its summary is printed;
        # they ended the process without one (SIGINT: "interrupted"). Routed before the progress
        # line's first word, which tells a watcher (tests/integration/test_demo_stop_signals.py) they are.
        with stop_event_while() as stop, stopped_by(stop), progress_line("cheope demo") as progress:
            progress(f"{cfg.robot.kind}, task {cfg.task.kind}, in simulated time")
            summary = run(cfg, args.duration, plot)
        print(strict_json(summary) if args.json else strict_json(summary, indent=1))
        say_run_notes(summary, "cheope demo")
        return 0 if summary["final_mode"] == "DONE" else 1
    spec = _spec(args, cfg, default_port=random_udp_port())
    with live_status(status_wanted(args.json, sys.stdout)) as status, _quiet_progress(status) as progress:
        # the terminal's status line shows the run; without it (--json, output to a file) the
        # elapsed time goes to stderr, so that the simulator's start and the laps are not silence
        progress(f"simulator and controller on {spec}, task {cfg.task.kind}")
        summary = run_demo(
            cfg,
            spec,
            _config_path(args),
            _overrides(args),
            args.duration,
            stop_event_on_signals(),
            plot,
            _realtime(args),
            _status_observers(status, cfg),
        )
    _print_summary(summary, args.json)
    say_run_notes(summary, "cheope demo")
    return run_exit_code(summary)  # as `cheope run`: a lost recording is 3 (it was 0 for a demo)


def cmd_run(args: argparse.Namespace) -> int:
    from controller.shell.service import run_controller
    from controller.shell.stop_signals import install_stop_signals

    _check_duration(args)
    cfg = _config(args)
    signals = install_stop_signals()
    with live_status(status_wanted(args.json, sys.stdout)) as status:
        summary = run_controller(
            cfg,
            _spec(args, cfg),
            args.duration,
            signals.stop,
            realtime=_realtime(args),
            quick_stop_event=signals.quick_stop,
            observers=_status_observers(status, cfg),
        )
    _print_summary(summary, args.json)
    say_run_notes(summary, "cheope run")
    return run_exit_code(summary)


EXIT_DONE, EXIT_FAULT, EXIT_REFUSED, EXIT_RECORDING_LOST = 0, 1, 2, 3
RUN_EXIT_CODES = """exit status: 0 the run ended in DONE (task finished, or stopped by SIGTERM/SIGINT/SIGHUP, cheope stop or
--duration: braked, drives disabled); 1 it ended in FAULT (a fault, a quick stop after a second
signal, or a stop that did not reach DONE within loop.stop_timeout_s); 2 refused at start (usage,
configuration, bus load, workspace, real-time permissions, the bus or the devices); 3 DONE, but the
recording was lost (see recording.on_failure)"""


def say_run_notes(summary: dict[str, Any], command: str) -> None:
    """What a finished run's summary says that its final mode does not, on stderr (each below says
    nothing where its part of the summary is absent)."""
    say_if_unfinished(summary, command)
    say_if_held_up_before_the_fault(summary, command)
    say_if_the_simulator_died(summary, command)
    say_if_plots_failed(summary, command)
    say_if_faults_injected_nothing(summary, command)
    say_if_the_shield_guardian_failed(summary, command)
    say_if_realtime_tasks_shared_the_loops_cpu(summary, command)
    say_if_the_controller_was_traced(summary, command)
    say_if_laps_ran_slow(summary, command)


def say_if_unfinished(summary: dict[str, Any], command: str) -> None:
    """DONE is also a run stopped before its task's end (exit 0, RUN_EXIT_CODES): said on stderr, so
    that "DONE" after --duration 15 is not read as the experiment done (an outside tester's)."""
    if summary.get("final_mode") == "DONE" and summary.get("task_finished") is False:
        recording = summary.get("recording") or {}
        why = (
            f'the recording failed and recording.on_failure = "stop": {recording["error"]}'
            if recording.get("error") and recording.get("on_failure") == "stop"
            else "--duration, a signal or cheope stop"
        )
        print(f"{command}: note: the task did not finish: the run was stopped first ({why})", file=sys.stderr)


def say_if_held_up_before_the_fault(summary: dict[str, Any], command: str) -> None:
    """A fault that followed the loop's own hold-up (controller/shell/run_summary.py) is said on stderr."""
    if summary.get("final_mode") == "FAULT" and summary.get("fault_after_holdup"):
        print(f"{command}: note: {summary['fault_after_holdup']}", file=sys.stderr)


def say_if_the_simulator_died(summary: dict[str, Any], command: str) -> None:
    """A demo's simulator that ended before the demo stopped it is said on stderr: the fault that
    follows names the drives' silence, which was the simulator's (an outside tester's kill -9)."""
    simulator = summary.get("simulator")
    if isinstance(simulator, dict) and simulator.get("ended_early"):
        print(
            f"{command}: note: the simulator ended during the run ({simulator['ended_early']}): "
            "the simulated drives and sensor went silent with it",
            file=sys.stderr,
        )


def say_if_plots_failed(summary: dict[str, Any], command: str) -> None:
    """A plot that could not be written (a full disk) is said on stderr; the summary, printed, has it too."""
    if summary.get("plots_error"):
        print(f"{command}: warning: {summary['plots_error']}", file=sys.stderr)


def say_if_faults_injected_nothing(summary: dict[str, Any], command: str) -> None:
    """Injected faults that injected nothing are said on stderr: those whose start came after the
    run's end (``--inject force=100@200`` in a 70-s demo passed silently before), and those active
    at no SYNC (``FaultSchedule.missed``)."""
    late = summary.get("faults_not_reached")
    if late:
        print(
            f"{command}: note: the run ended before {len(late)} injected fault(s) began, and they "
            f"injected nothing: {', '.join(late)}",
            file=sys.stderr,
        )
    missed = summary.get("faults_missed")
    if missed:
        print(
            f"{command}: note: {len(missed)} injected fault(s) were active at no SYNC (no SYNC fell in "
            "their window, or no device asked for them then), and they injected nothing: "
            f"{', '.join(missed)}",
            file=sys.stderr,
        )


SLOW_LAP_FRACTION = 0.75  # a lap below this share of its commanded speed is said (say_if_laps_ran_slow)


def say_if_laps_ran_slow(summary: dict[str, Any], command: str) -> None:
    """Contour laps that ran well below their commanded speed are said on stderr. The law slows a
    lap on purpose (the force out of its band, a bump the first lap found), and the stall rule
    faults only below a quarter of it: a part with five times the estimated friction ran every lap
    at 10 mm/s of 20, 40 and 60 commanded and ended DONE, exit 0, without a word (an outside
    tester's). The run stays DONE: the laps were tracked, slower than asked."""
    contour = summary.get("contour") or {}
    slow = [
        lap
        for lap in contour.get("laps") or ()
        if lap.get("speed_commanded_m_s")
        and lap.get("speed_achieved_m_s") is not None
        and lap["speed_achieved_m_s"] < SLOW_LAP_FRACTION * lap["speed_commanded_m_s"]
    ]
    if slow:
        laps = ", ".join(
            f"{lap['lap']} at {lap['speed_achieved_m_s'] * 1000:.1f} of {lap['speed_commanded_m_s'] * 1000:.0f}"
            for lap in slow
        )
        print(
            f"{command}: note: lap(s) {laps} mm/s ran below {SLOW_LAP_FRACTION:.0%} of their commanded "
            "speed: the law slowed them to keep the force in its band (the summary's laps give their force "
            "errors); the experiment did not run as commanded",
            file=sys.stderr,
        )


def say_if_the_shield_guardian_failed(summary: dict[str, Any], command: str) -> None:
    """A CPU shield whose guardian did not restore (killed under the run, or stopped) is said on
    stderr; its tasks were given back at the end from its state file (controller/shell/cpu_shield.py)."""
    shield = summary.get("cpu_shield")
    if isinstance(shield, dict) and shield.get("guardian_failed"):
        print(
            f"{command}: note: the CPU shield's guardian did not restore the machine "
            f"({shield['guardian_failed']}); tasks given back from its state file at the end: "
            f"{shield.get('tasks_restored')}",
            file=sys.stderr,
        )


def _shield_watch(summary: dict[str, Any], key: str) -> list[dict[str, Any]]:
    """What the CPU shield's guardian saw of ``key`` (``realtime_neighbours``, ``tracers``): none
    without a shield, or when it saw nothing."""
    shield = summary.get("cpu_shield")
    seen = shield.get(key) if isinstance(shield, dict) else None
    return seen if isinstance(seen, list) else []


def say_if_realtime_tasks_shared_the_loops_cpu(summary: dict[str, Any], command: str) -> None:
    """Real-time tasks that used CPU time on the loop's CPU during the run are said on stderr: the
    kernel throttles them with the loop (controller/shell/realtime_neighbours.py)."""
    neighbours = _shield_watch(summary, "realtime_neighbours")
    if not neighbours:
        return
    named = "; ".join(
        f"{n['name']} (pid {n['pid']}, {n['policy']} {n['priority']}) used {n['cpu_s']:g} s of CPU "
        f"between {n['seen_s'][0]:g} and {n['seen_s'][1]:g} s after the shield rose"
        for n in neighbours
    )
    print(
        f"{command}: note: real-time task(s) shared the loop's CPU: {named}. The kernel throttles a CPU's "
        "real-time tasks together, the loop with them (summary.realtime says the setting)",
        file=sys.stderr,
    )


def say_if_the_controller_was_traced(summary: dict[str, Any], command: str) -> None:
    """Processes that traced the controller during the run are said on stderr: the loop waits for
    them (controller/shell/tracer_watch.py)."""
    tracers = _shield_watch(summary, "tracers")
    if not tracers:
        return
    named = "; ".join(
        f"{t['name']} (pid {t['pid']}) attached in {t['looks']} look(s) a second apart between "
        f"{t['seen_s'][0]:g} and {t['seen_s'][1]:g} s after the shield rose"
        for t in tracers
    )
    print(
        f"{command}: note: the controller was traced: {named}. A traced loop waits for its tracer at "
        "every system call or sample (py-spy: --nonblocking does not stop the process)",
        file=sys.stderr,
    )


def run_exit_code(summary: dict[str, Any]) -> int:
    """``RUN_EXIT_CODES`` for a finished run's summary."""
    if summary["final_mode"] != "DONE":
        return EXIT_FAULT
    recording = summary.get("recording")
    if isinstance(recording, dict) and recording.get("error"):
        return EXIT_RECORDING_LOST
    return EXIT_DONE


def cmd_sim(args: argparse.Namespace) -> int:
    from controller.child_process import end_with_parent, parent_is_gone
    from sim_backend.process import serve

    stop = stop_event_on_signals()
    end_with_parent()  # a demo's simulator: its demo's end, even by SIGKILL, stops it (a SIGTERM)
    cfg = _config(args)
    try:
        serve(
            cfg,
            _spec(args, cfg),
            stop,
            (lambda line: print(json.dumps({"line": line}), flush=True))
            if args.json
            else (lambda line: print(line, flush=True)),
            _realtime(args, simulator=True),
            true_force_tap=args.true_force_tap,
        )
    finally:
        if args.true_force_tap and parent_is_gone():
            # its reader, the demo, was killed: nobody else removes the block (and the last line
            # to the demo's closed pipe may have raised on the way here)
            Path(args.true_force_tap).unlink(missing_ok=True)
    return 0


def cmd_bus_load(args: argparse.Namespace) -> int:
    from controller.shell.service import prepare

    cfg = _config(args)
    # everything `cheope run` refuses before opening a bus refuses here too (one line, exit 2);
    # only the load against its limit is reported as a table (exit 1 when over)
    load = prepare(cfg, _spec(args, cfg), enforce_load_limit=False).bus_load
    ok = load.percent <= cfg.bus.max_load_percent
    if args.json:
        print(
            strict_json(
                {
                    "load_percent": load.percent,
                    "limit_percent": cfg.bus.max_load_percent,
                    "ok": ok,
                    "frames_per_second": load.frames_per_second,
                    "fd": cfg.bus.fd,
                    "frames": [f.__dict__ for f in load.frames],
                }
            )
        )
    else:
        kind = (
            f"CAN FD {cfg.bus.bitrate_bit_s / 1e6:g}/{cfg.bus.data_bitrate_bit_s / 1e6:g} Mbit/s"
            if cfg.bus.fd
            else f"classical CAN {cfg.bus.bitrate_bit_s / 1e6:g} Mbit/s"
        )
        print(f"{kind} at {cfg.loop.rate_hz:g} Hz, worst-case bit stuffing")
        for f in load.frames:
            print(f"  {f.name:<16} {f.n_bytes:>2} bytes  {f.rate_hz:>8.1f} frames/s")
        print(
            f"load {load.percent:.1f} % (limit {cfg.bus.max_load_percent:g} %): {'OK' if ok else 'REFUSED'}"
        )
    return 0 if ok else 1


def cmd_nodes(args: argparse.Namespace) -> int:
    from drivers.bus import open_bus
    from drivers.bus_presence import check_no_other_master
    from drivers.node_scan import log_quietly, lss_fast_scan, nodes_as_json, nodes_table, scan_nodes
    from drivers.node_setup import DRIVE_EDS, SENSOR_EDS, device_description_path

    cfg = _config(args)
    if not args.verbose:
        log_quietly()
    eds = (
        device_description_path(cfg.actuators.eds_file, DRIVE_EDS),
        device_description_path(cfg.sensor.eds_file, SENSOR_EDS),
    )
    for node_id in args.lss_assign:
        if not 1 <= node_id <= 127:
            raise ConfigError(f"--lss-assign {node_id}: a node id is 1..127")
    spec = _spec(args, cfg)
    with open_bus(spec) as bus:
        # a scan is a master's SDO requests: beside a running controller they faulted it mid-contour
        # ("a second master") and read back its answers as a wrong table, exit 0 (an outside tester's)
        check_no_other_master(bus, spec.place, cfg.loop.controller_node_id, cfg.bus.presence_listen_s)
        lss = lss_fast_scan(bus, tuple(args.lss_assign)) if args.lss_scan or args.lss_assign else []
        nodes = scan_nodes(bus, eds, sdo_timeout_s=cfg.loop.sdo_timeout_s)
    if args.json:
        print(strict_json({"lss": [n.__dict__ for n in lss], "nodes": nodes_as_json(nodes)}, indent=1))
        return 0
    for n in lss:
        address = (
            f"vendor 0x{n.vendor_id:08X} product 0x{n.product_code:08X} revision 0x{n.revision:08X} "
            f"serial 0x{n.serial:08X}"
        )
        print(f"LSS: a node without node id: {address}" + (f" -> node id {n.assigned}" if n.assigned else ""))
    if (args.lss_scan or args.lss_assign) and not lss:
        print("LSS: no node without a node id answered the fast scan")
    print(nodes_table(nodes))
    return 0


def cmd_bench(args: argparse.Namespace) -> int:
    from controller.tools.bench import run_bench_command

    return run_bench_command(args, _realtime(args))


def cmd_soak(args: argparse.Namespace) -> int:
    from controller.tools.bench.soak import run_soak_command

    return run_soak_command(args, ["--no-realtime"] if args.no_realtime else [])


def cmd_analyze(args: argparse.Namespace) -> int:
    cfg = _config(args)
    from controller.plugins import ANALYSES

    analyze = ANALYSES.get(cfg.robot.kind)
    if analyze is None:
        raise ConfigError(f"robot.kind = {cfg.robot.kind!r} has no analysis plots")
    out = check_output_dir(args.output_dir, "--output-dir")
    with progress_line("cheope analyze") as progress:
        progress(f"{cfg.robot.kind}: workspace, margins, ellipsoids -> {args.output_dir}")
        report = analyze(cfg, out)
    print(strict_json(report) if args.json else "\n".join(f"{k}: {v}" for k, v in report.items()))
    return 0


def _plugin_command(name: str, command: Command) -> Callable[[argparse.Namespace], int]:
    """A plug-in's command (controller/commands.py): its configuration loaded, its robots checked."""

    def run(args: argparse.Namespace) -> int:
        if command.robots and not args.robot and not args.config:
            args.robot = command.robots[0]
        cfg = _config(args)
        if command.robots and cfg.robot.kind not in command.robots:
            raise ConfigError(
                f"cheope {name} runs on robot.kind {' or '.join(map(repr, command.robots))}; "
                f"robot.kind is {cfg.robot.kind!r}"
            )
        return command.run(args, cfg)

    return run


def _add_plugin_commands(sub: Any) -> None:
    for name, command in plugin_commands().items():
        # a command's help is plain text ("95 % of"); argparse reads help as a %-format string
        p = sub.add_parser(name, help=command.help.replace("%", "%%"))
        _common(p, bus=False, robots=command.robots or None)
        command.add_arguments(p)
        p.set_defaults(func=_plugin_command(name, command))


def cmd_faults(args: argparse.Namespace) -> int:
    for flag in ("contour_scan", "contour_shapes", "contour_stress"):  # the spelling before: cheope contour-*
        if getattr(args, flag):
            return plugin_commands()[flag.replace("_", "-")].run(args, _config(args))
    from controller.tools.fault_scenarios import format_table, run_all

    cfg = _config(args)
    keep = check_output_dir(args.output_dir, "--output-dir") if args.output_dir else None
    with progress_line("cheope faults") as progress:
        rows = run_all(cfg, keep, tuple(args.only or ()), progress)
    print(strict_json(rows) if args.json else format_table(rows))
    return 0 if all(r["as_expected"] and r["recording_complete"] for r in rows) else 1


class OneLineParser(argparse.ArgumentParser):
    """Wrong options get one line naming the problem (argparse's default prints the usage block)."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _verbose_on_every_command(parser: argparse.ArgumentParser) -> None:
    """``-v`` after the subcommand too (``cheope run -v``, ``cheope logs info -v FILE``); SUPPRESS keeps a
    ``-v`` given before the subcommand from being reset to False by the subcommand's default."""
    for action in parser._actions:
        if not isinstance(action, argparse._SubParsersAction):
            continue
        for sub in {id(p): p for p in action.choices.values()}.values():
            if "-v" not in sub._option_string_actions:
                sub.add_argument(
                    "-v",
                    "--verbose",
                    action="store_true",
                    default=argparse.SUPPRESS,
                    help="log to stderr (also before the command)",
                )
            _verbose_on_every_command(sub)


def _installed_version() -> str:
    from importlib import metadata

    try:
        return metadata.version("cheope-controller")
    except metadata.PackageNotFoundError:  # run from a source tree that was not installed
        return "(not installed)"


def build_parser() -> argparse.ArgumentParser:
    ap = OneLineParser(prog="cheope", description="Controller service for parallel-kinematic robots")
    ap.add_argument("-v", "--verbose", action="store_true", help="log to stderr")
    ap.add_argument("--version", action="version", version=f"cheope {_installed_version()}")
    sub = ap.add_subparsers(dest="command", required=True)
    p = sub.add_parser("demo", help="simulator process + controller + the configured task, then a summary")
    _common(p)
    add_controller_options(p)
    p.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    p.add_argument(
        "--duration", type=float, default=600.0, metavar="SECONDS", help="stop after this long (default 600)"
    )
    p.add_argument("--max-duration", dest="duration", type=float, help=argparse.SUPPRESS)  # before --duration
    p.add_argument(
        "--task",
        choices=task_kinds(),
        help="the task (default: the robot's first, Cheope's contour, or the --config file's): contour runs the "
        "paper's force-controlled contour tracking, then the same contour under position control; "
        "path: once around the configured circle; planned: the 3-nSPU's planned motion",
    )
    p.add_argument("--output-dir", metavar="DIR", help="write the contour experiment's PNG plots here")
    p.add_argument("--plot", dest="output_dir", help=argparse.SUPPRESS)  # the spelling before --output-dir
    p.add_argument(
        "--simulated-time",
        action="store_true",
        help="with --task contour: run the laps against the in-process devices in simulated time "
        "(deterministic, no bus, no simulator process)",
    )
    _live_options(p)
    _rt_options(p)  # the simulator gets the priority minus 10 and the same memory locking
    p.set_defaults(func=cmd_demo)
    p = sub.add_parser(
        "run",
        help="only the controller, against whatever devices are on the bus",
        description="Run the controller until its task ends or it is told to stop (SIGTERM, "
        "SIGINT, cheope stop, --duration); a second signal quick-stops the drives.",
        epilog=RUN_EXIT_CODES,
    )
    _common(p)
    add_controller_options(p)
    p.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    p.add_argument(
        "--duration",
        type=float,
        default=None,
        metavar="SECONDS",
        help="stop (through STOPPING: brake, disable the drives) after this long; default: run until stopped",
    )
    p.add_argument("--max-duration", dest="duration", type=float, help=argparse.SUPPRESS)  # before --duration
    _live_options(p)
    _rt_options(p)
    p.set_defaults(func=cmd_run)
    p = sub.add_parser("sim", help="only the simulated hardware")
    _common(p)
    p.add_argument("--json", action="store_true", help="print its READY and STOPPED lines as JSON objects")
    _rt_options(p)
    p.add_argument(
        "--true-force-tap",
        metavar="PATH",
        default="",
        help="write the true contact force of every SYNC into this memory-mapped file, made by its "
        "reader (cheope demo does: sim_backend/true_force_tap.py)",
    )
    p.set_defaults(func=cmd_sim)
    p = sub.add_parser(
        "faults", help="inject every handled fault into the simulated devices; table of reactions"
    )
    _common(p, bus=False)
    p.add_argument("--json", action="store_true", help="print the rows as one JSON array")
    p.add_argument("--only", action="append", metavar="SCENARIO", help="run only this scenario (repeatable)")
    p.add_argument("--output-dir", metavar="DIR", help="keep the scenarios' recordings in DIR")
    p.add_argument("--keep", dest="output_dir", help=argparse.SUPPRESS)  # the spelling before --output-dir
    for flag in ("--contour-scan", "--contour-shapes", "--contour-stress"):  # now cheope contour-*
        p.add_argument(flag, action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--jobs", type=job_count, default=1, help=argparse.SUPPRESS)
    p.set_defaults(func=cmd_faults)
    p = sub.add_parser(
        "nodes",
        help="scan the bus: each node's identity, NMT state, power state, error code and PDO mapping",
        description="Commissioning: every node that answers SDO (ids 1..127), described; with --lss-scan "
        "or --lss-assign, first the nodes without a node id (LSS fast scan, CiA 305). A master's "
        "traffic: not beside a running controller (it would take it for a second master).",
    )
    _common(p, robots=None)
    p.add_argument("--json", action="store_true", help="print the nodes as one JSON object")
    p.add_argument(
        "--lss-scan", action="store_true", help="find the nodes without a node id first (LSS fast scan)"
    )
    p.add_argument(
        "--lss-assign",
        type=int,
        action="append",
        default=[],
        metavar="NODE_ID",
        help="give the nodes without a node id these ids, one each in the order found (repeatable); stored",
    )
    p.set_defaults(func=cmd_nodes)
    p = sub.add_parser("bus-load", help="bus load of the configured cycle")
    _common(p, bus=False)
    p.add_argument("--json", action="store_true", help="print the load and its frames as one JSON object")
    p.set_defaults(func=cmd_bus_load)
    p = sub.add_parser("analyze", help="workspace, singularity margins and ellipsoids; writes PNG plots")
    _common(p, bus=False)
    p.add_argument("--output-dir", default="analysis", metavar="DIR", help="directory for the PNG plots")
    p.add_argument("--out", dest="output_dir", help=argparse.SUPPRESS)  # the spelling before --output-dir
    p.add_argument("--json", action="store_true", help="print the report as one JSON object")
    p.set_defaults(func=cmd_analyze)
    p = sub.add_parser(
        "bench", help="timing benchmark with the simulator: 400 Hz and 1 kHz, table, JSON, PNG"
    )
    from controller.tools.bench import add_bench_arguments

    add_bench_arguments(p)
    _rt_options(p)
    p.set_defaults(func=cmd_bench)
    p = sub.add_parser(
        "soak", help="a long run of cheope sim + cheope run: controller RSS slope, late cycles per 10 000"
    )
    from controller.tools.bench.soak import add_soak_arguments

    add_soak_arguments(p)
    p.add_argument("--no-realtime", action="store_true", help="both processes under the normal scheduler")
    p.set_defaults(func=cmd_soak)
    _add_plugin_commands(sub)  # the robots' and tasks' own commands (cheope.commands)
    add_monitoring_subcommands(sub)
    from controller.ros2.cli import add_subcommand as add_ros2_subcommand  # imports no ROS

    add_ros2_subcommand(sub)
    from logs.cli import add_commands as add_log_commands  # cheope logs info|recover, cheope replay

    add_log_commands(sub, stop_event_on_signals)
    _verbose_on_every_command(ap)
    return ap


def main(argv: list[str] | None = None) -> int:
    with listing_what_loads() as skipped:  # a broken plug-in must not take `cheope stop` with it
        parser = build_parser()
    for trouble in skipped:  # before --help too: why a robot, a task or a command is missing
        print(f"cheope: warning: {trouble}; the commands that use robots and tasks refuse", file=sys.stderr)
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.INFO if args.verbose else logging.WARNING,
        format="%(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )
    # canopen logs an SDO transfer it gives up as ERROR ("Transfer aborted by client"), before the
    # exception our set-up turns into its one line (node N did not answer...): shown with -v only
    # (canopen.sdo only: the warnings of canopen's EDS reader name what is wrong in a file)
    logging.getLogger("canopen.sdo").setLevel(logging.INFO if args.verbose else logging.CRITICAL)
    try:
        code: int = args.func(args)
        return code
    except RefusedError as err:  # WorkspaceError, PlanningError, ...: a task we refuse to run
        print(f"cheope {args.command}: refused: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # Ctrl-C in a command that has no stop of its own (a scan, a bench)
        print(f"cheope {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # the reader went (cheope plan --json | head): nothing more to say
        # Python would flush stdout again at exit and fail on the same pipe (its docs' recipe)
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except (CheopeError, can.CanError, OSError) as err:  # InputError, DeviceError (controller/errors.py)
        print(f"cheope {args.command}: error: {err}", file=sys.stderr)
        return 2
    except ValueError as err:  # a model's own argument check on a value the configuration let through
        print(f"cheope {args.command}: error: {err}", file=sys.stderr)
        return 2
