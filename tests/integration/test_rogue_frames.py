"""Rogue frames timed to arrive before the real answer: the data is never used, the reaction is named.

In-process and deterministic: the production ``CyclicExchange`` behind the loopback devices
(sim_backend/loopback.py) in simulated time, with the fault injection sending someone else's
frame on a device's COB-ID just before the device's own answer to the same SYNC. One test over
udp_multicast with a separate rogue sender is at the end.
"""

from __future__ import annotations

import contextlib
import errno
import itertools
import json
import math
import os
import random
import signal
import socket
import struct
import subprocess
import sys
import threading
from dataclasses import dataclass, field
from pathlib import Path

import can
import canopen
import pytest
from busy_machine import TOLERANT
from can.interfaces.udp_multicast.utils import pack_message
from controller_on_the_bus import (
    controller_beside_simulator,
    drives_over_sdo,
    run_sets,
    wait_until_drive_1_moves,
)
from waiting import wait_until

from controller.assembly import build_law
from controller.config import load_config
from controller.core.cia402 import PowerState, decode_statusword
from controller.core.controller_state import ControllerState, Mode
from controller.core.cycle_data import CycleInputs, CycleOutputs, Event
from controller.core.periods import cycles_in
from controller.core.ports import CycleTiming
from controller.shell.loop import CycleLoop, SimulatedTime
from controller.tasks.contour_tracking import ContourPhase
from drivers.bus import LOCAL_MULTICAST_GROUP, open_bus, parse_bus_spec
from drivers.local_multicast import host_addresses, multicast_interface
from sim_backend.drive import ABORT_NO_ACTION
from sim_backend.loopback import LoopbackExchange

ROGUE_AT_S = 1.0  # the path task is running by then (it starts at about 0.2 s)
DRIVE_2 = 1  # index of node 2


@dataclass
class Trace:
    """Per cycle: the step's inputs, state, outputs and events, and what the simulated devices really are."""

    exchange: LoopbackExchange
    t: list[float] = field(default_factory=list)
    inputs: list[CycleInputs] = field(default_factory=list)
    states: list[ControllerState] = field(default_factory=list)
    outputs: list[CycleOutputs] = field(default_factory=list)
    events: list[Event] = field(default_factory=list)
    true_positions: list[tuple[float, ...]] = field(
        default_factory=list
    )  # what each drive's own TPDO carried
    powers: list[tuple[PowerState, ...]] = field(default_factory=list)
    true_force_n: list[float] = field(default_factory=list)  # the simulated contact's, not the measurement

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
        drives = self.exchange.drives
        self.t.append(t)
        self.inputs.append(inputs)
        self.states.append(state)
        self.outputs.append(outputs)
        self.events.extend(events)
        # the plant moves on only at the next send: this is where each drive was at this cycle's SYNC
        self.true_positions.append(tuple(d.position_counts() / d.params.counts_per_unit for d in drives))
        self.powers.append(tuple(d.power for d in drives))
        self.true_force_n.append(math.hypot(*(float(x) for x in self.exchange.plant.force_n)))


def run(
    faults: list[str],
    abort_option: int | None = None,
    max_s: float = 3.0,
    overrides: dict[str, object] | None = None,
) -> tuple[ControllerState, Trace]:
    cfg = load_config(overrides={"sim.faults": faults, "task.path.laps": 0.5, **(overrides or {})})
    clock = SimulatedTime()
    law = build_law(cfg)
    ex = LoopbackExchange(cfg, clock.clock)
    if abort_option is not None:  # a drive that does not stop by itself when it loses its master
        for d in ex.drives:
            d.abort_connection_option = abort_option
    trace = Trace(ex)
    final, _ = CycleLoop(
        law, ex, cfg.period_s, cfg.loop.collect_fraction, clock, clock.clock, observers=(trace,)
    ).run(law.initial_state(), max_s)
    return final, trace


def assert_drive_2_never_measured_off(trace: Trace) -> None:
    """Every fresh drive-2 sample the step got is what drive 2 itself sent, and no target went elsewhere."""
    for k, (inputs, true) in enumerate(zip(trace.inputs, trace.true_positions, strict=True)):
        d = inputs.drives[DRIVE_2]
        if d.fresh:
            assert d.position == pytest.approx(true[DRIVE_2], abs=1e-6), (
                trace.t[k],
                d.position,
                true[DRIVE_2],
            )
    used = {i.drives[DRIVE_2].position for i in trace.inputs if i.drives[DRIVE_2].fresh}
    for k, state in enumerate(trace.states):
        if (
            state.mode == Mode.FAULT
        ):  # held where the drive was measured and trusted, never where the rogue said
            assert state.setpoint.position[DRIVE_2] in used, trace.t[k]


