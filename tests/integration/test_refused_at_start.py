"""Mistakes refused at start, not mid-motion or after the work (issue 38, item 6).

Each case is one ``cheope`` command as a user types it: exit code 2 and one line on stderr that
names what is wrong, and no work done before it (no frame on the bus, no output directory, no
recording left behind). Before: /dev/zero as --config read until memory ran out; a full disk
stopped a run 1.6 s into its motion; --plot and --max-duration of a demo failed after the run;
bench --rates 0 after two sections; replay --rerun to an unwritable path printed a traceback; an
injection shorter than a cycle injected nothing; an empty bus printed canopen's ERROR lines.
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys
from pathlib import Path

import pytest

from controller.shell.demo import random_udp_port
from drivers.bus import open_bus, parse_bus_spec

pytestmark = pytest.mark.integration
DATA = Path(__file__).resolve().parents[1] / "data"
QUIET = ["--set", "monitoring.enabled=false", "--no-realtime"]


def _limit_memory() -> None:  # 1.5 GB of address space: reading /dev/zero whole would fail, not swap
    resource.setrlimit(resource.RLIMIT_AS, (1_500_000_000, 1_500_000_000))


def _cheope(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "controller", *args],
        capture_output=True,
        text=True,
        timeout=120.0,
        check=False,
        cwd=cwd,
        preexec_fn=_limit_memory,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )


def _one_line(r: subprocess.CompletedProcess[str], *expected: str) -> None:
    assert r.returncode == 2, r.stdout + r.stderr
    assert r.stderr.count("\n") == 1 and "Traceback" not in r.stderr, r.stderr
    for text in expected:
        assert text in r.stderr, r.stderr


@pytest.mark.parametrize("device", ["/dev/zero", "/dev/urandom"])
@pytest.mark.parametrize("command", ["bus-load", "run", "demo", "sim"])
def test_an_endless_file_as_config_is_refused_after_a_bounded_read(command: str, device: str) -> None:
    bus = [] if command == "bus-load" else ["--udp-port", str(random_udp_port())]
    r = _cheope(command, "--config", device, *bus)
    _one_line(r, f"configuration file {device} is larger than 4 MiB")


@pytest.mark.parametrize("node_ids", ["[]", "[1, 2]"])
@pytest.mark.parametrize("command", ["bus-load", "run", "demo", "sim"])
def test_a_node_id_list_without_one_id_per_actuator_is_refused(command: str, node_ids: str) -> None:
    """An empty list raised IndexError out of the bus-load count in ``bus-load`` and ``run``."""
    bus = [] if command == "bus-load" else ["--udp-port", str(random_udp_port())]
    r = _cheope(command, "--set", f"actuators.node_ids={node_ids}", *bus, *QUIET[:2])
    _one_line(r, f"actuators.node_ids = {node_ids}: ", "value(s) for the 3 actuators")


def test_an_endless_file_as_zenoh_config_is_refused() -> None:
    r = _cheope("run", "--zenoh-config", "/dev/zero", "--udp-port", str(random_udp_port()))
    _one_line(
        r, "monitoring.config_file (--zenoh-config): Zenoh configuration file /dev/zero is larger than 4 MiB"
    )


def test_too_little_free_space_is_refused_before_the_bus_is_opened(tmp_path: Path) -> None:
    """recording.min_free_space_mb above what the file system has (a full disk, as far as the key goes)."""
    spec = parse_bus_spec("udp_multicast", udp_port=random_udp_port())
    with open_bus(spec) as listener:
        r = _cheope(
            "run",
            "--udp-port",
            str(spec.udp_port),
            "--set",
            "recording.min_free_space_mb=1e7",
            "--set",
            f'recording.directory="{tmp_path}"',
            *QUIET,
        )
        heard = listener.recv(0.5)
    _one_line(r, "recording.min_free_space_mb = 1e+07: only", f"MB free on the file system of {tmp_path}")
    assert heard is None and list(tmp_path.iterdir()) == []  # nothing sent, no recording left


def test_demo_outputs_and_arguments_are_checked_before_the_simulator_starts(tmp_path: Path) -> None:
    _one_line(
        _cheope("demo", "--output-dir", "/proc/1/nope", *QUIET),
        "--output-dir /proc/1/nope: cannot write there",
    )
    _one_line(
        _cheope("demo", "--duration", "-1", *QUIET), "--duration -1: must be a finite number of seconds > 0"
    )
    _one_line(
        _cheope("demo", "--duration", "nan", *QUIET), "--duration nan: must be a finite number of seconds > 0"
    )
    plot_file = tmp_path / "a-file"
    plot_file.write_text("")
    _one_line(
        _cheope("demo", "--output-dir", str(plot_file), *QUIET),
        f"--output-dir {plot_file}: is not a directory",
    )


def test_bench_arguments_and_its_output_are_checked_before_any_section(tmp_path: Path) -> None:
    _one_line(_cheope("bench", "--rates", "0", cwd=tmp_path), "--rates 0: loop.rate_hz = 0.0: must be >= 1.0")
    _one_line(_cheope("bench", "--rates", "400,x", cwd=tmp_path), "--rates '400,x': expected loop rates")
    _one_line(_cheope("bench", "--duration", "-5", cwd=tmp_path), "--duration -5: must be > 0")
    _one_line(
        _cheope("bench", "--output-dir", "/proc/1/b", cwd=tmp_path),
        "--output-dir /proc/1/b: cannot write there",
    )
    assert list(tmp_path.iterdir()) == []  # no ./bench left behind


def test_replay_to_an_unwritable_rerun_file_is_one_line() -> None:
    r = _cheope("replay", str(DATA / "path_quarter_lap.mcap"), "--rerun", "/proc/1/x.rrd")
    _one_line(r, "--rerun /proc/1/x.rrd: cannot write in /proc/1")


def test_an_injection_shorter_than_a_cycle_is_refused_with_the_reason() -> None:
    """The supervision table's former form: at 400 Hz a 2-ms window may hold no SYNC."""
    r = _cheope("demo", "--inject", "rogue_emcy:2@2+0.002", *QUIET)
    _one_line(r, "lasts 0.002 s, less than one cycle (0.0025 s at loop.rate_hz = 400)", "+DURATION >= 0.0025")
    assert _cheope("bus-load", "--set", 'sim.faults=["rogue_emcy:2@2+0.0025"]').returncode == 0


def test_an_injection_that_would_inject_nothing_is_refused_with_the_reason() -> None:
    """Both were taken, and did nothing (an outside tester): a window of no length, and a delay of
    the sensor's frames, which the simulated devices never delay (only a drive's TPDO)."""
    _one_line(_cheope("demo", "--inject", "drop:2@0+0", *QUIET), "lasts 0 s: give +DURATION > 0")
    _one_line(
        _cheope("demo", "--inject", "delay:16=0.001@1+0.5", *QUIET),
        "node 16 is not a drive; delay takes drives 1, 2, 3",
    )


def test_run_against_an_empty_bus_says_one_line_without_library_errors() -> None:
    r = _cheope("run", "--udp-port", str(random_udp_port()), "--set", "recording.enabled=false", *QUIET)
    _one_line(r, "cheope run: error: node 1 did not answer SDO requests")
    assert "Transfer aborted" not in r.stderr and "Exception in thread" not in r.stderr
