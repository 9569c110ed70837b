"""``cheope contour-stress``: the contour task against what no scenario was tuned to.

The contour scan (``contour_scan.py``) holds the disturbances the task was designed around; this
scan holds the ones an outside tester brings on day one, in simulated time (deterministic),
recorded like the scan (``--record DIR``). Each scenario runs the scan's three laps (40, 60, 60
mm/s) and reports the simulator's **true** contact force, how far the tool (the simulator's true
TCP) strayed from the part while tracking and where it ended, and the outcome:

- **the part misplaced** in 8 directions by the approach clearance and by twice it (5 and 10 mm),
  and by the placement tolerance (15 mm) in 4; by more than the tolerance (a part touching the
  staging point, where the tare is taken: not meant to be ridden through);
- **bumps and steps** of 1-4 mm, 2-30 mm long, and notches of 2 and 4 mm, at 8 places;
- **the sensor's offset** stepping by +-5 to +-60 N, and drifting by +-5 to +-60 N over 10 s;
- **sensor spikes** of +-30 to +-60 N lasting 0.5 and 2 s;
- **tares in contact**: a phantom force on the sensor during the tare, a part touching the staging point;
- **combinations** of our own: a misplaced part with an offset step, a bump where the approach lands,
  a spike during the approach, a stale sensor during the approach, an ellipse misplaced;
- **the loop held up** (the simulator's ``stall`` fault: it wakes that late and skips the deadlines
  it missed): 9.6 ms every 2.5 s, 30 ms once, and 9.6 ms every 0.5 s on a bump in lap 1.

Outcomes: ``DONE``; ``retracted`` (the task retracted and named the cause); ``backed off`` (the
safety layer's protective stop, ``controller/core/contact_guard.py``, named the cause); anything
else (a quick stop) is a failure. Which scenarios are meant to be ridden through, and why not the
others, is in each scenario's ``ride_through``: a measured force the safety limit forbids (a spike
that reads past 60 N: the limits act on the larger of sensor and witness) and a sensor that drifts
faster than the task can re-tare end in a named retract by design.

Targets (issue "Force control safe by design"): no run's true contact force above
``safety.max_contact_force_n``; no run ends with the tool further from the part than the envelope's
margin unless it retracted or backed off with a named cause; at least 90 % of the scenarios to ride
through end DONE; every other one retracts or backs off with a named cause.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

from controller.config import Config, load_config
from controller.tools.contour.scan import (
    ContourScenario,
    Progress,
    lap_places,
    run_scenarios,
    scan_config,
)

NAMED_ENDS = ("retracted", "backed off")
# The simulated robot's start 20 mm further out than the default's (TCP at (0.11, 0, 0.5) m instead of
# (0.09, 0, 0.5)): for a staging point that a part lies over, or that lies further out.
HOME_FURTHER_OUT = ("sim.drive.initial_positions_m", [0.74266, 0.56056, 0.38677])
RIDE_THROUGH_DONE_FRACTION = 0.9


def _places(base: Config) -> tuple[dict[str, float], dict[str, object]]:
    """Times [s] of an undisturbed run: the tare, the approach, and 8 places in laps 2 and 3."""
    places, phases, row = lap_places(base, per_lap=4)
    if len(phases) < 2:
        raise RuntimeError(f"the undisturbed run ended {row['outcome']} ({row['cause']}) before its places")
    return {**phases, **{f"place{k + 1}": t for k, t in enumerate(places)}}, row


def scenarios(t: dict[str, float], period_s: float) -> Iterator[ContourScenario]:
    place = [t[f"place{k}"] for k in range(1, 9)]
    # -- the part misplaced: by the clearance, twice it (the target), the tolerance, beyond
    for distance_mm, directions in ((5, 8), (10, 8), (15, 4)):
        for k in range(directions):
            a = 2.0 * math.pi * k / directions
            centre = [round(distance_mm * 1e-3 * math.cos(a), 6), round(distance_mm * 1e-3 * math.sin(a), 6)]
            yield ContourScenario(
                f"part {distance_mm} mm off towards {math.degrees(a):.0f} deg",
                overrides=(("sim.workpiece.centre_m", centre),),
            )
    for distance_mm in (21, 25):  # the staging point (the tare's) inside the part: no way to tare there
        yield ContourScenario(
            f"part {distance_mm} mm off towards the approach (over the staging point; the robot starts 20 mm out)",
            overrides=(("sim.workpiece.centre_m", [distance_mm * 1e-3, 0.0]), HOME_FURTHER_OUT),
            ride_through=False,
        )
    # -- bumps (depth < 0) and notches
    angles = (30.0, 75.0, 120.0, 165.0, 210.0, 255.0, 300.0, 345.0)
    k = 0
    for height_mm in (1, 2, 3, 4):
        for length_mm in (2, 5, 10, 30):
            yield ContourScenario(
                f"bump {height_mm} mm x {length_mm} mm",
                features=(
                    {"angle_deg": angles[k % 8], "length_m": length_mm * 1e-3, "depth_m": -height_mm * 1e-3},
                ),
            )
            k += 1
    for depth_mm in (2, 4):
        for length_mm in (5, 30):
            yield ContourScenario(
                f"notch {depth_mm} mm x {length_mm} mm",
                features=(
                    {"angle_deg": angles[k % 8], "length_m": length_mm * 1e-3, "depth_m": depth_mm * 1e-3},
                ),
            )
            k += 1
    # A slot as wide as the point probe's wobble: met head-on, the back-off along the force went into
    # the slot's other wall (77 N) and the quick stop left the tool pressed there at 84 N; a carriage
    # jammed for 50 ms let go mid-back-off (178 N, left at 112 N at the lap speed 97 mm/s). Both now
    # retrace the way in (an outside tester, 2026-12-06).
    yield ContourScenario(
        "point probe into a 2 mm x 10 mm slot",
        features=({"angle_deg": 90.0, "length_m": 0.002, "depth_m": 0.01},),
        ride_through=False,
    )
    yield ContourScenario(
        "carriage 1 jammed for 50 ms in lap 2", (f"block:1@{place[2]}+0.05",), ride_through=False
    )
    # -- the sensor's offset: steps (a drift over 10 ms) and drifts over 10 s
    for i, step in enumerate((5.0, -5.0, 10.0, -10.0, 20.0, -20.0, 40.0, -40.0, 60.0, -60.0)):
        yield ContourScenario(
            f"offset step {step:+g} N",
            (f"drift={step / 0.01:g}@{place[i % 8]}+0.01",),
            ride_through=abs(step) < 50.0,  # 60 N on 10 N of contact reads past the 60 N limit
        )
    for i, total in enumerate((5.0, -5.0, 20.0, -20.0, 60.0, -60.0)):
        yield ContourScenario(
            f"offset drifting {total:+g} N over 10 s",
            (f"drift={total / 10.0:g}@{place[i % 4]}+10",),
            ride_through=abs(total) <= 20.0,  # 6 N/s: re-taring every second, more than 3 a lap
        )
    # -- spikes on the measurement (the sensor reads F more along X; nothing touches the tool)
    i = 0
    for amplitude in (30.0, -30.0, 45.0, -45.0, 60.0, -60.0):
        for duration in (0.5, 2.0):
            yield ContourScenario(
                f"spike {amplitude:+g} N for {duration:g} s",
                (f"force={amplitude:g}@{place[i % 8]}+{duration}",),
                ride_through=amplitude < 50.0,  # +60 N on 10 N of contact reads past the 60 N limit
            )
            i += 1
    # -- tares in contact
    tare = t["TARE"]
    yield ContourScenario("phantom 15 N on the sensor during the tare", (f"force=15@{tare - 0.05:.3f}+0.3",))
    yield ContourScenario("phantom -8 N on the sensor from the tare on", (f"force=-8@{tare - 0.05:.3f}",))
    # -- combinations of our own
    approach = t["APPROACH"]
    yield ContourScenario(
        "part 8 mm off towards the approach, offset step -20 N in lap 2",
        (f"drift=-2000@{place[1]}+0.01",),
        overrides=(("sim.workpiece.centre_m", [0.008, -0.001]),),
    )
    yield ContourScenario(
        "bump 3 mm x 10 mm where the approach lands",
        features=({"angle_deg": 0.0, "length_m": 0.01, "depth_m": -0.003},),
    )
    yield ContourScenario(
        "spike +15 N for 0.3 s during the approach", (f"force=15@{approach + 0.5:.3f}+0.3",)
    )
    yield ContourScenario(  # reads past the guarded move's limit: the larger of the two acts
        "spike +30 N for 0.3 s during the approach",
        (f"force=30@{approach + 0.5:.3f}+0.3",),
        ride_through=False,
    )
    yield ContourScenario(
        "sensor stale for 0.08 s during the approach", (f"freeze@{approach + 0.5:.3f}+0.08",)
    )
    yield ContourScenario(  # past safety.sensor_stale_s: the protective stop, by design
        "sensor stale for 0.2 s during the approach",
        (f"freeze@{approach + 0.5:.3f}+0.2",),
        ride_through=False,
    )
    yield ContourScenario("sensor stale for 0.2 s in lap 2", (f"freeze@{place[2]}+0.2",), ride_through=False)
    yield ContourScenario(
        "ellipse 10 mm off towards 135 deg",
        overrides=(
            ("sim.workpiece.shape", "ellipse"),
            ("sim.workpiece.size_m", [0.075, 0.055]),
            ("sim.workpiece.centre_m", [-0.00707, 0.00707]),
            ("task.contour.expected_radius_m", 0.074),
            HOME_FURTHER_OUT,
        ),
    )
    yield ContourScenario(
        "offset step -7 N in lap 1 (a phantom wall)", (f"drift=-700@{round(t['APPROACH'] + 6.0, 3)}+0.01",)
    )
    # -- an outside tester's (7dcefb5): a sensor that lies along the contact normal, or stops changing
    touch = t["TRACKING"]  # the first contact
    yield ContourScenario("offset step -5 N as the tool touches", (f"drift=-500@{touch - 0.02:.3f}+0.01",))
    yield ContourScenario("offset drift -2 N/s through the approach", (f"drift=-2@{approach:.3f}+3",))
    yield ContourScenario(  # reads past the limit: the guard's, backing off along the drives' effort
        "spike -75 N along the normal for 0.5 s in lap 1",
        (f"force=-75@{touch + 0.65:.3f}+0.5",),
        ride_through=False,
    )
    yield ContourScenario(  # fresh and wrong: the drives' effort ends the guarded move
        "sensor stuck at its reading during the approach",
        (f"stuck@{approach + 0.5:.3f}",),
        ride_through=False,
    )
    yield ContourScenario("sensor stuck at its reading in lap 2", (f"stuck@{place[2]}",), ride_through=False)
    # -- the loop held up (the machine's hold-ups: 10 ms beside two CPU hogs, cyclictest's too)
    # (a stall fault active for one period holds up the one deadline that falls in it)
    every = 2.5  # s
    held = tuple(f"stall=0.0096@{approach + every * k:.4f}+{period_s}" for k in range(int(90.0 / every)))
    yield ContourScenario("loop held up 9.6 ms every 2.5 s from the approach on", held)
    yield ContourScenario("loop held up 30 ms in lap 2", (f"stall=0.03@{place[1]:.4f}+{period_s}",))
    yield ContourScenario(
        "bump 2 mm x 5 mm, loop held up 9.6 ms every 0.5 s in lap 1",
        tuple(f"stall=0.0096@{approach + 0.5 * k:.4f}+{period_s}" for k in range(40)),
        features=({"angle_deg": 45.0, "length_m": 0.005, "depth_m": -0.002},),
    )


def run_stress(
    base: Config | None = None,
    directory: Path | None = None,
    jobs: int = 1,
    progress: Progress | None = None,
) -> list[dict[str, object]]:
    """Every scenario; rows in the order of ``scenarios``, the undisturbed run first."""
    base = scan_config(base or load_config())
    times, undisturbed = _places(base)
    return run_scenarios(
        base,
        undisturbed,
        scenarios(times, base.period_s),
        directory,
        jobs,
        progress,
        "cheope-contour-stress-",
    )


def summary(
    rows: list[dict[str, object]], max_contact_force_n: float, envelope_margin_m: float
) -> dict[str, object]:
    n = len(rows)
    ride = [r for r in rows if r["ride_through"]]
    ride_done = sum(r["outcome"] == "DONE" for r in ride)
    named = [r for r in rows if r["outcome"] in NAMED_ENDS]
    failed = [r["scenario"] for r in rows if r["outcome"] not in ("DONE", *NAMED_ENDS)]
    strayed = [
        r["scenario"]
        for r in rows
        if float(r["final_off_part_mm"]) > envelope_margin_m * 1000.0 and r["outcome"] not in NAMED_ENDS  # type: ignore[arg-type]
    ]
    over = [r["scenario"] for r in rows if r["over_limit"]]
    # a run that ended with the tool pressed into the part past the limit (a quick stop in place)
    pressed = [r["scenario"] for r in rows if float(r["final_true_contact_force_n"]) > max_contact_force_n]  # type: ignore[arg-type]
    return {
        "scenarios": n,
        "done": sum(r["outcome"] == "DONE" for r in rows),
        "named_ends": len(named),
        "ride_through": len(ride),
        "ride_through_done": ride_done,
        "ride_through_done_percent": round(100.0 * ride_done / len(ride), 1) if ride else 100.0,
        "failed": failed,
        "over_limit": over,
        "left_pressed": pressed,
        "strayed": strayed,
        "max_true_contact_force_n": max(float(r["max_true_contact_force_n"]) for r in rows),  # type: ignore[arg-type]
        "max_off_part_mm": max(float(r["max_off_part_mm"]) for r in rows),  # type: ignore[arg-type]
        "targets_met": not over
        and not pressed
        and not strayed
        and not failed
        and ride_done >= RIDE_THROUGH_DONE_FRACTION * len(ride),
    }


def format_table(rows: list[dict[str, object]], max_contact_force_n: float, envelope_margin_m: float) -> str:
    lines = [
        "| scenario | ride through | outcome | true force: max / end [N] | off the part: max / end [mm] | losses | cause |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in rows:
        lines.append(
            f"| {r['scenario']} | {'yes' if r['ride_through'] else 'no'} | {r['outcome']} | "
            f"{r['max_true_contact_force_n']:.1f}{' **over**' if r['over_limit'] else ''} / "
            f"{r['final_true_contact_force_n']:.1f} | {r['max_off_part_mm']:.1f} / {r['final_off_part_mm']:.1f} | {r['contact_losses']} | {r['cause'] or '-'} |"
        )
    s = summary(rows, max_contact_force_n, envelope_margin_m)
    lines.append("")
    lines.append(
        f"{s['scenarios']} scenarios: {s['done']} DONE, {s['named_ends']} retracted or backed off with a "
        f"named cause; {s['ride_through_done']} of the {s['ride_through']} to ride through DONE "
        f"({s['ride_through_done_percent']} %); failed: {', '.join(s['failed']) or 'none'}; over the "  # type: ignore[arg-type]
        f"{max_contact_force_n:g} N limit: {', '.join(s['over_limit']) or 'none'} (largest true contact force "  # type: ignore[arg-type]
        f"{s['max_true_contact_force_n']:.1f} N); left pressed past it: {', '.join(s['left_pressed']) or 'none'}; "  # type: ignore[arg-type]
        f"ended off the part unnamed: {', '.join(s['strayed']) or 'none'} "  # type: ignore[arg-type]
        f"(furthest while tracking {s['max_off_part_mm']:.1f} mm); targets {'met' if s['targets_met'] else 'NOT met'}"
    )
    return "\n".join(lines)