@pytest.mark.parametrize(("offset_m", "what"), [(0.05, "position jump"), (0.0025, "small offset")])
def test_a_rogue_drive_tpdo_before_the_real_one_is_never_used(offset_m, what):
    """+50 mm or +2.5 mm tracking the real position, on drive 2's COB-ID before its answer: two
    candidates in one window; neither is used, and the fault names the node and the COB-ID."""
    final, trace = run([f"rogue_tpdo:2={offset_m}@{ROGUE_AT_S}"])
    assert final.mode == Mode.FAULT
    assert (
        final.fault_reason == "1 TPDO(s) twice in one cycle (a second sender; neither is used) from node 2 "
        "(COB-ID 0x182)"
    )
    first_rogue = next(k for k, t in enumerate(trace.t) if t >= ROGUE_AT_S)
    assert not trace.inputs[first_rogue].drives[DRIVE_2].fresh  # the cycle of the race: unusable
    assert trace.states[first_rogue].mode == Mode.FAULT
    assert_drive_2_never_measured_off(trace)


def test_a_lone_rogue_drive_tpdo_with_the_duplicates_warned_is_still_never_used():
    """With safety.on_duplicate_frames = warn, the rogue goes on for cycles: every one of them
    unusable, so the drive is as silent and loop.max_missing_s faults, naming it."""
    cfg_faults = [f"rogue_tpdo:2=0.0025@{ROGUE_AT_S}"]
    cfg = load_config(
        overrides={"sim.faults": cfg_faults, "task.path.laps": 0.5, "safety.on_duplicate_frames": "warn"}
    )
    clock = SimulatedTime()
    law = build_law(cfg)
    ex = LoopbackExchange(cfg, clock.clock)
    trace = Trace(ex)
    final, _ = CycleLoop(
        law, ex, cfg.period_s, cfg.loop.collect_fraction, clock, clock.clock, observers=(trace,)
    ).run(law.initial_state(), 3.0)
    assert (
        final.fault_reason == f"drive 2: no TPDO for {cycles_in(cfg.loop.max_missing_s, cfg.period_s)} cycles"
    )
    starts = [e for e in trace.events if e.message.startswith("burst starts") and "from node 2" in e.message]
    assert len(starts) == 1  # one event when the burst starts, not one per frame
    assert_drive_2_never_measured_off(trace)


def test_a_drive_position_jump_holds_at_the_last_trusted_position():
    """A lying encoder (one candidate, +50 mm): the jump faults at once, and the hold target is the
    last trusted position, not the flagged one (it was commanded to the rogue one for 3 cycles)."""
    final, trace = run([f"jump:2=0.05@{ROGUE_AT_S}"])
    assert final.fault_reason.startswith("drive 2 position jumped 0.0")
    k = next(k for k, s in enumerate(trace.states) if s.mode == Mode.FAULT)
    assert trace.inputs[k].drives[DRIVE_2].fresh  # the flagged sample itself
    trusted = trace.inputs[k - 1].drives[DRIVE_2].position  # the last sample before the jump
    assert trace.inputs[k - 1].drives[DRIVE_2].fresh
    assert all(s.setpoint.position[DRIVE_2] == trusted for s in trace.states[k:])
    assert all(o.targets[DRIVE_2] == trusted for o in trace.outputs[k:])


def test_a_spoofed_sensor_frame_before_the_real_one_is_never_used():
    final, trace = run([f"spoof_sensor=30@{ROGUE_AT_S}"])
    assert final.mode == Mode.FAULT
    assert "from node 16 (COB-ID 0x190)" in final.fault_reason
    fresh_forces = [i.sensor.force_n[0] for i in trace.inputs if i.sensor is not None and i.sensor.fresh]
    assert (
        fresh_forces and max(abs(f) for f in fresh_forces) < 5.0
    )  # the path task touches nothing; 30 N never


