"""``cheope demo``: the simulator as a child process, the controller in this one, one task.

The simulator gets the same configuration file and overrides as the controller and a
fresh UDP port, so concurrent demos do not hear each other. It is stopped (SIGTERM, then
SIGKILL) whatever happens to the controller.
"""

from __future__ import annotations

import contextlib
import os
import random
import selectors
import signal
import subprocess
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from controller.child_process import child_environment, ending_with_parent, exit_text, python_module_command
from controller.config import Config
from controller.core.ports import CycleObserver
from controller.errors import DeviceError
from controller.experiments import experiment_for
from controller.realtime import RealtimeOptions
from controller.shell.service import prepare, run_controller
from controller.sim_config.fault_specs import refuse_in_process_only
from drivers.bus import BusSpec
from sim_backend.process import (
    CONTACT_FORCE_REPORT,
    FAULTS_MISSED_REPORT,
    FAULTS_NOT_REACHED_REPORT,
    READY_LINE,
    STOPPED_LINE,
)
from sim_backend.true_force_tap import PREFIX as TRUE_FORCE_PREFIX
from sim_backend.true_force_tap import TrueForceReader


class SimulatorStartError(DeviceError, RuntimeError):
    pass


def random_udp_port() -> int:
    return random.SystemRandom().randint(43200, 44999)


# The wait ends on the simulator's READY line; the bound only decides when to give up. In the
# vcan VM without KVM (tests/vcan/run) importing the simulator took more than 30 s once.
SIMULATOR_READY_TIMEOUT_S = 120.0


@contextmanager
def simulator_process(
    spec: BusSpec,
    config_path: str | None,
    overrides: list[str],
    ready_timeout_s: float = SIMULATOR_READY_TIMEOUT_S,
    extra_args: list[str] | tuple[str, ...] = (),
    report: dict[str, object] | None = None,
) -> Iterator[subprocess.Popen[str]]:
    """``cheope sim`` as a child process; ``extra_args`` go to its command line (real-time options).

    ``report``, when given, receives what the simulator saw when it stopped
    (``max_true_contact_force_n``: its largest true contact force in each controller session, in
    the order they ran, a session starting at each NMT start; absent if it said nothing).
    """
    cmd = python_module_command(
        "controller",
        "sim",
        "--bus",
        f"{spec.interface}:{spec.channel}",
        "--udp-port",
        str(spec.udp_port),
        *extra_args,
    )
    if spec.fd:
        cmd.append("--fd")
    if config_path:
        cmd += ["--config", config_path]
    for s in overrides:
        cmd += ["--set", s]
    proc = subprocess.Popen(
        cmd,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=child_environment(PYTHONUNBUFFERED="1", **ending_with_parent()),
        # Out of the terminal's process group: its Ctrl-C (SIGINT) and hang-up (SIGHUP) go to the
        # whole group, and the simulated drives quit before the demo had shut them down (its stop
        # ended in FAULT, "drives silent for 40 cycles"). The demo stops them after the drives
        # (stop_process), and they end with it however it ends (ending_with_parent).
        start_new_session=True,
    )
    try:
        _wait_ready(proc, ready_timeout_s)
        yield proc
    finally:
        ended = proc.poll()  # before the demo stops it: the simulated drives died under the run
        said = stop_process(proc)
        if report is not None:
            report.update(simulator_report(said))
            if ended is not None:
                report["ended_early"] = exit_text(ended)


def _wait_ready(proc: subprocess.Popen[str], timeout_s: float) -> None:
    assert proc.stdout is not None
    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if not sel.select(timeout=max(0.0, deadline - time.monotonic())):
            break
        line = proc.stdout.readline()
        if not line:
            err = proc.stderr.read() if proc.stderr else ""
            raise SimulatorStartError(f"simulator exited with code {proc.wait()}: {err.strip()[-2000:]}")
        if line.startswith(READY_LINE):
            return
    raise SimulatorStartError(f"simulator not ready within {timeout_s} s")


