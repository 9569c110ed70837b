"""Faults, bad input and safe stops (the fault issue): every scenario, recovery, a killed controller."""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys

import can
import numpy as np
import pytest
from busy_machine import TOLERANT
from controller_on_the_bus import (
    controller_beside_simulator,
    drives_over_sdo,
    run_sets,
    wait_until_drive_1_moves,
)
from hypothesis import given, settings
from hypothesis import strategies as st
from waiting import wait_until

from controller.assembly import build_law
from controller.config import load_config
from controller.core.cia402 import PowerState, decode_statusword
from controller.core.controller_state import Mode
from controller.shell.loop import CycleLoop, SimulatedTime
from controller.tools.fault_scenarios import SCENARIOS, run_all
from drivers.cyclic_exchange import CyclicExchange
from drivers.pdo_codec import PositionScale
from sim_backend.loopback import LoopbackExchange


def test_every_fault_scenario_gets_its_reaction_and_a_complete_recording(tmp_path):
    rows = run_all(directory=tmp_path)
    assert [r["scenario"] for r in rows] == [s.name for s in SCENARIOS]
    for r in rows:
        assert r["as_expected"], r
        assert r["recording_complete"], r
        if r["reaction_expected"].startswith("fault"):
            # quick stop within a quarter second of the detection; a heartbeat is overdue only after
            # the consumer time (loop.heartbeat_consumer_s) since the last one
            cfg = load_config()
            detection_s = cfg.loop.heartbeat_consumer_s if r["fault"].startswith("heartbeat") else 0.0
            if "SYNC watchdog" in r["reaction_expected"]:  # the controller cannot reach them: their own
                detection_s = cfg.actuators.sync_watchdog_s
            if "back off" in r["reaction_expected"]:
                # the contact guard's protective stop: the back-off's way (5 mm at 20 mm/s, ramps at
                # 0.5 m/s^2) before the fault, not a quick stop in place
                c = cfg.safety.contact
                detection_s += (
                    c.back_off_distance_m / c.back_off_speed_m_s
                    + c.back_off_speed_m_s / c.back_off_acceleration_m_s2
                )
            assert 0.0 < r["time_to_safe_state_s"] < detection_s + 0.25, r
    malformed = next(r for r in rows if r["scenario"].startswith("malformed"))
    assert malformed["rejected_frames"] == 1 and malformed["final_mode"] == "DONE"


def test_recovery_after_a_reset_starts_from_the_measured_positions_within_the_jerk_limit():
    cfg = load_config(overrides={"task.path.laps": 0.5, "sim.faults": ["drive_fault:3@1.0"]})
    clock = SimulatedTime()
    law = build_law(cfg)
    ex = LoopbackExchange(cfg, clock.clock)
    sent = {"reset": False}
    setpoints, modes, measured = [], [], []

    def commands():
        if modes and modes[-1] == Mode.FAULT and clock.now_s > 1.5 and not sent["reset"]:
            sent["reset"] = True
            return ("reset", 0.0)
        return None

    class Trace:
        def on_cycle(self, cycle, t, inputs, state, outputs, events, timing):
            setpoints.append(state.setpoint)
            modes.append(state.mode)
            measured.append(tuple(d.position for d in inputs.drives))

    final, _ = CycleLoop(
        law, ex, cfg.period_s, 0.8, clock, clock.clock, observers=(Trace(),), commands=commands
    ).run(law.initial_state(), 30.0, exit_on_fault=False)
    assert sent["reset"] and Mode.FAULT in modes
    assert final.mode == Mode.DONE, final.fault_reason
    k = modes.index(Mode.ENABLING, modes.index(Mode.FAULT))  # the first cycle after the reset
    assert np.allclose(setpoints[k].position, measured[k], atol=1e-7)  # re-synchronised: no jump
    acc = np.array([s.acceleration for s in setpoints[k:]])
    jerk = np.abs(np.diff(acc, axis=0)) / cfg.period_s
    assert jerk.max() <= cfg.actuators.max_jerk_m_s3 * (1 + 1e-6)


@settings(max_examples=400, deadline=None)
@given(st.integers(0, 0x7FF), st.binary(min_size=0, max_size=64), st.booleans(), st.booleans())
def test_decoders_never_raise_and_count_what_they_reject(cob_id, data, fd, error_frame):
    bus = can.Bus(interface="virtual", channel=f"fuzz-{os.getpid()}")
    try:
        ex = CyclicExchange(bus, (1, 2, 3), PositionScale(1e7), 16, 100, heartbeat_every=40)
        ex._collecting = True
        before = ex.counters.rejected_frames
        ex._notify(
            can.Message(
                arbitration_id=cob_id, data=data, is_fd=fd, is_error_frame=error_frame, is_extended_id=False
            )
        )
        routed = cob_id in (
            0x181,
            0x182,
            0x183,
            0x190,
            0x290,
            0x81,
            0x82,
            0x83,
            0x90,
            0x701,
            0x702,
            0x703,
            0x710,
        )
        expected_len = {
            0x181: 6,
            0x182: 6,
            0x183: 6,
            0x190: 8,
            0x290: 8,
            0x701: 1,
            0x702: 1,
            0x703: 1,
            0x710: 1,
        }.get(cob_id, 8)  # heartbeats: the NMT state
        if routed and not error_frame and len(data) != expected_len:
            assert ex.counters.rejected_frames == before + 1
        else:
            assert ex.counters.rejected_frames == before
    finally:
        bus.shutdown()


