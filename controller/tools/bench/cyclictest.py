"""The machine's own timing floor: ``cyclictest`` (Debian ``rt-tests``) at the loop's rate and class.

A C program that does nothing but sleep to absolute deadlines is late as often as the kernel,
the hypervisor and the other tasks make it; a Python loop cannot do better. ``cheope bench``
runs this beside each of its cases (same interval, priority, CPU and memory locking) and
reports the loop's figures as ratios to it.

It runs with ``--laptop``: by default cyclictest holds the CPUs' wake-up latency limit at 0
(``/dev/cpu_dma_latency``) for as long as it runs, which on a guest with the ``haltpoll`` cpuidle
driver keeps every vCPU polling, the loop's too. The bench would then time the loop on a machine
the service does not run on, and its floor with it. With ``--laptop`` both see the machine as the
service leaves it: its own latency limit (``--cpu-latency-us``) or idle pollers where it asks for
them, nothing where it does not.

cyclictest writes a histogram of wake-up latencies in whole microseconds (``--histfile``),
one ``latency count`` line per bin up to ``-h`` microseconds, and the samples beyond it as
overflows; percentiles and counts above a threshold are read from it.

A sample is one wake-up, not one deadline. A wake-up late by more than a period passes the
deadlines after it unsampled: cyclictest moves its next deadline past the present
(``while (tsgreater(&now, &next)) next += interval`` in its ``timerthread``) and counts the
wake-up once. The loop counts each deadline its late cycle passed as one more late cycle (its
``overruns``, controller/tools/bench/statistics.py). So a 10-ms stall of the machine at 400 Hz is
1 late sample of cyclictest's and 4 or 5 late deadlines of the loop's. ``late_deadlines_per_10k``
counts cyclictest's the loop's way: each late sample with latency L is late itself and makes the
deadlines before ``now`` late too (those m periods after its own with m x period < L); the
histogram holds L to the microsecond up to ``-h``, an overflow counts as latency ``-h`` (the
largest, ``Max Latencies``, as itself): fewer deadlines than it passed, never more.
"""

from __future__ import annotations

import math
import shutil
import subprocess
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from controller.errors import DeviceError

INSTALL_HINT = "cyclictest not found: apt-get install rt-tests (Debian) for the machine's floor"


class CyclictestError(DeviceError, RuntimeError):
    """cyclictest did not run, or wrote no histogram we can read."""


@dataclass(frozen=True)
class Histogram:
    counts: np.ndarray  # counts[i]: samples with latency i microseconds
    overflows: int  # samples beyond the last bin
    max_us: float  # the largest latency cyclictest saw (also among the overflows)

    @property
    def samples(self) -> int:
        return int(self.counts.sum()) + self.overflows

    def percentile_us(self, q: float) -> float:
        """The latency below which a fraction ``q`` (0..1) of the samples lie (a bin's value)."""
        n = self.samples
        if n == 0:
            return float("nan")
        rank = q * n
        cum = np.cumsum(self.counts)
        i = int(np.searchsorted(cum, rank, side="left"))
        return float(i) if i < self.counts.size else self.max_us

    def late_deadlines_per_10k(self, threshold_us: float, interval_us: float) -> float:
        """Deadlines of a loop at ``interval_us`` that cyclictest's wake-ups met late (latency above
        ``threshold_us``) or passed while late, per 10 000 deadlines: the loop's count (module text)."""
        if self.samples == 0:
            return float("nan")
        latency = np.arange(self.counts.size, dtype=np.float64)
        passed = _passed(latency, interval_us)
        late = latency > threshold_us
        skipped = float((self.counts * passed).sum())
        late_deadlines = float((self.counts[late] * (1.0 + passed[late])).sum())
        if self.overflows:
            # beyond the histogram: its last bin's latency for each, the maximum for one of them
            beyond = float(self.counts.size)
            largest = self.max_us if math.isfinite(self.max_us) else beyond
            over = float((self.overflows - 1) * _passed(beyond, interval_us) + _passed(largest, interval_us))
            skipped += over
            late_deadlines += self.overflows + over
        return 1e4 * late_deadlines / (self.samples + skipped)

    def per_10k_above(self, threshold_us: float) -> float:
        """Samples with latency above ``threshold_us``, per 10 000."""
        n = self.samples
        if n == 0:
            return float("nan")
        first = int(np.floor(threshold_us)) + 1
        above = int(self.counts[first:].sum()) + self.overflows
        return 1e4 * above / n


def _passed(latency_us: np.ndarray | float, interval_us: float) -> np.ndarray:
    """Deadlines a wake-up late by ``latency_us`` (a number or an array) passed after its own
    (cyclictest's skip): the m >= 1 with m x interval < latency."""
    return np.maximum(np.ceil(np.asarray(latency_us) / interval_us) - 1.0, 0.0)


