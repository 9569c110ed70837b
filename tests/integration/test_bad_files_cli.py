"""Damaged files and refused configurations through the command line, as a user meets them.

Every command that loads a configuration and the EDS files (``sim``, ``run``, ``demo``,
``bus-load``) answers a damaged file with exit code 2 and one line on stderr naming the file,
never a traceback; ``bus-load`` refuses every configuration ``run`` refuses before it opens a
bus, with the same line. The loaders themselves are fuzzed in tests/unit/test_bad_input_files.py.
"""

from __future__ import annotations

import os
import random
import subprocess
import sys
from pathlib import Path

import pytest

from drivers.node_setup import DRIVE_EDS, SENSOR_EDS

pytestmark = pytest.mark.integration
CHEOPE = [sys.executable, "-m", "controller"]


def _cheope(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [*CHEOPE, *args],
        capture_output=True,
        text=True,
        timeout=120.0,
        check=False,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )


def _bus_args(command: str) -> list[str]:
    """A bus of its own for the commands that open one (none should get that far)."""
    if command == "bus-load":
        return []
    return [
        "--bus",
        "udp_multicast",
        "--udp-port",
        str(random.SystemRandom().randint(48000, 49999)),
        "--no-realtime",
    ]


def _assert_one_line(r: subprocess.CompletedProcess[str], command: str, needle: str) -> None:
    assert r.returncode == 2, (r.returncode, r.stderr, r.stdout)
    assert "Traceback" not in r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    assert lines[0].startswith(f"cheope {command}: error: ") and needle in lines[0], lines[0]


@pytest.fixture(scope="module")
def bad_files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[list[str], str]]:
    """name -> (options that point at the damaged file, what its one line must say)."""
    d = tmp_path_factory.mktemp("bad-files")
    drive = DRIVE_EDS.read_bytes()
    # cut inside a key, about 2 kB in: its last line is no KEY=VALUE
    truncated = drive[: drive.index(b"\nObjectType=", 1900) + len(b"\nObjectTy")]
    (d / "truncated.eds").write_bytes(truncated)
    truncated_line = truncated.count(b"\n") + 1
    (d / "twice.eds").write_bytes(drive + b"\n[1000]\nParameterName=Device type\nObjectType=0x7\n")
    twice_line = drive.count(b"\n") + 2  # after the file and its empty line
    (d / "directory.eds").mkdir()
    (d / "utf16.eds").write_bytes(SENSOR_EDS.read_text().encode("utf-16"))
    (d / "utf16.toml").write_bytes(b"\xff\xfe" + "[loop]\nrate_hz = 400\n".encode("utf-16-le"))
    (d / "junk.toml").write_bytes(b"[loop]\nrate_hz = 400\n\x93\xa7\x00junk")
    return {
        "truncated": (
            [f'--set=actuators.eds_file="{d / "truncated.eds"}"'],
            f"device description {d / 'truncated.eds'}: line {truncated_line} is not KEY=VALUE",
        ),
        "section twice": (
            [f'--set=actuators.eds_file="{d / "twice.eds"}"'],
            f"device description {d / 'twice.eds'}: line {twice_line}: section [1000] appears twice",
        ),
        "directory": (
            [f'--set=sensor.eds_file="{d / "directory.eds"}"'],
            f"device description {d / 'directory.eds'} is a directory, not a file",
        ),
        "utf-16 eds": (
            [f'--set=sensor.eds_file="{d / "utf16.eds"}"'],
            f"device description {d / 'utf16.eds'} is UTF-16 text",
        ),
        "utf-16 config": (
            ["--config", str(d / "utf16.toml")],
            f"configuration file {d / 'utf16.toml'} is UTF-16",
        ),
        "junk config": (
            ["--config", str(d / "junk.toml")],
            f"configuration file {d / 'junk.toml'} is not UTF-8 text: byte 0x93 at line 3, column 1",
        ),
    }


@pytest.mark.parametrize("command", ["sim", "run", "demo", "bus-load"])
@pytest.mark.parametrize(
    "damage", ["truncated", "section twice", "directory", "utf-16 eds", "utf-16 config", "junk config"]
)
def test_a_damaged_file_is_one_line_and_exit_2_in_every_command(bad_files, command, damage):
    options, needle = bad_files[damage]
    extra = ["--task", "path"] if command == "demo" else []
    _assert_one_line(_cheope(command, *_bus_args(command), *extra, *options), command, needle)


# Configurations `cheope run` refuses before opening a bus; `bus-load` accepted each of them.
REFUSED_BY_RUN = [
    (["--set", 'actuators.eds_file="/nonexistent/drive.eds"'], "/nonexistent/drive.eds does not exist"),
    (["--set", 'actuators.rpdo_objects=["0x9999"]'], "object 0x9999 is not in the device description"),
    (["--set", 'actuators.tpdo_objects=["0x6041","0x6064","0x606C"]'], "takes 10 bytes"),
    (["--set", 'actuators.tpdo_objects=["0x6041"]'], "TPDO mapping"),
    (["--set", 'bus.sync_producer="kernel"'], "bus.sync_producer = 'kernel' needs a socketcan bus"),
    (["--set", 'bus.can="kvaser:0"'], "interface 'kvaser' is not one of"),
    (["--set", 'monitoring.key_prefix="a/*"'], "monitoring.key_prefix = 'a/*'"),
    (["--set", 'monitoring.robot_id="two words"'], "monitoring.robot_id = 'two words'"),
    (["--set", 'monitoring.listen="nonsense"'], "monitoring.listen = 'nonsense'"),
    (["--set", 'monitoring.connect="tcp/10.0.0.5"'], "monitoring.connect = 'tcp/10.0.0.5'"),
]


@pytest.mark.parametrize("options,needle", REFUSED_BY_RUN)
def test_bus_load_refuses_what_run_refuses_with_the_same_line(options, needle):
    run = _cheope(
        "run", "--udp-port", str(random.SystemRandom().randint(48000, 49999)), "--no-realtime", *options
    )
    _assert_one_line(run, "run", needle)
    bus_load = _cheope("bus-load", *options)
    _assert_one_line(bus_load, "bus-load", needle)
    assert bus_load.stderr.removeprefix("cheope bus-load") == run.stderr.removeprefix("cheope run")


def test_bus_load_refuses_a_task_run_refuses(tmp_path: Path):
    r = _cheope("bus-load", "--set", "task.path.radius_m=0.3")
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert r.stderr.strip().count("\n") == 0 and "refused: path sample 0" in r.stderr