CONTOUR_SPOOF_AT_S = 4.0  # the contour task tracks the disk by then (contact at about 2 s)


def _contour_spoofed(**overrides: object) -> tuple[ControllerState, Trace, int]:
    """The contour task with a spoofed 30 N force frame while it tracks; the breach's cycle index."""
    final, trace = run(
        [f"spoof_sensor=30@{CONTOUR_SPOOF_AT_S}"], max_s=8.0, overrides={"task.kind": "contour", **overrides}
    )
    k = next(k for k, s in enumerate(trace.states) if s.sensor_breach or s.mode == Mode.FAULT)
    assert trace.states[k - 1].task_state.phase == ContourPhase.TRACKING
    return final, trace, k


def test_a_spoofed_sensor_frame_during_the_contour_retracts_the_tool_before_the_fault():
    """Someone else's force frame while the tool is in contact: the law stops using the sensor and
    the task moves the tool away along the last normal (no force needed), then the fault names the
    breach. The drives' own frames are still trusted; a quick stop would have held the tool in
    contact at whatever force it had."""
    final, trace, k = _contour_spoofed()
    assert final.mode == Mode.FAULT
    assert final.fault_reason == (
        "force sensor not trusted: 1 TPDO(s) the device cannot have sent (a position step or counter "
        "beyond it; not used) from node 16 (COB-ID 0x190)"
    )
    assert trace.states[k].mode == Mode.RUNNING and trace.states[k].sensor_breach
    # from the breach on, nothing of the sensor reaches the task: its filtered force never moves again
    frozen = trace.states[k].task_state.force_f
    assert all(s.task_state.force_f == frozen for s in trace.states[k:])
    f = next(j for j in range(k, len(trace.states)) if trace.states[j].mode == Mode.FAULT)
    assert trace.states[f].task_state.phase == ContourPhase.FINISHED  # retracted, then the fault
    # the tool left the contact: 10 mm along the normal (the retract), no contact force at the fault
    start, end = trace.states[k].tcp_measured_m, trace.states[f].tcp_measured_m
    assert math.dist(start, end) > 0.008
    assert trace.true_force_n[k] > 5.0 and trace.true_force_n[f] == 0.0
    assert max(trace.true_force_n[k:]) <= trace.true_force_n[k] + 1.0  # never pressed harder
    kinds = [e.kind for e in trace.events]
    assert "sensor_breach" in kinds and kinds.index("sensor_breach") < kinds.index(
        "mode", kinds.index("sensor_breach")
    )


def test_with_no_time_to_retract_a_spoofed_sensor_frame_is_the_quick_stop_at_once():
    final, trace, k = _contour_spoofed(**{"safety.sensor_breach_retract_s": 0.0})
    assert trace.states[k].mode == Mode.FAULT and not trace.states[k].sensor_breach
    assert final.fault_reason.startswith("1 TPDO(s) the device cannot have sent")


def test_a_retract_that_takes_too_long_ends_in_the_fault_at_the_bound():
    """A retract of 0.5 m at 20 mm/s cannot end within safety.sensor_breach_retract_s (0.5 s): the
    law faults at the bound, naming both."""
    final, trace, k = _contour_spoofed(
        **{"safety.sensor_breach_retract_s": 0.5, "task.contour.retract_distance_m": 0.5}
    )
    assert final.fault_reason.endswith("; the task did not retract within 0.5 s")
    f = next(j for j in range(k, len(trace.states)) if trace.states[j].mode == Mode.FAULT)
    assert (f - k) * 0.0025 == pytest.approx(0.5, abs=0.01)


def test_a_wrong_length_tpdo_before_the_real_one_is_never_used_and_named():
    final, trace = run([f"rogue_short:2@{ROGUE_AT_S}"])
    assert final.mode == Mode.FAULT and "from node 2 (COB-ID 0x182)" in final.fault_reason
    assert trace.exchange.rejected_frames >= 1
    rejected = [a for i in trace.inputs for a in i.anomalies if a.kind.value == "rejected_frame"]
    assert rejected and all(a.node_id == 2 for a in rejected)
    assert_drive_2_never_measured_off(trace)


