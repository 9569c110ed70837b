"""The report as a table: every figure beside its ratio to the machine's floor."""

from __future__ import annotations

from collections.abc import Callable

from controller.shell.thread_usage import UsageBetween
from controller.tools.bench.statistics import Json


def format_table(report: Json) -> str:
    lines = []
    cases = report["cases"]
    header = f"{'':34}" + "".join(f"{c['case']:>24}" for c in cases)
    lines.append(header)

    def row(label: str, fn: Callable[[Json], str]) -> None:
        lines.append(f"{label:34}" + "".join(f"{fn(c):>24}" for c in cases))

    def q(d: Json, keys: tuple[str, ...] = ("p50", "p99", "p99_9", "max")) -> str:
        return "/".join(f"{d[k]:.0f}" for k in keys)

    row("achieved rate [Hz]", lambda c: f"{c['achieved_rate_hz']:.2f}")
    row("period error p50/p99/p99.9/max us", lambda c: q(c["period_error_us"]))
    row("wake latency p50/p99/p99.9/max us", lambda c: q(c["wake_latency_us"]))
    row("late cycles per 10 000", lambda c: f"{c['late_per_10k']:.1f} ({c['overruns']} skipped)")
    row("step compute p50/p99 us", lambda c: q(c["step_us"], ("p50", "p99")))
    row("SYNC out -> last TPDO in p50/p99 us", lambda c: q(c["sync_to_last_tpdo_us"], ("p50", "p99")))
    row("last TPDO -> outputs ready p50/p99", lambda c: q(c["tpdo_to_ready_us"], ("p50", "p99")))
    row("last TPDO -> RPDOs out p50/p99 us", lambda c: q(c["tpdo_to_rpdo_us"], ("p50", "p99")))
    row(
        "CPU loop thread / process [%]",
        lambda c: "{} / {}".format(
            c["cpu_percent_of_one_core"]["loop_thread"], c["cpu_percent_of_one_core"]["controller_process"]
        ),
    )
    row("CPU process excluding the spin [%]", _process_without_spin)
    row("CPU simulator [%]", lambda c: f"{c['cpu_percent_of_one_core']['simulator_process']}")
    row(
        "bus load computed / measured [%]",
        lambda c: "{:.1f} / {:.1f}".format(
            c["bus_load_percent"]["computed"], c["bus_load_percent"]["measured"]["percent"]
        ),
    )
    row("CPU MCAP writer [%]", lambda c: f"{c['cpu_percent_of_one_core'].get('writer_process')}")
    f = report["bus_frame_cost"]
    row("python-can floor ctrl / sim [%]", lambda c: "{} / {}".format(*python_can_floor_percent(c, f)))
    row("floor ctrl + step in process [%]", lambda c: _or_dash(loop_floor_percent(c, report)))
    row(
        "missing frames drive/sensor",
        lambda c: "{}/{}".format(
            (c["missing_frames"] or {}).get("drive"), (c["missing_frames"] or {}).get("sensor")
        ),
    )
    row(
        "laps 4-5 force error RMS [N]",
        lambda c: (
            "/".join(f"{lap['force_error_rms_n']:.2f}" for lap in (c.get("task_laps") or [])[3:5]) or "-"
        ),
    )
    row(
        "cyclictest p50/p99/p99.9/max us",
        lambda c: q(c["cyclictest"]["latency_us"]) if "latency_us" in c.get("cyclictest", {}) else "-",
    )
    row(
        "cyclictest late per 10 000 deadlines (wake-ups)",
        lambda c: (
            "{} ({})".format(
                c["cyclictest"]["late_deadlines_per_10k_above_us"][f"{c['cyclictest']['late_us']:g}"],
                c["cyclictest"]["per_10k_above_us"][f"{c['cyclictest']['late_us']:g}"],
            )
            if "late_ratio" in c.get("cyclictest", {})
            else "-"
        ),
    )
    row(
        "late ratio loop / cyclictest (to its wake-ups)",
        lambda c: (
            f"{c['cyclictest']['late_ratio']} ({c['cyclictest']['late_ratio_to_samples']})"
            if "late_ratio" in c.get("cyclictest", {})
            else "-"
        ),
    )
    row(
        "wake p99 ratio loop / cyclictest",
        lambda c: (
            f"{c['cyclictest'].get('wake_p99_ratio')}" if "latency_us" in c.get("cyclictest", {}) else "-"
        ),
    )
    row(
        "longest cycle us (its largest part)",
        lambda c: _longest(c.get("longest_cycle_us")),
    )
    row("CPU hogs beside", lambda c: f"{c.get('cpu_hogs', 0)}")
    row("final mode", lambda c: c["final_mode"])
    for c in cases:
        if c.get("fault_reason"):
            lines.append(f"  {c['case']}: fault: {c['fault_reason']}")
        if "error" in c.get("cyclictest", {}):
            lines.append(f"  {c['case']}: {c['cyclictest']['error']}")
        elif "command" in c.get("cyclictest", {}):
            lines.append(f"  {c['case']}: floor by `{c['cyclictest']['command']}`")
    lines.append("")
    lines.append("loop shell vs naive time.sleep(period), same busy work, alternating blocks:")
    for s in report["sleepers"]:
        for arm in ("deadline", "naive"):
            a = s[arm]
            lines.append(
                f"  {s['rate_hz']:>6g} Hz {arm:8} rate {a['achieved_rate_hz']:>9.2f} Hz  drift "
                f"{a['drift_ms_per_s']:>8.3f} ms/s  period error p50/p99/p99.9/max "
                f"{q(a['period_error_us'])} us  late/10k {a['late_per_10k']:.1f}"
            )
    lines.append("")
    w = report.get("work_per_cycle")
    if w:
        b = w["budget_per_cycle"]
        ipc = w.get("instructions_per_cycle")
        lines.append(
            f"work per cycle, {w['task']} task, cycles {w['skip']}-{w['skip'] + w['cycles'] - 1} (deterministic): "
            f"{w['bytecodes_per_cycle']:.0f} bytecodes (budget {b['bytecodes']}), {w['c_calls_per_cycle']:.0f} C calls "
            f"(budget {b['c_calls']}), {w['python_calls_per_cycle']:.0f} Python calls, "
            + (f"{ipc} instructions (callgrind), " if ipc else "")
            + f"{w['tracked_objects_left_per_cycle']} tracked objects left"
            + (f"; OVER BUDGET: {'; '.join(w['over_budget'])}" if w["over_budget"] else "")
        )
    p = report["pdo_path"]
    lines.append(
        f"cyclic PDO path, CPU per cycle (stub bus, 4 frames out, 5 in): project {p['project_cpu_us']} us, "
        f"canopen PDO objects {p['canopen_cpu_us']} us (x{p['canopen_over_project']}); wall "
        f"{p['project_wall_us']} / {p['canopen_wall_us']} us"
    )
    f = report["bus_frame_cost"]
    lines.append(
        f"python-can per frame on {f['bus']}: send p50/p99 {q(f['send_us'], ('p50', 'p99'))} us, "
        f"recv p50/p99 {q(f['recv_us'], ('p50', 'p99'))} us; own frames received back "
        f"{f['own_frames_received_back']} of {f['frames']}"
    )
    for b in report["step_breakdown"]:
        lines.append(
            f"step at {b['rate_hz']:g} Hz (in process), law {b.get('law', '?')}: "
            f"p50/p99 {q(b['step_us'], ('p50', 'p99'))} us"
        )
        interpreted = b.get("interpreted")
        if interpreted:
            ratio = (
                interpreted["step_us"]["p50"] / b["step_us"]["p50"]
                if b["step_us"]["p50"] > 0
                else float("nan")
            )
            lines.append(
                f"  the same step interpreted: p50/p99 {q(interpreted['step_us'], ('p50', 'p99'))} us "
                f"(p50 x{ratio:.2f} the compiled one's)"
            )
        r = b if "ruckig_calls_per_cycle" in b else interpreted or {}
        if "ruckig_calls_per_cycle" in r:
            lines.append(
                f"  Ruckig reported {q(r['ruckig_reported_calculation_us'], ('p50', 'p99'))} us, "
                f"Ruckig call in Python {q(r['ruckig_call_in_python_us'], ('p50', 'p99'))} us, "
                f"{r['ruckig_calls_per_cycle']} calls/cycle: Ruckig {r['ruckig_share_of_step_percent']} % of "
                f"the step (interpreted)"
            )
    lines.append(
        f"classical CAN 1 Mbit/s at 1 kHz: computed load {report['classical_can_1khz_computed_load_percent']} %"
        " (over the limit: refused)"
    )
    for path in report["plots"]:
        lines.append(f"plot {path}")
    return "\n".join(lines)


