"""The own-robot tutorial, verbatim: its files taken from the page, installed with pip, its commands run.

docs/tutorial/own-robot.md builds a linear Delta the repository does not ship. This test writes
the page's titled code blocks where their titles say, runs the page's install line (``pip install
./cheope-delta``, here with ``--target`` so that the shared environment stays as it was) and each
``cheope`` line of the page (with ``--json`` to read its outcome), then runs the project's own
plug-in tests with the Delta installed beside them.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
PAGE = REPO / "docs" / "tutorial" / "own-robot.md"
FENCE = re.compile(r'^```(\w+)(?: title="([^"]+)")?\n(.*?)^```\n', re.S | re.M)


def _blocks() -> list[tuple[str, str | None, str]]:
    return [(m[1], m[2], m[3]) for m in FENCE.finditer(PAGE.read_text())]


@pytest.fixture(scope="module")
def delta(tmp_path_factory):
    """The page's files written, and its install line run: (the run directory, its environment)."""
    root = tmp_path_factory.mktemp("tutorial")
    files = [(title, text) for _, title, text in _blocks() if title]
    assert {t for t, _ in files} >= {"cheope-delta/pyproject.toml", "cheope-delta/cheope_delta/__init__.py"}
    for title, text in files:
        (root / title).parent.mkdir(parents=True, exist_ok=True)
        (root / title).write_text(text)
    install = _commands()[0]
    assert install == ["pip", "install", "./cheope-delta"]
    site = root / "site"
    subprocess.run(
        [sys.executable, "-m", *install, "--no-deps", "--no-build-isolation", "--target", str(site), "-q"],
        cwd=root,
        check=True,
        timeout=300,
    )
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(site), os.environ.get("PYTHONPATH", "")]),
        "XDG_DATA_HOME": str(root / "data"),  # the recordings' default directory, here
    }
    return root, env


def _commands() -> list[list[str]]:
    (bash,) = [text for lang, _, text in _blocks() if lang == "bash"]
    return [line.split() for line in bash.splitlines() if line.strip()]


def _cheope(args: list[str], root: Path, env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    assert args[0] == "cheope"
    return subprocess.run(
        [sys.executable, "-m", "controller", *args[1:]],
        cwd=root,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )


def test_the_tutorials_delta_runs_its_path_in_simulated_time_and_over_the_bus(delta):
    root, env = delta
    runs = [c for c in _commands()[1:] if c[:2] == ["cheope", "demo"] and "contour" not in c]
    assert [c[2:] for c in runs] == [["--robot", "delta", "--simulated-time"], ["--robot", "delta"]]
    # a circle of 50 mm around (0, 0, 0.1): within 0.1 mm in simulated time; over the bus within 2 mm,
    # a margin late cycles on a busy machine do not break (0.12 mm measured beside the test suite)
    for command, max_error_m in zip(runs, (1e-4, 2e-3), strict=True):
        r = _cheope([*command, "--json"], root, env)
        assert r.returncode == 0, r.stderr
        summary = json.loads(r.stdout)
        assert summary["final_mode"] == "DONE", summary["fault_reason"]
        assert 0 < summary["tracking_error_m"]["max"] < max_error_m
    assert list((root / "data" / "cheope" / "sessions").glob("*.mcap")), "the run over the bus records"


def test_the_tutorials_delta_runs_the_papers_contour_experiment(delta):
    """Its capabilities (joint motion, structure, force witness) declared, the contour runs on it:
    five laps DONE, in contact all along, pressing its 10 N within the safety limit."""
    root, env = delta
    (contour,) = [c for c in _commands() if "contour" in c]
    r = _cheope([*contour, "--json"], root, env)
    assert r.returncode == 0, r.stderr
    summary = json.loads(r.stdout)
    assert summary["final_mode"] == "DONE", summary["fault_reason"]
    laps = summary["contour"]["laps"]
    assert len(laps) == 5 and all(lap["contact_losses"] == 0 for lap in laps)
    assert all(lap["force_error_rms_n"] < 2.0 for lap in laps[1:])  # lap 1 explores at 20 mm/s
    assert 5.0 < summary["contour"]["max_true_contact_force_n"] < 60.0


def test_the_tutorials_refusals_name_what_is_wrong(delta):
    root, env = delta
    r = _cheope(["cheope", "demo", "--robot", "delta", "--task", "planned"], root, env)
    assert (
        r.returncode == 2 and "task.kind = 'planned': robot.kind = 'delta' runs 'path', 'contour'" in r.stderr
    )
    inside = ["cheope", "demo", "--robot", "delta", "--task", "contour", "--simulated-time"]
    r = _cheope([*inside, "--set", "robot.delta.home_m=[0.0,0.0,0.1]"], root, env)
    assert r.returncode == 2 and "starts inside the workpiece" in r.stderr, r.stderr
    r = _cheope(
        ["cheope", "bus-load", "--robot", "delta", "--set", "robot.delta.arm_lenght_m=0.3"], root, env
    )
    assert r.returncode == 2 and "unknown key(s) arm_lenght_m in [robot.delta]" in r.stderr


def test_the_projects_own_tests_pass_with_a_third_party_plugin_installed(delta):
    _, env = delta
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "pytest",
            "-q",
            "-p",
            "no:cacheprovider",
            str(REPO / "tests" / "unit" / "test_plugins.py"),
            str(REPO / "tests" / "unit" / "test_adding_a_robot.py"),
            str(REPO / "tests" / "unit" / "test_cli_details.py"),
        ],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert r.returncode == 0, r.stdout[-3000:]
    assert " passed" in r.stdout