def stop_process(proc: subprocess.Popen[str], timeout_s: float = 5.0) -> str:
    """SIGTERM, then SIGKILL after ``timeout_s``; what it wrote to stdout since it was last read."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
    try:
        out, _ = proc.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate()
    except ValueError:  # its streams were closed already
        proc.wait()
        out = ""
    return out or ""


FAULTS_INJECTING_NOTHING = ("faults_not_reached", "faults_missed")  # the summary's keys of them


def simulator_report(stdout: str) -> dict[str, object]:
    """The simulator's last words (``sim_backend/process.py``, STOPPED_LINE): its largest true
    contact forces, the injected faults the run ended before (``faults_not_reached``) and those it
    reached that were active at no SYNC (``faults_missed``)."""
    report: dict[str, object] = {}
    for line in stdout.splitlines():
        if not line.startswith(STOPPED_LINE):
            continue
        if CONTACT_FORCE_REPORT in line:
            values = line.split(CONTACT_FORCE_REPORT, 1)[1].split()[:-1]  # the numbers, then "N"
            report["max_true_contact_force_n"] = [float(v) for v in values]
        elif FAULTS_NOT_REACHED_REPORT in line:
            report["faults_not_reached"] = line.split(FAULTS_NOT_REACHED_REPORT, 1)[1].split()
        elif FAULTS_MISSED_REPORT in line:
            report["faults_missed"] = line.split(FAULTS_MISSED_REPORT, 1)[1].split()
    return report


def simulator_realtime_args(realtime: RealtimeOptions | None) -> list[str]:
    """The demo's simulator gets the loop's options, one priority step below, on the other CPUs.

    The simulator stands in for drives that answer on their own hardware: it must not queue
    behind the controller's loop, nor the loop behind it.
    """
    return [] if realtime is None else realtime.for_simulator().cli_args()


def run_demo(
    cfg: Config,
    spec: BusSpec,
    config_path: str | None,
    overrides: list[str],
    max_duration_s: float = 600.0,
    stop_event: threading.Event | None = None,
    plot_dir: Path | None = None,
    realtime: RealtimeOptions | None = None,
    observers: tuple[CycleObserver, ...] = (),
) -> dict[str, object]:
    prepare(cfg, spec)  # what the controller would refuse, refused before the simulator starts
    refuse_in_process_only(cfg.sim.faults, "cheope demo without --simulated-time")
    simulator: dict[str, object] = {}
    # the simulator's true contact force, live (a diagnostic: the per-lap tables show it beside the measured)
    truth = TrueForceReader(f"{TRUE_FORCE_PREFIX}{os.getpid()}-{spec.udp_port}")
    sim_args = [*simulator_realtime_args(realtime), "--true-force-tap", truth.name]
    with (
        contextlib.closing(truth),
        simulator_process(spec, config_path, overrides, extra_args=sim_args, report=simulator),
    ):
        experiment = experiment_for(cfg.task.kind)
        if experiment is not None:  # the task's own experiment (the contour's: laps, comparison, plots)
            summary = experiment.over_bus(
                cfg, spec, plot_dir, max_duration_s, stop_event, realtime, observers, true_force=truth.read
            )
        else:
            summary = run_controller(
                cfg,
                spec,
                max_duration_s=max_duration_s,
                stop_event=stop_event,
                realtime=realtime,
                observers=observers,
            )
    # what only the simulator knows: the true contact force (the controller sees the measurement),
    # and the faults that injected nothing (at the top, as in simulated time: say_run_notes says them)
    idle = {key: specs for key in FAULTS_INJECTING_NOTHING if (specs := simulator.pop(key, None))}
    return {**summary, "simulator": simulator, **idle}


def run_simulated_time(
    cfg: Config, max_duration_s: float = 600.0, plot_dir: Path | None = None
) -> dict[str, object]:
    """Any task against the in-process devices in simulated time (``cheope demo --simulated-time``
    for a task without an experiment of its own: the path, a plug-in robot's first run).

    The in-process rig (controller/shell/simulated_rig.py): deterministic, independent of the
    machine's load. ``plot_dir`` is unused: only an experiment plots.
    """
    from controller.core.cycle_data import Severity
    from controller.shell.run_summary import RunRecorder, simulated_time_summary
    from controller.shell.simulated_rig import SimulatedRig

    rig = SimulatedRig(cfg)
    recorder = RunRecorder()
    final, stats = rig.run((recorder,), max_duration_s)
    te = recorder.tracking
    return {
        **simulated_time_summary(final, recorder, stats, rig.exchange.counters, rig.exchange.faults),
        "simulated_duration_s": round(stats.cycles * cfg.period_s, 6),
        "tracking_error_m": {"rms": te.rms, "max": te.maximum, "samples": te.count},
        "final_tcp_m": [round(float(x), 6) for x in rig.exchange.plant.tcp_m],
        "events": [
            f"{t:.4f}s {e.severity.name}: {e.message}"
            for t, e in recorder.events
            if e.severity >= Severity.INFO
        ],
    }