def test_a_short_emcy_is_rejected_and_reported_per_burst_with_its_count():
    """20 cycles of a 3-byte EMCY on drive 2's EMCY COB-ID: never an EMCY of the step, one event
    when the burst starts and one with its count when it ends; the task goes on."""
    final, trace = run([f"rogue_emcy:2@{ROGUE_AT_S}+0.05"])  # 20 cycles at 400 Hz
    assert final.mode == Mode.DONE, final.fault_reason
    assert all(i.emcy == () for i in trace.inputs)
    burst = [e.message for e in trace.events if "(COB-ID 0x082)" in e.message]
    assert burst == [
        "burst starts: 1 frame(s) of the wrong length (rejected) from node 2 (COB-ID 0x082)",
        "burst ended: 20 frame(s) of the wrong length (rejected) from node 2 (COB-ID 0x082) in 20 cycle(s)",
    ]


@pytest.mark.parametrize(
    ("fault", "command"),
    [("nmt_preop", "enter PRE-OPERATIONAL"), ("nmt_stop", "stop"), ("nmt_reset", "reset node")],
)
def test_a_foreign_nmt_command_to_one_drive_stops_every_drive_within_100_ms(fault, command):
    """Another master's NMT to drive 2, which then processes no RPDO: every drive out of OPERATION
    ENABLED within 100 ms (simulated time, the devices' own state), the command and node named."""
    final, trace = run([f"{fault}:2@{ROGUE_AT_S}+0.0025"])
    assert final.fault_reason == f"NMT {command} to node 2 from another master"
    enabled_until = max(
        t for t, powers in zip(trace.t, trace.powers, strict=True) if PowerState.OPERATION_ENABLED in powers
    )
    assert ROGUE_AT_S <= enabled_until < ROGUE_AT_S + 0.1


def test_a_drive_put_in_pre_operational_that_does_not_stop_itself_is_quick_stopped_by_sdo():
    """0x6007 = 0 (no reaction of its own): the quick stop in its RPDO does not reach a
    PRE-OPERATIONAL drive; the SDO 0x6040 the loop sends as well does, within 100 ms."""
    final, trace = run([f"nmt_preop:2@{ROGUE_AT_S}+0.0025"], abort_option=ABORT_NO_ACTION)
    assert final.mode == Mode.FAULT
    asked = [k for k, o in enumerate(trace.outputs) if o.sdo_controlwords]
    assert asked and trace.outputs[asked[0]].sdo_controlwords == ((DRIVE_2, 0x0002),)
    assert any(e.kind == "sdo_quick_stop" and "node(s) 2" in e.message for e in trace.events)
    after = [p for t, p in zip(trace.t, trace.powers, strict=True) if t >= ROGUE_AT_S + 0.1]
    assert after and all(PowerState.OPERATION_ENABLED not in p for p in after)
    assert after[-1][DRIVE_2] == PowerState.QUICK_STOP_ACTIVE


def test_every_silent_node_is_named_in_one_fault():
    """The simulator gone (its frames lost): one fault names all of them, after the silence every
    device shares (loop.max_bus_silence_s)."""
    final, _ = run([f"tx_full@{ROGUE_AT_S}"])
    cfg = load_config()
    limit = cycles_in(cfg.loop.max_bus_silence_s, cfg.period_s)
    assert final.fault_reason == f"drives 1, 2, 3 and the force sensor silent for {limit} cycles"


