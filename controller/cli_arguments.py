"""Argument types for the command line: each refuses a bad value by the option's name, before the
command starts (argparse prints ``argument --timeout: ...`` and exits 2).

A float option parsed by ``float`` alone takes ``inf``, ``nan`` and negatives: ``--timeout inf``
reached Zenoh as ``int(inf * 1000)`` and ended in a traceback, ``monitor --duration nan`` ran
forever, ``contour-scan --jobs 1000`` forked a thousand processes on a 2-core machine.
"""

from __future__ import annotations

import argparse
import math
import os


def positive_seconds(text: str) -> float:
    """A finite number of seconds > 0."""
    return _seconds(text, zero_allowed=False)


def seconds_or_zero(text: str) -> float:
    """A finite number of seconds >= 0."""
    return _seconds(text, zero_allowed=True)


def positive_count(text: str) -> int:
    """A whole number >= 1."""
    return _whole_number(text, at_least=1)


def count_or_zero(text: str) -> int:
    """A whole number >= 0 (a random generator's seed)."""
    return _whole_number(text, at_least=0)


def job_count(text: str) -> int:
    """Worker processes: 1 up to the machine's CPUs (each runs a CPU-bound simulation; more than
    the CPUs only share them)."""
    value = positive_count(text)
    cpus = os.cpu_count() or 1
    if value > cpus:
        raise argparse.ArgumentTypeError(f"{text!r}: at most {cpus}, this machine's CPUs")
    return value


def _seconds(text: str, zero_allowed: bool) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: not a number") from None
    if not (math.isfinite(value) and (value >= 0 if zero_allowed else value > 0)):
        raise argparse.ArgumentTypeError(
            f"{text!r}: must be a finite number of seconds {'>=' if zero_allowed else '>'} 0"
        )
    return value


def _whole_number(text: str, at_least: int) -> int:
    refused = argparse.ArgumentTypeError(f"{text!r}: must be a whole number >= {at_least}")
    try:
        value = int(text)
    except ValueError:
        raise refused from None
    if value < at_least:
        raise refused
    return value
