"""``cheope soak``: does a long run stay flat? The controller's memory and lateness over time.

Starts ``cheope sim`` and ``cheope run`` (the service as a user starts it, with its recording
and monitoring) on a private udp_multicast port, with a path task far longer than the soak,
samples the controller's resident set (``VmRSS`` in /proc) every ``--sample-s`` seconds, then
stops it with SIGTERM (the service's orderly stop) and reads its JSON summary. Prints:
- the RSS slope after the warm-up [kB/min], a least-squares line through the samples taken
  after ``--warmup-s`` (start-up imports, Zenoh, first allocations and the first fold of the
  loop's ring are not a leak), with the RSS at the warm-up's end and at the end;
- late cycles per 10 000 (the summary's ``late_cycles`` over its ``cycles``), final mode and
  exit status (SIGTERM must end in DONE, exit 0).
A benchmark, not a test: its figures depend on the machine (docs/guides/service.md).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from controller.cli_arguments import positive_seconds, seconds_or_zero
from controller.cli_output import progress_line, strict_json
from controller.errors import InputError
from controller.output_paths import check_output_dir
from controller.shell.demo import random_udp_port, simulator_process
from drivers.bus import parse_bus_spec


def memory_kb(pid: int) -> dict[str, int]:
    """The resident set and what it is made of [kB] ({} once ``pid`` is gone): ``VmRSS`` = ``RssAnon`` (heap, stacks) + ``RssFile``
    (mapped files: the interpreter, numpy's and the other libraries' code) + ``RssShmem``, and
    ``VmLck``. With ``mlockall`` (``cheope run`` locks by default where permitted) every mapped page
    is faulted in and stays resident, so VmRSS counts whole libraries that an unlocked process
    leaves on disk: about three times the unlocked figure; the slope is what shows a leak."""
    wanted = ("VmRSS:", "RssAnon:", "RssFile:", "RssShmem:", "VmLck:")
    out: dict[str, int] = {}
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith(wanted):
                key, value = line.split()[:2]
                out[key.rstrip(":")] = int(value)
    except (OSError, ValueError):
        return {}
    return out


def rss_slope_kb_per_min(times_s: np.ndarray, rss: np.ndarray) -> float:
    """Least-squares slope of RSS [kB] against time [s], in kB per minute."""
    if times_s.size < 2 or np.ptp(times_s) == 0:
        raise InputError(f"an RSS slope needs samples at two times or more, got {times_s.size}")
    return float(np.polyfit(times_s, rss, 1)[0] * 60.0)


@dataclass(frozen=True)
class SoakResult:
    duration_s: float
    warmup_s: float
    samples: int
    rss_warm_kb: int
    rss_end_kb: int
    rss_slope_kb_per_min: float
    cycles: int
    late_cycles: int
    late_per_10k: float
    period_error_max_us: float  # the loop's longest stall: its worst wake-up past a deadline
    longest_silence_cycles: dict[str, int]  # the devices' longest run of cycles without a usable sample
    memory_end_kb: dict[str, int]  # VmRSS, RssAnon, RssFile, RssShmem, VmLck at the last sample
    final_mode: str
    fault_reason: str
    exit_code: int
    recording: dict[str, object] | None
    recording_gb_per_hour: float  # the session's files (every rotation) over the controller's run time
    rss_series: list[tuple[float, int]]  # (s since start, VmRSS kB) at every sample: a step or a slope

    def table(self) -> str:
        return "\n".join(
            [
                f"soak                {self.duration_s:.0f} s, warm-up {self.warmup_s:.0f} s, {self.samples} RSS samples",
                (
                    f"controller RSS      {self.rss_warm_kb / 1024:.1f} MB after warm-up, {self.rss_end_kb / 1024:.1f} MB "
                    f"at the end, slope {self.rss_slope_kb_per_min:+.2f} kB/min"
                ),
                (
                    "memory at the end   "
                    + ", ".join(f"{k} {v / 1024:.1f} MB" for k, v in self.memory_end_kb.items())
                ),
                f"late cycles         {self.late_cycles} of {self.cycles}: {self.late_per_10k:.1f} per 10 000",
                (
                    f"longest stalls      loop period error max {self.period_error_max_us / 1000:.1f} ms; no usable sample "
                    f"for {self.longest_silence_cycles.get('drive', 0)} cycles (a drive), "
                    f"{self.longest_silence_cycles.get('sensor', 0)} (the sensor)"
                ),
                f"recording           {self.recording_gb_per_hour:.3f} GB an hour (every file of the session)",
                (
                    f"end                 {self.final_mode}{f' ({self.fault_reason})' if self.fault_reason else ''}, "
                    f"exit {self.exit_code} (SIGTERM)"
                ),
            ]
        )


def run_soak(
    duration_s: float,
    warmup_s: float,
    sample_s: float,
    rate_hz: float,
    realtime_args: list[str],
    recording_dir: Path,
    extra_sets: list[str],
    progress: Callable[[str], None] | None = None,
) -> SoakResult:
    """``progress`` hears ``120/1800 s, RSS 72.4 MB`` at each RSS sample."""
    if not duration_s > warmup_s + 2 * sample_s:
        raise InputError(f"--duration {duration_s:g} s: must exceed --warmup-s {warmup_s:g} s by two samples")
    port = random_udp_port()
    spec = parse_bus_spec("udp_multicast", fd=False, udp_port=port)
    sets = [
        f"loop.rate_hz={rate_hz}",
        'task.kind="path"',
        "task.path.laps=1000.0",
        f'recording.directory="{recording_dir}"',
        f'monitoring.robot_id="soak-{os.getpid()}"',
        *extra_sets,
    ]
    set_args = [a for s in sets for a in ("--set", s)]
    with simulator_process(spec, None, sets, extra_args=realtime_args):
        cmd = [
            sys.executable,
            "-m",
            "controller",
            "run",
            "--json",
            "--bus",
            "udp_multicast",
            "--udp-port",
            str(port),
            *realtime_args,
            *set_args,
        ]
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        started = time.monotonic()
        times: list[float] = []
        rss: list[int] = []
        memory: dict[str, int] = {}
        try:
            start = time.monotonic()
            while (now := time.monotonic() - start) < duration_s and proc.poll() is None:
                sample = memory_kb(proc.pid)  # one read of /proc/PID/status: VmRSS and its parts
                kb = sample.get("VmRSS")
                if kb is not None:
                    times.append(now)
                    rss.append(kb)
                    memory = sample
                    if progress is not None:
                        progress(f"{now:.0f}/{duration_s:.0f} s, controller RSS {kb / 1024:.1f} MB")
                time.sleep(sample_s)  # a sampling period, not a wait for an event
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
            out, err = proc.communicate(timeout=120)
            ran_s = time.monotonic() - started  # what the recording covers: start-up to the last write
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    if proc.returncode not in (0, 1, 3) or not out.strip() or sum(t >= warmup_s for t in times) < 2:
        raise InputError(
            f"cheope run ended with status {proc.returncode} after {times[-1] if times else 0:.0f} s: "
            f"{err.strip()[-2000:]} {out.strip()[-2000:]}"
        )
    summary = json.loads(out)
    t, r = np.asarray(times), np.asarray(rss, dtype=float)
    warm = t >= warmup_s
    cycles, late = int(summary["cycles"]), int(summary["late_cycles"])
    return SoakResult(
        duration_s=float(t[-1]) if t.size else 0.0,
        warmup_s=warmup_s,
        samples=int(warm.sum()),
        rss_warm_kb=int(r[warm][0]),
        rss_end_kb=int(r[-1]),
        rss_slope_kb_per_min=rss_slope_kb_per_min(t[warm], r[warm]),
        cycles=cycles,
        late_cycles=late,
        late_per_10k=1e4 * late / cycles if cycles else 0.0,
        period_error_max_us=float(summary["period_error_us"]["max"]),
        longest_silence_cycles=dict(summary.get("longest_silence_cycles", {})),
        memory_end_kb=memory,
        final_mode=str(summary["final_mode"]),
        fault_reason=str(summary["fault_reason"]),
        exit_code=proc.returncode,
        recording=summary.get("recording"),
        recording_gb_per_hour=_gb_per_hour(summary.get("recording"), ran_s),
        rss_series=[(round(float(a), 1), int(b)) for a, b in zip(t, r, strict=True)],
    )


def _gb_per_hour(recording: dict[str, object] | None, duration_s: float) -> float:
    files = recording.get("files") if isinstance(recording, dict) else None
    if not isinstance(files, list) or duration_s <= 0.0:
        return 0.0
    size = sum(Path(str(f)).stat().st_size for f in files if Path(str(f)).is_file())
    return size / 1e9 * 3600.0 / duration_s


def add_soak_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument(
        "--duration", type=positive_seconds, default=1800.0, help="seconds of running (default 1800)"
    )
    ap.add_argument(
        "--warmup-s", type=seconds_or_zero, default=120.0, help="seconds left out of the slope (default 120)"
    )
    ap.add_argument(
        "--sample-s", type=positive_seconds, default=5.0, help="seconds between RSS samples (default 5)"
    )
    ap.add_argument("--rate", type=float, default=400.0, help="loop rate [Hz] (default 400)")
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="more configuration overrides for both processes (repeatable)",
    )
    ap.add_argument(
        "--output-dir", metavar="DIR", help="keep the session recording in DIR (default: a deleted temp dir)"
    )
    ap.add_argument("--keep", dest="output_dir", help=argparse.SUPPRESS)  # the spelling before --output-dir
    ap.add_argument("--json", action="store_true", help="print the figures as one JSON object")


def run_soak_command(args: argparse.Namespace, realtime_args: list[str]) -> int:
    if args.warmup_s >= args.duration:
        raise InputError(f"--warmup-s {args.warmup_s:g}: must be shorter than --duration {args.duration:g}")
    if args.output_dir:  # refused before the simulator and the controller start, not after
        check_output_dir(args.output_dir, "--output-dir")
    with tempfile.TemporaryDirectory(prefix="cheope-soak-") as tmp, progress_line("cheope soak") as progress:
        result = run_soak(
            args.duration,
            args.warmup_s,
            args.sample_s,
            args.rate,
            realtime_args,
            Path(args.output_dir) if args.output_dir else Path(tmp),
            list(args.set),
            progress,
        )
    print(strict_json(result.__dict__) if args.json else result.table())
    return 0 if result.final_mode == "DONE" and result.exit_code == 0 else 1
