"""The guarded moves' fastest speeds against the cell's stiffness, and what the simulator's part meets at them.

    .venv/bin/python -m controller.tools.contour.guarded_speeds

For each loop rate and sensor mount stiffness (in series with the shipped part's), the cell is declared
as it is (``safety.contact.cell_stiffness_n_m``), the search and approach run at 0.999 of the
fastest speed ``controller/core/contact_budget.py`` allows, and the part lies 15 mm towards the
approach, so the search meets it. Each row: the fastest speed (where the model predicts the
task's ``max_force_n``), and the simulator's true largest contact force of the contour run (in
simulated time: deterministic). The docs' table (docs/concepts/contour-tracking.md) is this command's output.
"""

from __future__ import annotations

import argparse

from controller.config import load_config
from controller.core.contact_budget import StoppingModel
from controller.tools.contour.scan import ContourScenario, run_contour_scenario
from sim_backend.environment import series_stiffness_n_m

CASES = (
    (400.0, 3.0e5),
    (400.0, 1.0e7),
    (400.0, 1.0e8),
    (1000.0, 3.0e5),
    (1000.0, 1.0e7),
    (250.0, 3.0e5),
    (250.0, 1.0e7),
)
TOWARDS_THE_APPROACH = ContourScenario(
    "part 15 mm towards the approach", overrides=(("sim.workpiece.centre_m", [0.015, 0.0]),)
)


def run_case(rate_hz: float, sensor_stiffness_n_m: float) -> dict[str, float | str]:
    """One row: the cell declared as it is, the guarded moves at the fastest speed it allows."""
    part_n_m = load_config().sim.workpiece.contact_stiffness_n_m
    cell = series_stiffness_n_m(part_n_m, sensor_stiffness_n_m)
    base = {"task.kind": "contour", "loop.rate_hz": rate_hz, "safety.contact.cell_stiffness_n_m": cell}
    cfg = load_config(overrides=base)
    c, a = cfg.task.model("contour"), cfg.actuators
    stop = StoppingModel(cfg.period_s, a.max_acceleration_m_s2, a.max_jerk_m_s3)
    speed = 0.999 * stop.fastest_m_s(c.max_force_n - c.contact_force_n, cell)
    run = {
        **base,
        "sim.workpiece.sensor_stiffness_n_m": sensor_stiffness_n_m,
        "task.contour.search_speed_m_s": speed,
        "task.contour.approach_speed_m_s": min(c.approach_speed_m_s, speed),
    }
    row = run_contour_scenario(load_config(overrides=run), TOWARDS_THE_APPROACH, None)
    return {
        "cell_n_m": cell,
        "fastest_mm_s": speed / 0.999 * 1000.0,
        "true_max_n": float(row["max_true_contact_force_n"]),  # type: ignore[arg-type]
        "limit_n": c.max_force_n,
        "outcome": str(row["outcome"]),
    }


def main(argv: list[str] | None = None) -> None:
    # no options: the parser gives --help and refuses a stray argument by name, where the table
    # used to start its minute-long runs whatever was asked
    argparse.ArgumentParser(prog="guarded_speeds", description=__doc__.splitlines()[0]).parse_args(argv)
    print("| loop | sensor mount [N/m] | cell [N/m] | fastest [mm/s] | true force at it [N] | outcome |")
    print("| --- | --- | --- | --- | --- | --- |")
    for rate_hz, mount in CASES:
        r = run_case(rate_hz, mount)
        print(
            f"| {rate_hz:g} Hz | {mount:.0e} | {r['cell_n_m']:.3g} | {r['fastest_mm_s']:.2f} | "
            f"{r['true_max_n']:.1f} | {r['outcome']} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