def parse_histogram(text: str) -> Histogram:
    counts: dict[int, int] = {}
    overflows = 0
    max_us = float("nan")
    for line in text.splitlines():
        line = line.strip()
        if not line:
            continue
        if line.startswith("#"):
            key, _, value = line[1:].partition(":")
            value = value.strip()
            if key.strip() == "Histogram Overflows" and value:
                overflows = int(value.split()[0])
            elif key.strip() == "Max Latencies" and value:
                max_us = float(value.split()[0])
            continue
        parts = line.split()
        if len(parts) >= 2 and parts[0].isdigit():
            counts[int(parts[0])] = int(parts[1])
    if not counts:
        raise CyclictestError("cyclictest wrote no histogram lines")
    arr = np.zeros(max(counts) + 1, dtype=np.int64)
    for k, v in counts.items():
        arr[k] = v
    return Histogram(arr, overflows, max_us)


def cyclictest_path() -> str | None:
    return shutil.which("cyclictest")


def cyclictest_command(
    binary: str,
    interval_us: int,
    loops: int,
    histogram_us: int,
    histfile: Path,
    priority: int | None,
    cpu: int | None,
    lock_memory: bool,
) -> list[str]:
    cmd = [
        binary,
        "-t1",
        "-q",
        f"-i{interval_us}",
        f"-l{loops}",
        f"-h{histogram_us}",
        f"--histfile={histfile}",
        "--laptop",  # the machine's idle states as the service leaves them (module text)
    ]
    cmd += [f"-p{priority}"] if priority is not None else ["--policy=other"]
    if cpu is not None:
        cmd.append(f"-a{cpu}")
    if lock_memory:
        cmd.append("-m")
    return cmd


def run_cyclictest(
    rate_hz: float,
    duration_s: float,
    priority: int | None,
    cpu: int | None,
    lock_memory: bool,
    thresholds_us: tuple[float, ...],
) -> dict[str, object]:
    """One cyclictest thread at ``rate_hz`` for ``duration_s``: latency percentiles and rates above thresholds."""
    with cyclictest_beside(rate_hz, duration_s, priority, cpu, lock_memory, thresholds_us) as result:
        pass
    return result


@contextmanager
def cyclictest_beside(
    rate_hz: float,
    duration_s: float,
    priority: int | None,
    cpu: int | None,
    lock_memory: bool,
    thresholds_us: tuple[float, ...],
) -> Iterator[dict[str, object]]:
    """cyclictest started on entering and waited for on leaving, for whatever runs beside it in the
    ``with`` block (the bench's run: both see the same machine); the dict yielded is filled then."""
    binary = cyclictest_path()
    if binary is None:
        raise CyclictestError(INSTALL_HINT)
    interval_us = round(1e6 / rate_hz)
    loops = max(1, round(duration_s * rate_hz))
    # 100 ms: the latency of each late wake-up the host's stalls make (a few ms to tens), to the
    # microsecond, for the deadlines it passed (module text); the file is 1.4 MB
    histogram_us = max(2 * interval_us, 100_000)
    result: dict[str, object] = {}
    with tempfile.TemporaryDirectory(prefix="cheope-cyclictest-") as tmp:
        histfile = Path(tmp) / "histogram.txt"
        cmd = cyclictest_command(
            binary, interval_us, loops, histogram_us, histfile, priority, cpu, lock_memory
        )
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            yield result
            try:
                _, err = proc.communicate(timeout=duration_s * 3 + 30)
            except subprocess.TimeoutExpired as exc:
                raise CyclictestError(f"cyclictest did not finish within {exc.timeout:.0f} s") from exc
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
        if proc.returncode != 0 or not histfile.exists():
            raise CyclictestError(f"cyclictest exited with {proc.returncode}: {err.strip()[-300:]}")
        hist = parse_histogram(histfile.read_text())
    result.update(
        {
            "command": " ".join(cmd[:1] + [c for c in cmd[1:] if not c.startswith("--histfile")]),
            "samples": hist.samples,
            "latency_us": {
                "p50": hist.percentile_us(0.5),
                "p99": hist.percentile_us(0.99),
                "p99_9": hist.percentile_us(0.999),
                "max": hist.max_us,
            },
            "per_10k_above_us": {f"{t:g}": round(hist.per_10k_above(t), 2) for t in thresholds_us},
            "late_deadlines_per_10k_above_us": {
                f"{t:g}": round(hist.late_deadlines_per_10k(t, interval_us), 2) for t in thresholds_us
            },
        }
    )
