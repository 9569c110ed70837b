"""Time the hypervisor took from each CPU of this machine over a run: ``/proc/stat``'s steal.

On a virtual machine the host may stop running a vCPU while work waits on it. Inside the guest
nothing shows it but this counter (in ticks of ``SC_CLK_TCK``, 10 ms on Linux). A contour demo of
2026-12-05 faulted when its simulator, on CPU 0, stood still 103 ms while the loop on CPU 1 ran
on: 41 SYNCs went on time and their answers came in one burst after. From inside the run that
cannot be told from a stall of the simulator's own; the summary's ``steal_s`` says how long the
host held each CPU over the run, so the next one can be (zeros on bare metal).
"""

from __future__ import annotations

import os

PROC_STAT = "/proc/stat"
_STEAL_FIELD = 8  # "cpuN user nice system idle iowait irq softirq steal ..." (proc(5))


def steal_ticks(path: str = PROC_STAT) -> dict[str, int]:
    """Each CPU's steal so far, by its name in ``path`` (``cpu0``, ``cpu1`` ...); empty when the
    file cannot be read or has no steal column (an old kernel, not Linux)."""
    try:
        with open(path) as f:
            lines = f.read().splitlines()
    except OSError:
        return {}
    out: dict[str, int] = {}
    for line in lines:
        fields = line.split()
        if len(fields) > _STEAL_FIELD and fields[0].startswith("cpu") and fields[0][3:].isdigit():
            try:
                out[fields[0]] = int(fields[_STEAL_FIELD])
            except ValueError:
                continue
    return out


def steal_s_since(before: dict[str, int], path: str = PROC_STAT) -> dict[str, float]:
    """Seconds of steal of each CPU since ``before`` (``steal_ticks``), CPUs in both readings only."""
    ticks_per_s = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
    now = steal_ticks(path)
    return {cpu: round((now[cpu] - t0) / ticks_per_s, 3) for cpu, t0 in before.items() if cpu in now}
