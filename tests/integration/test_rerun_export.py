"""Conversion of a recording to Rerun on a headless machine: the .rrd holds the expected entities."""

from __future__ import annotations

from pathlib import Path

from controller.cli import main
from logs.rerun_export import export

DATA = Path(__file__).resolve().parents[1] / "data"

ROBOT = {"/world/axes", "/world/base", "/world/sliders", "/world/rods", "/world/platform", "/world/tcp",
         "/world/tcp_trail", "/world/force"}
PLOTS = {f"/plots/actuators/{k}_{j}" for k in ("target", "position") for j in (1, 2, 3)} | {
    "/plots/force/fx", "/plots/force/fy", "/plots/force/fz", "/plots/loop/period_ms", "/plots/loop/wake_error_us",
    "/plots/loop/step_us"}


def _entities(rrd: Path) -> set[str]:
    from rerun.chunk import RrdReader

    reader = RrdReader(rrd)
    assert reader.blueprints(), "the .rrd carries no blueprint"
    return set(reader.stream().collect().schema().entity_paths())


def test_the_rrd_holds_the_robot_the_plots_and_the_events(tmp_path):
    out = tmp_path / "path.rrd"
    from logs.reader import read_info

    result = export(DATA / "path_quarter_lap.mcap", out)
    recorded_cycles = read_info(DATA / "path_quarter_lap.mcap").message_counts["/cycle"]
    assert result.output == out and not result.spawned and result.cycles == recorded_cycles > 500
    entities = _entities(out)
    assert ROBOT | PLOTS | {"/events", "/world/reference_path"} <= entities
    assert "/plots/normal_force_error" not in entities  # the path task has no force loop


def test_the_contour_session_adds_the_workpiece_and_the_normal_force_error(tmp_path):
    out = tmp_path / "contour.rrd"
    export(DATA / "contour_contact.mcap", out)
    entities = _entities(out)
    assert {"/world/workpiece/rim", "/world/workpiece/expected", "/plots/normal_force_error"} <= entities


def test_without_a_display_the_viewer_is_not_spawned_and_the_file_is_written_beside(tmp_path, monkeypatch, capsys):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    src = tmp_path / "s.mcap"
    src.write_bytes((DATA / "path_quarter_lap.mcap").read_bytes())
    assert main(["replay", str(src), "--rerun"]) == 0
    out = capsys.readouterr().out
    assert "no display" in out and str(tmp_path / "s.rrd") in out
    assert (tmp_path / "s.rrd").stat().st_size > 10_000


def test_a_truncated_recording_converts_what_is_readable(tmp_path, capsys):
    data = (DATA / "path_quarter_lap.mcap").read_bytes()
    src = tmp_path / "t.mcap"
    src.write_bytes(data[: int(len(data) * 0.6)])
    assert main(["replay", str(src), "--rerun", str(tmp_path / "t.rrd")]) == 0
    out = capsys.readouterr().out
    assert "wrote" in out and "truncated" in out
    assert "/world/rods" in _entities(tmp_path / "t.rrd")


def test_a_file_without_cycles_is_one_clear_error(tmp_path, capsys):
    src = tmp_path / "empty.mcap"
    src.write_bytes(b"\x89MCAP0\r\n")
    assert main(["replay", str(src), "--rerun", str(tmp_path / "e.rrd")]) == 2
    assert "no readable control cycles" in capsys.readouterr().err
