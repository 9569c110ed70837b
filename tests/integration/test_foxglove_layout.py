"""The shipped Foxglove layout works on a recording of a path task and of a contour task.

Each session is recorded by the production recorder (its writer process) from the in-process
simulated devices in simulated time, and read back with the ``mcap`` reader. The live side of the
same check (the live server serves every topic the layout names) is in test_live_views.py.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import pytest
from foxglove_layout_paths import named_topics, panels, plot_paths, resolve
from mcap.reader import make_reader

from controller.assembly import build_law
from controller.config import load_config
from controller.shell.loop import CycleLoop, SimulatedTime
from logs import messages as m
from logs.live_views import FoxgloveLive
from logs.recorder import SessionRecorder, session_metadata
from sim_backend.loopback import LoopbackExchange


def _record(path: Path, task_kind: str, max_s: float) -> None:
    cfg = load_config(overrides={"task.kind": task_kind})
    clock = SimulatedTime()
    law = build_law(cfg)
    exchange = LoopbackExchange(cfg, clock.clock)
    with SessionRecorder(
        path, session_metadata(cfg), clock=clock.clock, phase_name=law.task.phase_name, lossless=True
    ) as rec:
        loop = CycleLoop(
            law, exchange, cfg.period_s, cfg.loop.collect_fraction, clock, clock.clock, observers=(rec,)
        )
        loop.run(law.initial_state(), max_s)


@pytest.fixture(scope="module")
def recordings(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A path and a contour session, long enough for the contour task to touch the disk."""
    out = {}
    for kind, seconds in (("path", 1.0), ("contour", 6.0)):
        out[kind] = tmp_path_factory.mktemp(kind) / f"{kind}.mcap"
        _record(out[kind], kind, seconds)
    return out


def _read(path: Path) -> tuple[Counter[str], list[object]]:
    """Messages per topic, and the decoded /cycle messages."""
    from controller.messages import cheope_pb2 as pb

    counts: Counter[str] = Counter()
    cycles = []
    with path.open("rb") as f:
        for _, channel, message in make_reader(f).iter_messages():
            counts[channel.topic] += 1
            if channel.topic == m.TOPIC_CYCLE:
                cycles.append(pb.Cycle.FromString(message.data))
    return counts, cycles


def test_the_layout_names_the_scene_the_reference_the_log_and_the_cycle():
    assert named_topics() == {m.TOPIC_SCENE, m.TOPIC_TCP_REFERENCE, m.TOPIC_LOG, m.TOPIC_CYCLE}
    (three_d,) = panels("3D")
    assert m.TOPIC_SCENE in three_d["topics"]


def test_the_live_server_serves_every_topic_the_layout_names():
    assert named_topics() <= set(FoxgloveLive.TOPICS)


@pytest.mark.parametrize("task_kind", ["path", "contour"])
def test_every_topic_the_layout_names_is_in_the_recording_and_every_plot_shows_data(recordings, task_kind):
    counts, cycles = _read(recordings[task_kind])
    missing = {t for t in named_topics() if counts[t] == 0}
    assert not missing, f"no message on {missing} in the {task_kind} recording"
    for paths in plot_paths():
        shown = [p for p in paths if any(resolve(c, p) is not None for c in cycles)]
        assert shown, f"a plot with {paths} is empty for a {task_kind} recording"


def test_every_series_of_the_layout_shows_data_in_a_path_or_a_contour_recording(recordings):
    cycles = [c for kind in ("path", "contour") for c in _read(recordings[kind])[1]]
    for path in (p for paths in plot_paths() for p in paths):
        assert any(resolve(c, path) is not None for c in cycles), path
