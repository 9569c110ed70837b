"""The documentation says what the code does: generated pages are current, the README stays a front door."""

from __future__ import annotations

import re
from pathlib import Path

from controller.tools.config_reference import page

ROOT = Path(__file__).resolve().parents[2]


def test_the_configuration_keys_page_is_what_the_schema_says():
    shipped = (ROOT / "docs/reference/configuration-keys.md").read_text(encoding="utf-8")
    assert shipped == page(), (
        "regenerate: python -m controller.tools.config_reference > docs/reference/configuration-keys.md"
    )


def test_the_configuration_keys_page_names_every_section():
    text = page()
    for key in (
        "loop.max_missing_s",
        "safety.sensor_stale_s",
        "robot.cheope.rod_length_m",
        "robot.uru.knee_sign",
        "task.contour.force_setpoint_n",
        "sim.drive.sync_timeout_s",
        "recording.max_file_size_mb",
    ):
        assert f"| `{key}` |" in text


def test_the_configuration_keys_page_gives_the_length_limits():
    """A limit the schema enforces is on the page (robot_id's 64 characters was not: the generator
    read only number ranges)."""
    rows = {line.split("|")[1].strip(): line for line in page().splitlines() if line.startswith("| `")}
    assert "<= 64 characters" in rows["`monitoring.robot_id`"]


def test_the_readme_is_a_front_door_of_at_most_200_lines_with_the_two_commands():
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(readme.splitlines()) <= 200
    assert "make demo" in readme and "make test " in readme


def test_every_page_the_readme_links_exists():
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    targets = re.findall(r"\]\((docs/[^)#]+)", readme)
    assert targets
    assert [t for t in targets if not (ROOT / t).is_file()] == []


def _documented_modules() -> list[str]:
    """Every ``python -m controller...`` module the docs and the README tell a reader to run."""
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
    found = {
        m for p in pages for m in re.findall(r"python -m (controller\.tools\.[\w.]+)", p.read_text("utf-8"))
    }
    return sorted(found)


def test_every_documented_tool_answers_help_without_a_warning():
    """``--help`` of each documented tool prints its usage and ends 0, with no warning on stderr.
    Three used to ignore or misread their arguments (one started its minute-long table whatever was
    asked, one died on ``int('--help')``, one printed its page), and ``step_cost`` made runpy warn on
    every run: its package had imported it before ``-m`` ran it."""
    import subprocess
    import sys

    modules = _documented_modules()
    assert "controller.tools.bench.step_cost" in modules and len(modules) >= 10
    for module in modules:
        done = subprocess.run(
            [sys.executable, "-W", "error::RuntimeWarning", "-m", module, "--help"],
            capture_output=True,
            text=True,
            timeout=120,
            cwd=ROOT,
        )
        assert done.returncode == 0, f"{module} --help: rc {done.returncode}\n{done.stderr}"
        assert "usage:" in done.stdout, f"{module} --help printed no usage"
        assert "Warning" not in done.stderr, f"{module} --help warned:\n{done.stderr}"
