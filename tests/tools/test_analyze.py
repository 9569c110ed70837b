"""``cheope analyze`` on the default geometry."""

from __future__ import annotations

from controller.tools.analysis.cheope_plots import analyze_cheope


def test_analyze_writes_the_plots_and_reports_the_indices(cfg, tmp_path):
    report = analyze_cheope(cfg, tmp_path)
    names = sorted(p.name for p in tmp_path.glob("*.png"))
    assert names == ["cheope_ellipses.png", "cheope_path_margins.png", "cheope_workspace.png"]
    assert all((tmp_path / n).stat().st_size > 20_000 for n in names)
    assert abs(report["centre_condition_number"] - 2.49) < 0.01
    assert report["force_capacity_x_over_y"] > 1.0 and report["velocity_capacity_y_over_x"] > 1.0
    assert report["path_max_condition_number"] < 4.5
    assert report["path_max_joint_swing_deg"] < 22.0
    assert report["path_min_inverse_measure"] > cfg.robot.margins.min_inverse_measure
