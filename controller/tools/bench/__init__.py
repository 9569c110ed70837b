"""``cheope bench``: how fast and how regular the loop is, with the simulator beside it.

One command measures everything the timing issue asks for and writes a table (stdout), one
JSON file and PNG plots of the period-error distribution:

1. the cyclic PDO path: this project's ``CyclicExchange`` against the ``canopen`` package's
   own PDO objects doing the same cycle (3 RPDOs + SYNC out, 3 drive + 2 sensor TPDOs in,
   decoded to SI units), CPU time per cycle, on python-can's in-process virtual bus;
2. the step's cost in Python against Ruckig's own reported calculation time, in process on
   simulated time (``sim_backend.loopback``), with a cProfile of the hottest functions;
3. for each configured rate (400 Hz on classical CAN, 1 kHz on CAN FD by default):
   a. the loop shell's sleeper against a naive ``time.sleep(period)`` loop doing the same
      busy work (the step's measured median), in alternating blocks so machine noise hits
      both arms alike: drift and jitter;
   b. the real service (``run_controller``) against the simulator as its own process:
      achieved rate, period error p50/p99/p99.9/max, late cycles per 10 000, step compute
      time, last TPDO in -> outputs ready and -> RPDOs out, CPU use of controller (process
      and loop thread) and simulator, computed and measured bus load.

Definitions (also in the JSON):
- period error: |(wake_k - wake_{k-1}) - period|, wake-ups on the monotonic clock;
- late cycle: woke more than ``late_fraction`` of a period after its deadline, or a deadline
  skipped because the loop fell a whole period behind (an overrun);
- a received frame's time (SYNC out -> last TPDO in, last TPDO in -> ...): when it came, from its
  receive timestamp (``drivers/frame_tap.py``), not when the exchange read it, which at 400 Hz is
  the window's end (``controller/shell/service.py`` ``sleeps_through_window``);
- measured bus load: every frame on the bus (the controller's sent and received ones) times
  its duration by ``drivers.bus_load`` with its own FD/BRS flags, worst-case stuffing, per
  second of the run; it counts classical frames where a device answers with classical frames.

The package holds one concept per module: ``statistics`` (the figures), ``sleepers`` (the sleeper
comparison), ``probes`` (the loop's timing and CPU accounting), ``case`` (one configuration against
the simulator, the machine's floor beside it), ``step_cost`` (the step against Ruckig), ``pdo_paths``
(the PDO path against canopen's), ``runner`` (the whole benchmark and its plots), ``report`` (the
table) and ``command`` (its command line). Beside it, the measurements the bench and the docs cite:
``cyclictest`` (the machine's floor), ``cycle_work`` (the deterministic work per cycle),
``sync_jitter``, ``node_setup_time``, ``query_flood`` and ``soak`` (a long run).
"""

from __future__ import annotations

from controller.child_process import process_cpu_s
from controller.tools.bench.case import BenchCase, machine_floor, machine_floor_beside, run_case
from controller.tools.bench.command import add_bench_arguments, checked_bench_arguments, run_bench_command
from controller.tools.bench.pdo_paths import bus_frame_cost, compare_pdo_paths, stub_bus
from controller.tools.bench.probes import LoopProbe, child_pid, cpu_use_percent
from controller.tools.bench.report import format_table, python_can_floor_percent
from controller.tools.bench.runner import plot_distributions, run_bench, work_per_cycle
from controller.tools.bench.sleepers import busy_work, compare_sleepers, deadline_loop, naive_loop
from controller.tools.bench.statistics import late_per_10k, percentiles_us, schedule_stats

__all__ = [
    "BenchCase",
    "LoopProbe",
    "add_bench_arguments",
    "bus_frame_cost",
    "busy_work",
    "checked_bench_arguments",
    "child_pid",
    "compare_pdo_paths",
    "compare_sleepers",
    "cpu_use_percent",
    "deadline_loop",
    "format_table",
    "late_per_10k",
    "machine_floor",
    "machine_floor_beside",
    "naive_loop",
    "percentiles_us",
    "plot_distributions",
    "process_cpu_s",
    "python_can_floor_percent",
    "run_bench",
    "run_bench_command",
    "run_case",
    "schedule_stats",
    "stub_bus",
    "work_per_cycle",
]