@pytest.mark.integration
def test_a_killed_controller_leaves_the_simulated_robot_stopped(tmp_path):
    """SIGKILL the controller mid-task: the drives' SYNC watchdog quick-stops them."""
    ids = tuple(load_config().actuators.node_ids)
    # tolerant of a busy machine: the point is what happens after the kill
    with controller_beside_simulator(run_sets(tmp_path)) as run:
        wait_until_drive_1_moves(run.bus, run.process)  # well into the task, not a guessed 4 s
        run.process.send_signal(signal.SIGKILL)
        run.process.wait()
        with drives_over_sdo(run.spec, ids) as network:
            previous: list[list[int]] = []

            def quick_stopped_and_still():
                # the watchdog's quick stop, then the same positions in two polls in a row
                states = [decode_statusword(network[n].sdo[0x6041].raw) for n in ids]
                positions = [network[n].sdo[0x6064].raw for n in ids]
                still = bool(previous) and positions == previous[-1]
                previous.append(positions)
                return states == [PowerState.QUICK_STOP_ACTIVE] * 3 and still

            wait_until(
                quick_stopped_and_still,
                "every drive quick-stopped by its SYNC watchdog and standing still",
                poll_s=0.05,
            )


@pytest.mark.integration
@pytest.mark.parametrize(
    ("signals", "args", "exit_code", "mode", "powers"),
    [
        ((signal.SIGTERM,), (), 0, "DONE", {PowerState.READY_TO_SWITCH_ON, PowerState.SWITCH_ON_DISABLED}),
        (
            (),
            ("--duration", "4"),
            0,
            "DONE",
            {PowerState.READY_TO_SWITCH_ON, PowerState.SWITCH_ON_DISABLED},
        ),
        ((signal.SIGTERM, signal.SIGINT), (), 1, "FAULT", {PowerState.QUICK_STOP_ACTIVE}),
    ],
    ids=["sigterm-stops", "duration-stops", "second-signal-quick-stops"],
)
def test_a_signal_mid_motion_stops_the_run_under_control(tmp_path, signals, args, exit_code, mode, powers):
    """SIGTERM while the carriages move (or the end of --duration): STOPPING brakes, the drives
    are disabled, DONE, exit 0 (read back over SDO from the drives); a second signal quick-stops
    them instead, exit 1. Three laps take far longer than any of these runs."""
    ids = tuple(load_config().actuators.node_ids)
    # more tolerant of a busy machine than TOLERANT: a drive fault before the signal is not the point here
    sets = run_sets(tmp_path, "--set", "loop.max_missing_s=0.25", "--set", "safety.sensor_stale_s=0.25")
    with controller_beside_simulator([*args, *sets]) as run:
        ctrl = run.process
        wait_until_drive_1_moves(run.bus, ctrl)
        for sig in signals:
            ctrl.send_signal(sig)
        out, err = ctrl.communicate(timeout=60)
        assert ctrl.returncode == exit_code, err[-2000:] + out[-3000:]
        summary = json.loads(out)
        assert summary["final_mode"] == mode, summary["fault_reason"]
        if mode == "FAULT":
            assert summary["fault_reason"] == "quick stop requested"
        else:
            assert any("stop requested" in e for e in summary["events"])
        assert "Traceback" not in err
        with drives_over_sdo(run.spec, ids) as network:
            states = {decode_statusword(network[n].sdo[0x6041].raw) for n in ids}
            assert states <= powers, states


def test_bad_fault_spec_is_one_clear_line():
    r = subprocess.run(
        [sys.executable, "-m", "controller", "demo", "--inject", "explode@1"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert r.returncode == 2
    assert "unknown kind 'explode'" in r.stderr and "Traceback" not in r.stderr


@pytest.mark.integration
def test_a_50_mm_position_jump_over_udp_multicast_faults_within_3_cycles(tmp_path):
    """The simulator process's drive 2 reports 50 mm more than its carriage is at (a lying encoder
    or frame): the controller faults within 3 cycles of the first TPDO that carries it."""
    from logs import messages as m
    from logs.reader import iter_decoded

    port = random.SystemRandom().randint(48000, 49999)
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "controller",
            "demo",
            "--task",
            "path",
            "--json",
            "--udp-port",
            str(port),
            "--inject",
            "jump:2=0.05@1.0",
            "--set",
            "task.path.laps=1",
            "--set",
            f'recording.directory="{tmp_path}"',
            "--set",
            "monitoring.enabled=false",
            *TOLERANT,
        ],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    summary = json.loads(r.stdout)
    assert summary["final_mode"] == "FAULT", summary["final_mode"]
    assert "drive 2 position jumped" in summary["fault_reason"], summary["fault_reason"]
    cycles = [d.message for d in iter_decoded(summary["recording"]["path"], [m.TOPIC_CYCLE])]
    position = [c.inputs.drives[1].position for c in cycles]
    fresh = [c.inputs.drives[1].fresh for c in cycles]
    jumped = next(k for k in range(1, len(cycles)) if fresh[k] and abs(position[k] - position[k - 1]) > 0.04)
    faulted = next(k for k, c in enumerate(cycles) if c.state.mode == "FAULT")
    assert 0 <= faulted - jumped < 3, (jumped, faulted)