@pytest.mark.integration
def test_a_rogue_sender_on_udp_multicast_never_steers_the_controller(tmp_path):
    """A separate node on the bus answers every SYNC with drive 2's TPDO + 50 mm (tracking the real
    one) as fast as it can, racing the simulator: the controller faults naming node 2, and no
    recorded cycle used a drive-2 position off by more than the drive can move."""
    from logs import messages as m
    from logs.reader import iter_decoded

    port = random.SystemRandom().randint(48000, 49999)
    stop = threading.Event()
    armed = threading.Event()  # the rogue starts once drive 2 has moved (the task runs)
    sent = [0]

    def rogue() -> None:
        with open_bus(parse_bus_spec("udp_multicast", udp_port=port)) as bus:
            last: bytes | None = None
            start_counts: int | None = None
            while not stop.is_set():
                msg = bus.recv(timeout=0.05)
                if msg is None:
                    continue
                # drive 2's TPDO: statusword and position first, then its effort (cheope.toml's mapping)
                if msg.arbitration_id == 0x182 and len(msg.data) >= 6 and bytes(msg.data) != last:
                    sw, counts = struct.unpack_from("<Hi", msg.data)
                    start_counts = counts if start_counts is None else start_counts
                    if abs(counts - start_counts) > 20_000:
                        armed.set()
                    # + 50 mm at 1e7 counts/m, the rest of the frame as it was
                    last = struct.pack("<Hi", sw, counts + 500_000) + bytes(msg.data[6:])
                elif msg.arbitration_id == 0x080 and armed.is_set() and last is not None:
                    bus.send(can.Message(arbitration_id=0x182, data=last, is_extended_id=False))
                    sent[0] += 1

    thread = threading.Thread(target=rogue, daemon=True)
    thread.start()
    try:
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
    finally:
        stop.set()
        thread.join(timeout=5)
    summary = json.loads(r.stdout)
    assert sent[0] > 0, "the rogue never sent"
    assert summary["final_mode"] == "FAULT", summary["final_mode"]
    assert "from node 2" in summary["fault_reason"], summary["fault_reason"]
    cycles = [d.message for d in iter_decoded(summary["recording"]["path"], [m.TOPIC_CYCLE])]
    used = [c.inputs.drives[1].position for c in cycles if c.inputs.drives[1].fresh]
    assert all(abs(b - a) < 0.02 for a, b in itertools.pairwise(used))  # 50 mm never appears in what was used
    targets = [c.outputs.targets[1] for c in cycles]
    assert all(abs(b - a) < 0.02 for a, b in itertools.pairwise(targets))


def test_a_long_burst_is_reported_while_it_goes_on_not_once_per_run_nor_per_frame():
    """1.2 s of short EMCYs (480 cycles): a start, the running count after a second, the end with its count."""
    final, trace = run([f"rogue_emcy:2@{ROGUE_AT_S}+1.2"], max_s=4.0)
    assert final.mode == Mode.DONE, final.fault_reason
    burst = [e.message for e in trace.events if "(COB-ID 0x082)" in e.message]
    what = "frame(s) of the wrong length (rejected) from node 2 (COB-ID 0x082)"
    assert burst == [
        f"burst starts: 1 {what}",
        f"burst goes on: 401 {what} in 401 cycle(s) so far",
        f"burst ended: 480 {what} in 480 cycle(s)",
    ]


@pytest.mark.integration
def test_another_master_s_nmt_pre_operational_leaves_no_drive_enabled_over_udp_multicast(tmp_path):
    """The issue's case: with loop.stay_in_fault = true, a second node on the bus sends NMT "enter
    PRE-OPERATIONAL" to drive 2 mid-motion. Drive 2 no longer processes RPDOs (their quick stop), yet
    every drive, read back over SDO while the controller holds FAULT, is out of OPERATION ENABLED
    (its own 0x6007 reaction and the controller's SDO quick stop), and the fault names command and node."""
    ids = tuple(load_config().actuators.node_ids)
    with controller_beside_simulator(run_sets(tmp_path, "--set", "loop.stay_in_fault=true")) as run:
        ctrl = run.process
        wait_until_drive_1_moves(run.bus, ctrl)
        run.bus.send(can.Message(arbitration_id=0x000, data=bytes((0x80, 2)), is_extended_id=False))
        with drives_over_sdo(run.spec, ids) as network:

            def none_enabled() -> bool:
                assert ctrl.poll() is None, ctrl.communicate()  # the controller holds FAULT
                try:
                    states = [decode_statusword(network[n].sdo[0x6041].raw) for n in ids]
                except canopen.sdo.exceptions.SdoCommunicationError:
                    # this test is a second SDO client on the drives' one server channel: the
                    # controller's own quick-stop download (0x6040) can answer our upload; ask again
                    return False
                return PowerState.OPERATION_ENABLED not in states

            wait_until(
                none_enabled,
                "every drive out of OPERATION ENABLED while the controller holds FAULT",
                poll_s=0.05,
            )
        ctrl.send_signal(signal.SIGINT)  # a stop ends a run that holds FAULT
        out, err = ctrl.communicate(timeout=60)
        summary = json.loads(out)
        assert summary["final_mode"] == "FAULT", err[-2000:]
        assert summary["fault_reason"] == "NMT enter PRE-OPERATIONAL to node 2 from another master"


