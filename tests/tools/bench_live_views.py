"""What the 3D scene and the live views cost the recorder's writer process, per control cycle.

    .venv/bin/python tests/tools/bench_live_views.py [--seconds 20] [--repeats 3]
    .venv/bin/pytest tests/tools/bench_live_views.py -m bench -s -q

The loop thread's side does not change with them: it hands the writer process the same record
per cycle whether or not the writer draws or streams (logs/recorder.py). The writer's side is
measured here: the records of a contour session of ``--seconds`` of simulated time at 400 Hz
are captured once (the production recorder's ``pack_record``), then fed to the writer's
``SessionWriter`` in this process once per variant and repeat; the CPU time of the whole
process (``time.process_time``: every thread, so also the Rerun and Foxglove SDKs' own) from
the first record to the closed file and closed views, divided by the cycles. The start-up
(imports, spawning) is not in it.

- ``no scene``: ``recording.scene_rate_hz = 0.1`` (the fixed parts once, one frame in 10 s),
  what the recorder cost before the scene;
- ``scene 20 Hz``: the default ``/scene`` channel;
- ``+ foxglove``: and the Foxglove WebSocket server (no client connected);
- ``+ rerun``: and the Rerun stream to a ``rerun --save`` gRPC server on loopback.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

import pytest

from controller.assembly import build_law
from controller.config import load_config
from controller.monitoring.zenoh_session import free_loopback_port
from controller.shell.loop import CycleLoop, SimulatedTime
from logs.recorder import SessionRecorder, session_metadata
from sim_backend.loopback import LoopbackExchange


def capture_records(seconds: float, directory: Path) -> list[tuple[object, ...]]:
    """Every record the loop hands the writer during a simulated-time contour session."""
    import logs.recorder as recorder_module

    records: list[tuple[object, ...]] = []
    original = recorder_module.pack_record

    def capture(record: tuple[object, ...]) -> bytes:
        records.append(record)
        return original(record)

    cfg = load_config(overrides={"task.kind": "contour"})
    clock = SimulatedTime()
    law = build_law(cfg)
    exchange = LoopbackExchange(cfg, clock.clock)
    recorder_module.pack_record = capture  # type: ignore[assignment]
    try:
        with SessionRecorder(
            directory / "capture.mcap",
            session_metadata(cfg),
            clock=clock.clock,
            phase_name=law.task.phase_name,
            lossless=True,
        ) as rec:
            loop = CycleLoop(
                law, exchange, cfg.period_s, cfg.loop.collect_fraction, clock, clock.clock, observers=(rec,)
            )
            loop.run(law.initial_state(), seconds)
    finally:
        recorder_module.pack_record = original
    return records


def writer_cpu_per_cycle_us(
    records: list[tuple[object, ...]], recording: dict[str, object], out: Path
) -> float:
    """Feed the captured records to a SessionWriter whose configuration has ``recording`` changed."""
    from logs import messages as m
    from logs.session_writer import CYCLE, END, SETUP, SessionWriter

    setup = records[0]
    assert setup[0] == SETUP
    settings = dict(setup[1])  # type: ignore[call-overload]
    meta = dict(settings["metadata"])
    table = json.loads(meta[m.META_CONFIG]["json"])
    table["recording"].update(recording)
    meta[m.META_CONFIG] = {"json": json.dumps(table)}
    settings.update(metadata=meta, path=str(out))
    writer = SessionWriter(settings)
    cycles = sum(1 for r in records if r[0] == CYCLE)
    t0 = time.process_time()
    for r in records[1:]:
        if r[0] != END:
            writer.write(r)
    writer.finish(0, 0)
    if writer.live is not None:
        writer.live.close()
    return (time.process_time() - t0) / cycles * 1e6


def _rerun_binary() -> str:
    """The Rerun executable itself: ``.venv/bin/rerun`` is a Python wrapper that starts it as a child,
    which would outlive a terminated wrapper."""
    import rerun_cli

    return str(Path(rerun_cli.__file__).parent / "rerun")


def run(seconds: float, repeats: int) -> dict[str, list[float]]:
    results: dict[str, list[float]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        records = capture_records(seconds, d)
        rerun_port = free_loopback_port()
        server = subprocess.Popen(
            [
                _rerun_binary(),
                "--bind",
                "127.0.0.1",
                "--port",
                str(rerun_port),
                "--save",
                str(d / "live.rrd"),
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        try:
            variants: dict[str, dict[str, object]] = {
                "no scene": {"scene_rate_hz": 0.1},
                "scene 20 Hz": {},
                "scene 20 Hz + foxglove": {"live_foxglove": "127.0.0.1:0"},  # a free port each time
                "scene 20 Hz + rerun": {"live_rerun": f"rerun+http://127.0.0.1:{rerun_port}/proxy"},
            }
            for k in range(repeats):
                for name, ov in variants.items():
                    us = writer_cpu_per_cycle_us(
                        records, ov, d / f"{k}-{len(results.get(name, []))}-{hash(name)}.mcap"
                    )
                    results.setdefault(name, []).append(us)
        finally:
            server.terminate()
            server.wait()
    return results


def report(results: dict[str, list[float]], seconds: float) -> str:
    runs = len(next(iter(results.values())))
    lines = [
        (
            f"writer process CPU per 400 Hz cycle, contour task, {seconds:g} s simulated, {runs} runs each: "
            "median (min-max) [us]"
        )
    ]
    for name, v in results.items():
        lines.append(f"  {name:24s} {statistics.median(v):7.1f} ({min(v):.1f}-{max(v):.1f})")
    return "\n".join(lines)


@pytest.mark.bench
def test_bench_live_views() -> None:
    print("\n" + report(run(10.0, 3), 10.0))


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args()
    print(report(run(a.seconds, a.repeats), a.seconds))
