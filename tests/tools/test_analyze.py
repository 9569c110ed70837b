"""``cheope analyze`` on the default geometry."""

from __future__ import annotations

from controller.robots.cheope.analysis import analyze_cheope


def test_analyze_writes_the_plots_and_reports_the_indices(cfg, tmp_path):
    report = analyze_cheope(cfg, tmp_path)
    names = sorted(p.name for p in tmp_path.glob("*.png"))
    assert names == ["cheope_ellipses.png", "cheope_path_margins.png", "cheope_workspace.png"]
    assert all((tmp_path / n).stat().st_size > 20_000 for n in names)
    assert abs(report["centre_condition_number"] - 2.49) < 0.01
    assert report["force_capacity_x_over_y"] > 1.0 and report["velocity_capacity_y_over_x"] > 1.0
    assert report["path_max_condition_number"] < 4.5
    assert report["path_max_joint_swing_deg"] < 22.0
    assert report["path_min_inverse_measure"] > cfg.robot.model("cheope").margins.min_inverse_measure


def test_analyze_reports_both_stiffness_ratios_and_says_which_is_which(cfg, tmp_path):
    import numpy as np

    from controller.robots.cheope.entry import build_cheope
    from controller.robots.cheope.model import jacobian

    report = analyze_cheope(cfg, tmp_path)
    jac = jacobian(
        build_cheope(cfg.robot.model("cheope")).geometry,
        np.asarray(cfg.task.model("path").center_m, dtype=float),
    )
    k = jac.T @ jac  # K / k: the ratios do not depend on the actuator stiffness
    ex, ey = np.eye(3)[0], np.eye(3)[1]
    k2_inv = np.linalg.inv(k @ k)
    # radius of {K d : |d| <= 1} along u: 1 / sqrt(u^T K^-2 u)
    image = np.sqrt(ey @ k2_inv @ ey) / np.sqrt(ex @ k2_inv @ ex)
    directional = (ex @ k @ ex) / (ey @ k @ ey)  # u^T K u
    assert report["stiffness_image_reach_x_over_y"] == round(float(image), 3)
    assert report["stiffness_directional_x_over_y"] == round(float(directional), 3)
    assert abs(image - directional) > 0.5  # they are different figures: a name must say which
    assert "stiffness_x_over_y" not in report


def test_every_panel_of_analyze_has_axis_labels_and_a_title(cfg, tmp_path, monkeypatch):
    from matplotlib.figure import Figure

    seen: dict[str, list[tuple[str, str, str]]] = {}
    save = Figure.savefig

    def recording_savefig(fig, fname, *args, **kwargs):
        panels = [ax for ax in fig.axes if ax.axison and ax.get_label() != "<colorbar>"]
        seen[str(fname)] = [(ax.get_xlabel(), ax.get_ylabel(), ax.get_title()) for ax in panels]
        return save(fig, fname, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", recording_savefig)
    analyze_cheope(cfg, tmp_path)
    assert len(seen) == 3
    for fname, panels in seen.items():
        assert panels, fname
        for xlabel, ylabel, title in panels:
            assert xlabel and ylabel, (fname, title)
            assert "[" in xlabel and "[" in ylabel, (fname, xlabel, ylabel)  # a unit, or [-] when none