def _sending_sources(pid: int) -> list[tuple[str, int]]:
    """The (address, port) of every IPv6 UDP socket of process ``pid`` not bound to a multicast group:
    its buses' sending sockets (/proc/net/udp6 writes an address as four host-order words)."""
    inodes = set()
    for fd in (Path(f"/proc/{pid}/fd")).iterdir():
        with contextlib.suppress(OSError):
            target = os.readlink(fd)
            if target.startswith("socket:["):
                inodes.add(target[8:-1])
    out = []
    for line in Path(f"/proc/{pid}/net/udp6").read_text().splitlines()[1:]:
        fields = line.split()
        address_hex, port_hex = fields[1].split(":")
        packed = b"".join(bytes.fromhex(address_hex[i : i + 8])[::-1] for i in range(0, 32, 8))
        if fields[9] in inodes and packed[0] != 0xFF:
            out.append((socket.inet_ntop(socket.AF_INET6, packed), int(port_hex, 16)))
    return out


@pytest.mark.integration
def test_a_second_sdo_client_sending_from_the_controllers_own_port_is_seen_and_faults_the_run(tmp_path):
    """An outside tester bound another address of this host to the controller's sending port: the
    bus dropped its frames as the controller's own echoes, and its SDO writes to a running drive were
    obeyed and never seen (44dbcbc). The controller's source (address and port) is its alone; from
    any other, the request and the drive's answer are someone else's, and the run faults naming them."""
    with controller_beside_simulator(run_sets(tmp_path)) as run:
        ctrl = run.process
        wait_until_drive_1_moves(run.bus, ctrl)
        sources = _sending_sources(ctrl.pid)
        assert sources, "the controller has no sending socket"
        address, port = sources[0]
        _, index = multicast_interface()
        with socket.socket(socket.AF_INET6, socket.SOCK_DGRAM) as same, pytest.raises(OSError) as refused:
            same.bind((address, port, 0, index if address.startswith("fe80") else 0))
        assert refused.value.errno == errno.EADDRINUSE
        rogue = None
        for other in sorted(host_addresses() - {address, "::1"}):
            candidate = socket.socket(socket.AF_INET6, socket.SOCK_DGRAM)
            candidate.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_MULTICAST_HOPS, 0)
            candidate.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_MULTICAST_IF, index)
            try:
                candidate.bind((other, port, 0, index if other.startswith("fe80") else 0))
                rogue = candidate
                break
            except OSError:
                candidate.close()
        if rogue is None:
            pytest.skip("this host has no second address to send from")
        with rogue:
            upload_statusword = can.Message(
                arbitration_id=0x602, data=bytes((0x40, 0x41, 0x60, 0, 0, 0, 0, 0)), is_extended_id=False
            )
            rogue.sendto(
                pack_message(upload_statusword), (LOCAL_MULTICAST_GROUP, run.spec.udp_port, 0, index)
            )
        out, err = ctrl.communicate(timeout=120)
    summary = json.loads(out)
    assert summary["final_mode"] == "FAULT", err[-2000:]
    assert "a second master) (COB-ID 0x602)" in summary["fault_reason"], summary["fault_reason"]


@pytest.mark.integration
def test_datagrams_that_are_no_frame_stop_neither_the_controller_nor_the_simulator(tmp_path):
    """Any process of this host may send anything to the bus's port. Before, python-can raised out of
    ``recv`` on the first datagram that was no packed frame, and the controller and the simulator
    both ended ("could not unpack received message"). Now each is dropped and counted, the drives
    keep moving under the controller, and a stop ends the run DONE."""
    not_frames = (b"hello", b"\x93\x01\x02\x03", b"\x81\xa7mystery\x01")  # text, a list, an unknown field
    with controller_beside_simulator(run_sets(tmp_path)) as run:
        ctrl = run.process
        wait_until_drive_1_moves(run.bus, ctrl)
        for datagram in not_frames:
            run.bus._multicast.send(datagram)
        wait_until_drive_1_moves(run.bus, ctrl)  # 2 mm more, after them: both processes go on
        ctrl.send_signal(signal.SIGINT)
        out, err = ctrl.communicate(timeout=60)
    summary = json.loads(out)
    assert summary["final_mode"] == "DONE", err[-2000:]
    assert summary["frames"]["unreadable_datagrams_dropped"] == len(not_frames)
    assert "datagram(s) that are no CAN frame dropped" in err
