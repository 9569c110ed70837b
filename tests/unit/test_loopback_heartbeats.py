"""The in-process simulated nodes' heartbeats (sim_backend/loopback.py) come every heartbeat period,
as their producers' 0x1017 says, on any SYNC grid: checked at the SYNCs, each goes at the first
SYNC at or after its due time."""

from __future__ import annotations

import numpy as np
import pytest

from controller.assembly import build_law
from controller.config import load_config
from controller.shell.loop import CycleLoop, SimulatedTime
from drivers import cob_ids
from sim_backend.loopback import LoopbackExchange


def _heartbeat_times(
    rate_hz: float, duration_s: float, node: int, faults: tuple[str, ...] = ()
) -> np.ndarray:
    cfg = load_config(overrides={"loop.rate_hz": rate_hz, "task.kind": "path", "sim.faults": list(faults)})
    law = build_law(cfg)
    clock = SimulatedTime()
    loopback = LoopbackExchange(cfg, clock.clock)
    seen: list[float] = []

    def sink(outgoing: bool, monotonic_s: float, msg: object) -> None:
        if not outgoing and msg.arbitration_id == cob_ids.heartbeat(node):  # type: ignore[attr-defined]
            seen.append(monotonic_s)

    loopback.exchange.frame_sink = sink
    loop = CycleLoop(law, loopback, cfg.period_s, cfg.loop.collect_fraction, clock, clock.clock)
    loop.run(law.initial_state(), duration_s)
    return np.array(seen)


@pytest.mark.parametrize("rate_hz", [400.0, 300.0, 250.0])
def test_on_a_grid_that_divides_the_period_every_heartbeat_is_a_period_after_the_last(rate_hz):
    """At 400 Hz the loopback's heartbeats came every 102.5 ms: ``now - last >= 0.1`` is false at
    40 periods of 2.5 ms by rounding."""
    times = _heartbeat_times(rate_hz, 2.0, node=1)
    assert len(times) >= 15
    np.testing.assert_allclose(np.diff(times), 0.1, atol=1e-9)


def test_on_a_grid_that_does_not_divide_it_they_keep_the_period_on_average():
    """At 333 Hz a period is 33.3 SYNCs: each heartbeat goes at the first SYNC after its due time,
    the next is due a period after that time, so the intervals are 33 and 34 SYNCs, 100 ms on average
    (counted from the SYNC that sent, every one would be 34: 102.1 ms)."""
    period_s = 1 / 333.0
    times = _heartbeat_times(333.0, 4.0, node=2)
    intervals = np.diff(times)
    assert len(intervals) >= 30
    assert abs(intervals.mean() - 0.1) < period_s / len(intervals) + 1e-9
    assert intervals.min() > 0.1 - period_s and intervals.max() < 0.1 + period_s


def test_after_a_silence_the_heartbeats_start_again_from_the_sync_that_sends() -> None:
    """``heartbeat:2@1+0.05`` at 400 Hz: the first after the silence at 1.05 s, the next a period
    after it (it came 50 ms after, on the grid from before the silence)."""
    times = _heartbeat_times(400.0, 1.5, node=2, faults=("heartbeat:2@1+0.05",))
    start = times[0]  # the grid's origin: the first SYNC's time
    after = times[times - start > 1.0]
    np.testing.assert_allclose(after[:3] - start, [1.05, 1.15, 1.25], atol=1e-9)
