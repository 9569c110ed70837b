"""``cheope faults``: every fault the controller handles, injected into the simulated devices.

Each scenario runs the path task against the simulated drives and sensor in simulated time
(``sim_backend.loopback``, the same device models as the simulator process, with the fault
schedule of ``sim_backend.fault_injection``), records the session to MCAP, and reports the
reaction expected and observed, the time from the fault to the safe state, and whether the
recording is complete. Simulated time makes the table reproducible; the separate-process
path is covered by the tests (tests/test_faults.py) and by ``cheope demo --inject ...``.

Safe state: every drive at rest (zero velocity) and out of OPERATION ENABLED (quick stop
active, switched off, or faulted), or, for a warning, the task finishing normally.
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import msgspec

from controller.config import Config, ConfigError, load_config
from controller.core.cia402 import PowerState
from controller.core.controller_state import ControllerState, Mode
from controller.core.cycle_data import CycleInputs, CycleOutputs, Event, Severity
from controller.core.ports import CycleTiming
from controller.shell.simulated_rig import SimulatedRig
from sim_backend.loopback import LoopbackExchange

FAULT_AT_S = 2.0  # the task is running then (it starts at about 0.2 s)


@dataclass(frozen=True)
class Scenario:
    name: str
    fault: str  # sim_backend/fault_injection.py syntax
    expected: str  # "fault", "warn" (event, task goes on) or "ignore" (counted, task goes on)
    reaction: str  # what a user should see, in words


SCENARIOS: tuple[Scenario, ...] = (
    Scenario(
        "drive TPDO missing",
        f"drop:2@{FAULT_AT_S}",
        "fault",
        "fault after loop.max_missing_s; quick stop",
    ),
    Scenario("drive TPDO late", f"delay:2=0.01@{FAULT_AT_S}", "fault", "late = missing: fault, quick stop"),
    Scenario(
        "malformed TPDO, one",
        f"malformed:2@{FAULT_AT_S}+0.0025",  # one cycle at 400 Hz: it fires at one SYNC
        "warn",
        "frame rejected, counted and reported with its node (safety.on_rejected_frames = warn: one event "
        "when a burst starts, one with its count when it ends); one missing cycle is ignored, the task goes on",
    ),
    Scenario(
        "sensor counter frozen",
        f"freeze@{FAULT_AT_S}",
        "fault",
        "stale after safety.sensor_stale_s: the contact guard's protective stop (back off along the "
        "drives' effort, or brake in place without a force), then fault",
    ),
    Scenario(
        "sensor saturated",
        f"saturate@{FAULT_AT_S}",
        "fault",
        "safety.on_sensor_saturated = fault: the contact guard's protective stop, then fault",
    ),
    Scenario(
        "drive fault + EMCY",
        f"drive_fault:3@{FAULT_AT_S}",
        "fault",
        "fault at once; quick stop of the others",
    ),
    Scenario(
        "drive heartbeat lost", f"heartbeat:1@{FAULT_AT_S}", "fault", "safety.on_heartbeat_lost = fault"
    ),
    Scenario(
        "CAN error frames", f"error_frames@{FAULT_AT_S}+0.05", "warn", "warning event once; the task goes on"
    ),
    Scenario("CAN bus-off", f"bus_off@{FAULT_AT_S}", "fault", "fault at once; quick stop"),
    Scenario(
        "transmit queue full",
        f"tx_full@{FAULT_AT_S}+0.5",
        "fault",
        "send errors counted, drives silent: fault; drives quick-stop on their SYNC watchdog",
    ),
    Scenario(
        "contact force where none is expected",
        f"force=100@{FAULT_AT_S}",
        "fault",
        "the contact guard (safety.contact.free_space_force_n): back off 5 mm along the force, then fault",
    ),
    Scenario(
        "loop overrunning",
        f"stall=0.0015@{FAULT_AT_S}",
        "fault",
        "fault after safety.max_consecutive_late_s of late cycles",
    ),
    # Someone or something on the bus that lies (drivers/cyclic_exchange.py watches the whole bus).
    Scenario(
        "drive position jump",
        f"jump:2=0.05@{FAULT_AT_S}",
        "fault",
        "a step beyond max_velocity x time + safety.max_position_jump_m: fault at once",
    ),
    Scenario(
        "following error (axis blocked)",
        f"block:2@{FAULT_AT_S}",
        "fault",
        "the drive's own window (0x6065/0x6066): drive FAULT, EMCY 0x8611",
    ),
    Scenario(
        "drive reboot (boot-up)",
        f"reboot:2@{FAULT_AT_S}",
        "fault",
        "its boot-up heartbeat: fault at once, the restarted drive named",
    ),
    Scenario(
        "NMT stop by someone else",
        f"nmt_stop:2@{FAULT_AT_S}",
        "fault",
        "safety.on_foreign_nmt = fault: the foreign NMT command named; the drive's 0x6007 quick-stops it",
    ),
    Scenario(
        "NMT pre-operational by someone else",
        f"nmt_preop:2@{FAULT_AT_S}",
        "fault",
        "safety.on_foreign_nmt = fault, command and node named; quick stop by SDO as well to the drive "
        "that no longer processes RPDOs",
    ),
    Scenario(
        "NMT reset by someone else",
        f"nmt_reset:2@{FAULT_AT_S}+0.0025",  # one cycle at 400 Hz: it fires at one SYNC
        "fault",
        "safety.on_foreign_nmt = fault, command and node named; the drive restarts disabled",
    ),
    Scenario("second SYNC producer", f"foreign_sync@{FAULT_AT_S}", "fault", "safety.on_foreign_sync = fault"),
    Scenario(
        "unknown node on the bus",
        f"unknown_node:42@{FAULT_AT_S}",
        "warn",
        "safety.on_unknown_node = warn: one event, counted, the task goes on",
    ),
    Scenario(
        "frame flood",
        f"flood@{FAULT_AT_S}",
        "fault",
        "more than safety.max_foreign_frames_per_cycle foreign frames in a cycle: a flood, named by COB-ID",
    ),
    Scenario(
        "spoofed sensor frames",
        f"spoof_sensor=30@{FAULT_AT_S}",
        "fault",
        "a second force frame before the true one, its counter out of step: neither is used; "
        "safety.on_duplicate_frames = fault",
    ),
    # A rogue sender's frame on a drive's COB-ID, before the true answer: never used.
    Scenario(
        "rogue TPDO, position jump",
        f"rogue_tpdo:2=0.05@{FAULT_AT_S}",
        "fault",
        "two candidates in one answer window: neither is used; safety.on_duplicate_frames = fault",
    ),
    Scenario(
        "rogue TPDO, small offset",
        f"rogue_tpdo:2=0.0025@{FAULT_AT_S}",
        "fault",
        "2.5 mm off, within the drive's physics: two candidates all the same; safety.on_duplicate_frames = fault",
    ),
    Scenario(
        "rogue TPDO, wrong length",
        f"rogue_short:2@{FAULT_AT_S}",
        "fault",
        "a candidate that does not decode: rejected, named, and the true one not used either",
    ),
    Scenario(
        "rogue EMCY, wrong length",
        f"rogue_emcy:2@{FAULT_AT_S}+0.0025",  # one cycle at 400 Hz: it fires at one SYNC
        "warn",
        "rejected, counted and reported with its node (safety.on_rejected_frames = warn), the task goes on",
    ),
)


@dataclass
class _Watch:
    """Observer: when the reaction came and when the drives reached the safe state."""

    exchange: LoopbackExchange
    fault_at_s: float
    reaction_s: float | None = None
    reaction: str = ""
    safe_s: float | None = None

    def on_cycle(
        self,
        cycle: int,
        t: float,
        inputs: CycleInputs,
        state: ControllerState,
        outputs: CycleOutputs,
        events: tuple[Event, ...],
        timing: CycleTiming,
    ) -> None:
        if t < self.fault_at_s:
            return
        for e in events:
            if self.reaction_s is None and e.severity >= Severity.WARNING:
                self.reaction_s, self.reaction = t, e.message
        if self.safe_s is None and state.mode in (Mode.FAULT, Mode.DONE):
            drives = self.exchange.drives
            if all(d.velocity == 0.0 and d.power != PowerState.OPERATION_ENABLED for d in drives):
                self.safe_s = t


def run_scenario(base: Config, sc: Scenario, directory: Path) -> dict[str, object]:
    from logs.reader import read_info
    from logs.recorder import SessionRecorder

    cfg = msgspec.structs.replace(
        base,
        sim=msgspec.structs.replace(base.sim, faults=(sc.fault,)),
        recording=msgspec.structs.replace(base.recording, enabled=True, directory=str(directory)),
    )
    rig = SimulatedRig(cfg)
    exchange = rig.exchange
    watch = _Watch(exchange, FAULT_AT_S)
    with SessionRecorder.for_config(
        cfg,
        clock=rig.clock.clock,
        phase_name=rig.law.task.phase_name,
        extra_metadata={"fault_scenario": sc.name},
    ) as recorder:
        # after the law's FAULT, long enough for drives the controller cannot reach (a transmit queue
        # full) to stop on their own SYNC watchdog: the safe state is theirs to reach
        final, stats = rig.run(
            (watch, recorder), 60.0, linger_after_end_s=cfg.actuators.sync_watchdog_s + 0.05
        )
    report = read_info(recorder.path)
    if final.mode == Mode.FAULT:
        observed = "fault"
    elif final.mode == Mode.DONE:
        observed = "warn" if watch.reaction else ("ignore" if exchange.rejected_frames else "none")
    else:
        observed = final.mode.name.lower()
    cycles_recorded = report.message_counts.get("/cycle", 0)
    return {
        "scenario": sc.name,
        "fault": sc.fault,
        "reaction_expected": f"{sc.expected}: {sc.reaction}",
        "reaction_observed": f"{observed}: {final.fault_reason or watch.reaction or 'none'}",
        "as_expected": observed == sc.expected,
        "final_mode": final.mode.name,
        "time_to_reaction_s": None if watch.reaction_s is None else round(watch.reaction_s - FAULT_AT_S, 4),
        "time_to_safe_state_s": None
        if watch.safe_s is None or sc.expected != "fault"
        else round(watch.safe_s - FAULT_AT_S, 4),
        "recording_complete": bool(
            report.complete
            and not report.damaged_chunks
            and recorder.dropped == 0
            and cycles_recorded == stats.cycles
        ),
        "recording": {"cycles": cycles_recorded, "loop_cycles": stats.cycles, "dropped": recorder.dropped},
        "rejected_frames": exchange.rejected_frames,
        "send_errors": exchange.send_errors,
    }


def run_all(
    base: Config | None = None,
    directory: Path | None = None,
    only: tuple[str, ...] = (),
    progress: Callable[[str], None] | None = None,
) -> list[dict[str, object]]:
    """The scenarios' rows; ``progress`` hears ``scenario 3/12: NAME`` before each one starts."""
    base = base or load_config()
    # The path task, one lap: long enough for every reaction, short enough for a table.
    base = msgspec.structs.replace(base, task=msgspec.structs.replace(base.task, kind="path"))
    unknown = sorted(set(only) - {sc.name for sc in SCENARIOS})
    if unknown:  # an empty table with exit 0 said nothing was wrong
        raise ConfigError(
            f"--only {', '.join(unknown)}: no such scenario; the scenarios: "
            + ", ".join(sc.name for sc in SCENARIOS)
        )
    chosen = [sc for sc in SCENARIOS if not only or sc.name in only]
    rows = []
    with tempfile.TemporaryDirectory(prefix="cheope-faults-") as tmp:
        out = Path(directory or tmp)
        for k, sc in enumerate(chosen, 1):
            if progress is not None:
                progress(f"scenario {k}/{len(chosen)}: {sc.name}")
            rows.append(run_scenario(base, sc, out))
    return rows


def format_table(rows: list[dict[str, object]]) -> str:
    head = "| scenario | injected | reaction expected | reaction observed | fault to safe state [s] | recording complete |"
    lines = [head, "| --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        safe = r["time_to_safe_state_s"]
        safe_text = (
            "n/a (task goes on)"
            if safe is None and r["final_mode"] == "DONE"
            else ("-" if safe is None else f"{safe:.4f}")
        )
        mark = "" if r["as_expected"] else " **(unexpected)**"
        lines.append(
            f"| {r['scenario']} | `{r['fault']}` | {r['reaction_expected']} | "
            f"{r['reaction_observed']}{mark} | {safe_text} | {'yes' if r['recording_complete'] else 'NO'} |"
        )
    return "\n".join(lines)