def _process_without_spin(case: Json) -> str:
    process, spin = (
        case["cpu_percent_of_one_core"]["controller_process"],
        case.get("spin_percent_of_one_core"),
    )
    return "-" if process is None or spin is None else f"{process - spin:.1f} (spin {spin})"


def python_can_floor_percent(case: Json, cost: Json) -> tuple[float, float]:
    """python-can's own cost per process at the case's rate, from the per-frame costs [% of a core].

    The controller sends its frames (``out`` a cycle) and receives the simulator's (``in``); the
    simulator the other way round. A bus that hands a sender its own frames back (python-can's
    udp_multicast; ``bus_frame_cost`` counts them) adds a receive for each frame sent; the
    project's bus does not (drivers/local_multicast.py).
    """
    per_cycle = case["frames_per_cycle"]
    send, recv = cost["send_us"]["p50"], cost["recv_us"]["p50"]
    echo = cost["own_frames_received_back"] / max(1, cost["frames"])
    rate = case["rate_hz"]
    received, sent = per_cycle["in"], per_cycle["out"]
    controller = rate * (sent * send + (received + echo * sent) * recv) * 1e-4
    simulator = rate * (received * send + (sent + echo * received) * recv) * 1e-4
    return round(controller, 1), round(simulator, 1)


def loop_floor_percent(case: Json, report: Json) -> float | None:
    """The loop's process can use no less than python-can's cost for its frames plus the step as it
    runs in process (``step_breakdown``, back to back, caches warm) at the case's rate [% of a core]:
    the floor of this design, against which the process's CPU without the spin compares. None when
    the step was not measured at that rate."""
    step = next(
        (b["step_us"]["p50"] for b in report["step_breakdown"] if b["rate_hz"] == case["rate_hz"]), None
    )
    if step is None:
        return None
    can, _ = python_can_floor_percent(case, report["bus_frame_cost"])
    return round(can + float(case["rate_hz"]) * float(step) * 1e-4, 1)


def _or_dash(value: object) -> str:
    return "-" if value is None else f"{value}"


def _longest(cycle: object) -> str:
    """The longest cycle's span and the part of it that took longest (controller/shell/loop.py)."""
    if not isinstance(cycle, dict) or "span" not in cycle:
        return "-"
    # the parts of its time, not the thread's usage over it (controller/shell/thread_usage.py)
    usage = {name.removesuffix("_s") for name in UsageBetween._fields}
    parts = {k: v for k, v in cycle.items() if k not in ("span", "cycle") and k not in usage}
    part = max(parts, key=lambda k: parts[k]) if parts else "-"
    return f"{cycle['span']:.0f} ({part} {parts.get(part, 0.0):.0f})"
