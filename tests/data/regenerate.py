"""Regenerate the short recorded sessions that ``tests/integration/test_replay.py`` verifies bit for bit.

    .venv/bin/python tests/data/regenerate.py

Each is a deterministic run of the controller against the in-process simulated devices
(``sim_backend.loopback``) in simulated time, recorded by ``logs.recorder.SessionRecorder``.
Regenerate them only when a change of the control law is *meant* to change its outputs
(``cheope replay tests/data/<file> --verify`` shows the first difference): the point of the
files is that an unintended change fails the test suite.
"""

from __future__ import annotations

import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent.parent))

from controller.assembly import build_law
from controller.config import load_config
from controller.shell.loop import CycleLoop, SimulatedTime
from logs.recorder import SessionRecorder, session_metadata
from sim_backend.loopback import LoopbackExchange

SESSIONS = {
    # the circle: configuring, enabling, holding, a quarter lap, braking, shut-down
    "path_quarter_lap.mcap": ({"task.path.laps": 0.25, "task.path.ramp_s": 0.2}, 10.0),
    # the contour task up to 1 s of tracking: enabling, the move to the start point, the tare,
    # the approach (from 3 mm out, 1 mm from the disk, no placement tolerance: a small file), contact, the
    # force loop and the normal tracker, with the drives' effort witness beside the sensor
    "contour_contact.mcap": (
        {
            "task.kind": "contour",
            "task.contour.approach_clearance_m": 0.003,
            "task.contour.placement_tolerance_m": 0.0,
        },
        3.5,
    ),
}


def record(path: Path, overrides: dict, max_s: float) -> int:
    cfg = load_config(overrides=overrides)
    clock = SimulatedTime()
    law = build_law(cfg)
    exchange = LoopbackExchange(cfg, clock.clock)
    path.unlink(missing_ok=True)
    # 64 kB chunks: simulated time outruns flush_interval_s, and the tests that cut a file need several
    with SessionRecorder(
        path,
        session_metadata(cfg, {"generator": "tests/data/regenerate.py"}),
        clock=clock.clock,
        phase_name=law.task.phase_name,
        lossless=True,
        chunk_size_bytes=64 * 1024,
    ) as rec:
        loop = CycleLoop(
            law, exchange, cfg.period_s, cfg.loop.collect_fraction, clock, clock.clock, observers=(rec,)
        )
        _, stats = loop.run(law.initial_state(), max_s)
    return stats.cycles


if __name__ == "__main__":
    for name, (overrides, max_s) in SESSIONS.items():
        n = record(HERE / name, overrides, max_s)
        print(f"{name}: {n} cycles, {(HERE / name).stat().st_size} bytes")
