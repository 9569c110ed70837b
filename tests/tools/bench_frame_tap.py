"""What the bus tap and the status line cost the loop's thread (CPU time, not timed tests).

    .venv/bin/python tests/tools/bench_frame_tap.py

1. One frame from another node received on udp_multicast: the raw bus against the tap (which
   hands it to a no-op sink); 7 runs of 5 000 frames. The bus hands no sender its own frames
   back (drivers/local_multicast.py), so no echo is read in either.
2. ``StatusObserver.on_cycle`` (controller/shell/status_line.py) with a contour task state,
   a JSON line every 100 cycles included; 7 runs of 40 000 cycles.
"""

from __future__ import annotations

import random
import statistics
import time

import can

from controller.core.controller_state import ControllerState, Mode
from controller.core.cycle_data import CycleInputs, CycleOutputs
from controller.core.ports import CycleTiming
from controller.core.setpoint_smoothing import Setpoint
from controller.shell.status_line import StatusObserver
from controller.tasks.contour_tracking import ContourPhase, ContourState
from drivers.bus import open_bus, parse_bus_spec
from drivers.frame_tap import FrameTap

N = 5000
spec = parse_bus_spec("udp_multicast", udp_port=random.randint(51000, 52000))
raw = open_bus(spec)
tap = FrameTap(open_bus(spec), lambda o, t, m: None)
sender = open_bus(spec)
msg = can.Message(arbitration_id=0x201, data=bytearray(6), is_extended_id=False)


BATCH = 100  # frames waiting at once: well inside a socket's default receive buffer


def receive_run() -> tuple[float, float]:
    """CPU time per frame [us] of receiving ``N`` frames another node sent: (raw bus, tap). Both
    sockets hear every frame; each batch is read by the raw bus, then by the tap."""
    raw_s = tap_s = 0.0
    for _ in range(N // BATCH):
        for _ in range(BATCH):
            sender.send(msg)
        time.sleep(0.02)  # the batch in both sockets' buffers before the clock starts
        for bus in (raw, tap):
            t0 = time.thread_time()
            for _ in range(BATCH):
                if bus.recv(1.0) is None:
                    raise RuntimeError("a frame from the other node did not arrive")
            spent = time.thread_time() - t0
            raw_s, tap_s = (raw_s + spent, tap_s) if bus is raw else (raw_s, tap_s + spent)
    return raw_s / N * 1e6, tap_s / N * 1e6


raw_r, tap_r = [], []
for _ in range(7):
    r, t = receive_run()
    raw_r.append(r)
    tap_r.append(t)
print(
    f"receive a frame, raw udp_multicast bus: median {statistics.median(raw_r):.1f} us, range {min(raw_r):.1f}-{max(raw_r):.1f}"
)
print(
    f"receive a frame, through FrameTap:      median {statistics.median(tap_r):.1f} us, range {min(tap_r):.1f}-{max(tap_r):.1f}"
)
sender.shutdown()
raw.shutdown()
tap.shutdown()

obs = StatusObserver(lambda b: None, 0.0025, laps=5)
st = ControllerState(
    mode=Mode.RUNNING,
    cycle=0,
    mode_entered_s=0.0,
    setpoint=Setpoint.at_rest((0.0,) * 3),
    controlwords=(0,) * 3,
    missing_streak=(0,) * 3,
    task_state=ContourState(phase=ContourPhase.TRACKING, lap=1, force_error_n=0.3),
    tcp_reference_m=None,
    tcp_measured_m=None,
)
inp, out, tim = CycleInputs(drives=()), CycleOutputs((), ()), CycleTiming(1e-5, 1e-4)
res = []
for r in range(7):
    t0 = time.thread_time()
    for k in range(r * 40000, (r + 1) * 40000):
        obs.on_cycle(k, 0.0, inp, st, out, (), tim)
    res.append((time.thread_time() - t0) / 40000 * 1e6)
print(
    f"StatusObserver.on_cycle (a JSON line every 100 cycles included): median {statistics.median(res):.2f} us, range {min(res):.2f}-{max(res):.2f}"
)
