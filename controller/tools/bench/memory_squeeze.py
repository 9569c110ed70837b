"""A neighbour that leaves the machine short of memory: ``MemAvailable`` held near a floor.

    .venv/bin/python -m controller.tools.bench.memory_squeeze --floor-mb 100 -- cheope demo --json

Fills memory with 16-MiB blocks, every page written, until ``/proc/meminfo``'s ``MemAvailable``
is within ``BLOCK_MB`` of ``--floor-mb``, and then holds it there while the command runs: blocks
are freed when the command's processes take memory below the floor and taken again when it rises,
and one block is written afresh every ``CHURN_S`` (new pages, so the kernel keeps reclaiming
rather than settling). The command starts once the floor is reached (filling a 24-GB machine
takes about a minute) and the squeeze ends with it, by process id; its exit code is the
command's. One JSON line on stderr says what the squeeze held: the lowest and median
``MemAvailable`` while the command ran, and how many blocks it wrote.

The squeeze is a child process of its own, the largest on the machine: if the kernel runs out of
memory, its out-of-memory killer ends the squeeze, not the command. Without a command it holds the
floor for ``--duration-s``. What a machine short of memory did to the demo is on the real-time
page (docs/concepts/realtime.md).
"""

from __future__ import annotations

import argparse
import json
import signal
import statistics
import subprocess
import sys
import time
from pathlib import Path

BLOCK_MB = 16
CHURN_S = 0.02  # one block written afresh this often
MEMINFO = Path("/proc/meminfo")


def meminfo_mb(key: str) -> int:
    """One field of ``/proc/meminfo`` (``MemAvailable``, ``MemTotal``) [MiB]."""
    for line in MEMINFO.read_text().splitlines():
        if line.startswith(f"{key}:"):
            return int(line.split()[1]) // 1024
    raise RuntimeError(f"{MEMINFO} has no {key} line")


def available_mb() -> int:
    return meminfo_mb("MemAvailable")


def _block(fill: bytes) -> bytearray:
    block = bytearray(BLOCK_MB << 20)
    block[::4096] = fill * ((BLOCK_MB << 20) // 4096)  # every page written: resident, not just reserved
    return block


class _StopError(Exception):
    pass


def _raise_stop(_signum: int, _frame: object) -> None:
    raise _StopError


def hold(floor_mb: int, duration_s: float) -> dict[str, int]:
    """Fill down to ``floor_mb`` available, say so on stdout, hold it until ``duration_s`` or SIGTERM."""
    signal.signal(signal.SIGTERM, _raise_stop)
    blocks: list[bytearray] = []
    samples: list[int] = []
    written = 0
    start = time.monotonic()
    try:
        while available_mb() > floor_mb + BLOCK_MB:
            blocks.append(_block(b"\1"))
        print(f"floor reached: {len(blocks) * BLOCK_MB} MB held, {available_mb()} MB available", flush=True)
        while time.monotonic() - start < duration_s:
            available = available_mb()
            samples.append(available)
            if available < floor_mb and blocks:
                del blocks[-2:]  # the command took memory: give way (1.6 GB/s) faster than it takes it
            elif available > floor_mb + 3 * BLOCK_MB:
                blocks.append(_block(b"\1"))
            if blocks:  # the old block freed before the new one is taken: no dip below the floor
                # of the squeeze's own making, which it would answer by freeing blocks for nothing
                blocks.pop(written % len(blocks))
                blocks.append(_block(b"\2"))
                written += 1
            time.sleep(CHURN_S)
    except _StopError:
        pass
    return {
        "held_mb_at_end": len(blocks) * BLOCK_MB,
        "blocks_written": written,
        "lowest_available_mb": min(samples, default=-1),
        "median_available_mb": int(statistics.median(samples)) if samples else -1,
    }


def squeeze_while(floor_mb: int, command: list[str]) -> int:
    """Run ``command`` while a child process holds the floor; the command's exit code."""
    squeeze = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "controller.tools.bench.memory_squeeze",
            "--floor-mb",
            str(floor_mb),
            "--duration-s",
            "86400",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert squeeze.stdout is not None
        ready = squeeze.stdout.readline()
        if not ready.startswith("floor reached"):
            _, err = squeeze.communicate(timeout=30)
            raise RuntimeError(f"memory squeeze ended ({squeeze.returncode}) before its floor: {err.strip()}")
        print(f"memory squeeze: {ready.strip()}", file=sys.stderr, flush=True)
        code = subprocess.run(command).returncode
    finally:
        squeeze.send_signal(signal.SIGTERM)
        out, err = squeeze.communicate(timeout=30)
    if squeeze.returncode != 0:  # the kernel's out-of-memory killer ends it with SIGKILL
        print(f"memory squeeze: ended {squeeze.returncode} {err.strip()}", file=sys.stderr)
    for line in out.splitlines():
        if line.startswith("{"):
            print(f"memory squeeze: {line}", file=sys.stderr)
    return code


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="memory_squeeze", description=__doc__.splitlines()[0])
    parser.add_argument("--floor-mb", type=int, required=True, help="MemAvailable to hold [MiB]")
    parser.add_argument("--duration-s", type=float, default=600.0, help="without a command: how long to hold")
    parser.add_argument(
        "command", nargs=argparse.REMAINDER, help="-- COMMAND ...: run while the floor is held"
    )
    args = parser.parse_args(argv)
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    total_mb = meminfo_mb("MemTotal")
    if not 0 <= args.floor_mb < total_mb:
        parser.error(f"--floor-mb {args.floor_mb}: must be 0 to {total_mb - 1} (the machine's memory)")
    if not 0.0 < args.duration_s <= 86_400.0:
        parser.error(f"--duration-s {args.duration_s:g}: must be more than 0 and at most a day")
    if command:
        return squeeze_while(args.floor_mb, command)
    print(json.dumps(hold(args.floor_mb, args.duration_s)), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
