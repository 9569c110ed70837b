"""Conversion of a recording to Rerun on a headless machine: the .rrd holds the expected entities."""

from __future__ import annotations

from pathlib import Path

from controller.cli import main
from logs.rerun_export import export

DATA = Path(__file__).resolve().parents[1] / "data"

# Cheope as solid primitives (logs/robot_drawing.py -> logs/rerun_scene.py): entity -> archetype
CHEOPE_SOLIDS = {
    "/world/base/cylinders": "Cylinders3D",
    "/world/guides/capsules": "Capsules3D",
    "/world/sliders/boxes": "Boxes3D",
    "/world/rods/capsules": "Capsules3D",
    "/world/platform/cylinders": "Cylinders3D",
    "/world/platform/spheres": "Ellipsoids3D",
    "/world/tool/cylinders": "Cylinders3D",
}
ROBOT = set(CHEOPE_SOLIDS) | {"/world/tcp", "/world/tcp_trail", "/world/force"}
PLOTS = {f"/plots/actuators/{k}_{j}" for k in ("target", "position") for j in (1, 2, 3)} | {
    "/plots/force/fx",
    "/plots/force/fy",
    "/plots/force/fz",
    "/plots/loop/period_us",
    "/plots/loop/wake_error_us",
    "/plots/loop/step_us",
}


def _entities(rrd: Path) -> set[str]:
    from rerun.chunk import RrdReader

    reader = RrdReader(rrd)
    assert reader.blueprints(), "the .rrd carries no blueprint"
    return set(reader.stream().collect().schema().entity_paths())


def _archetypes(rrd: Path) -> dict[str, set[str]]:
    """Entity path -> the archetypes logged to it, read back with Rerun's own reader."""
    from rerun.chunk import RrdReader

    out: dict[str, set[str]] = {}
    for c in RrdReader(rrd).stream().collect().schema().component_columns():
        out.setdefault(c.entity_path, set()).add(str(c.archetype).rsplit(".", 1)[-1])
    return out


def _blueprint_views(rrd: Path) -> list[str]:
    """The class of every view in the .rrd's blueprint ('3D', 'TimeSeries', 'TextLog')."""
    from rerun.chunk import RrdReader

    reader = RrdReader(rrd)
    views = []
    for chunk in reader.stream(store=reader.blueprints()[0]).to_chunks():
        batch = chunk.to_record_batch()
        if "ViewBlueprint:class_identifier" in batch.schema.names:
            views += [v[0] for v in batch.column("ViewBlueprint:class_identifier").to_pylist()]
    return views


def test_the_robot_is_drawn_with_solid_primitives_and_the_blueprint_has_a_3d_view(tmp_path):
    out = tmp_path / "path.rrd"
    export(DATA / "path_quarter_lap.mcap", out)
    arch = _archetypes(out)
    for entity, archetype in CHEOPE_SOLIDS.items():
        assert archetype in arch.get(entity, set()), (entity, arch.get(entity))
    assert not any("LineStrips3D" in arch.get(e, set()) for e in ("/world/rods", "/world/rods/capsules")), (
        "the rods are still drawn as lines"
    )
    views = _blueprint_views(out)
    assert views.count("3D") == 1 and "TextLog" in views and views.count("TimeSeries") >= 3, views


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
    assert {
        "/world/workpiece/disk/cylinders",
        "/world/workpiece/expected_contour/lines",
        "/plots/normal_force_error",
    } <= entities


def test_without_a_display_the_viewer_is_not_spawned_and_the_file_is_written_beside(
    tmp_path, monkeypatch, capsys
):
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
    assert "/world/rods/capsules" in _entities(tmp_path / "t.rrd")


def test_a_file_without_cycles_is_one_clear_error(tmp_path, capsys):
    src = tmp_path / "empty.mcap"
    src.write_bytes(b"\x89MCAP0\r\n")
    assert main(["replay", str(src), "--rerun", str(tmp_path / "e.rrd")]) == 2
    assert "no readable control cycles" in capsys.readouterr().err


def test_the_rerun_viewer_importer_draws_the_robot_of_a_recording_it_opens(tmp_path):
    """``rerun FILE.mcap`` runs ``rerun-importer-cheope FILE --recording-id ID`` (the venv's bin on PATH):
    its standard output is the robot, the plots and the blueprint, in the viewer's recording."""
    import subprocess
    import sys

    from rerun.chunk import RrdReader

    importer = Path(sys.executable).parent / "rerun-importer-cheope"
    rrd = tmp_path / "from_importer.rrd"
    with rrd.open("wb") as out:
        r = subprocess.run(
            [str(importer), str(DATA / "path_quarter_lap.mcap"), "--recording-id", "the-viewers-id"],
            stdout=out,
            stderr=subprocess.PIPE,
            timeout=120,
            check=False,
        )
    assert r.returncode == 0, r.stderr
    assert _entities(rrd) >= ROBOT | PLOTS
    assert [str(e.recording_id) for e in RrdReader(rrd).recordings()] == ["the-viewers-id"]
    # not a cheope recording: "not mine" (66), nothing on standard output
    other = tmp_path / "other.mcap"
    other.write_bytes(b"\x89MCAP0\r\n" + bytes(100))
    for path in (other, DATA.parent / "conftest.py"):
        r = subprocess.run([str(importer), str(path)], capture_output=True, timeout=60, check=False)
        assert (r.returncode, r.stdout) == (66, b""), r.stderr
