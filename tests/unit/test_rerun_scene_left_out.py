"""``cheope replay FILE --rerun OUT.rrd`` of a recording whose ``cheope.config`` record is bad writes
the plots and events without the robot's 3D scene, and says so on stderr in one line naming the
file and the record (logs/rerun_export.py). It wrote the file without the scene without a word (an
outside tester's finding).
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from recorded_config_record import SHIPPED, with_config_record

from controller.cli import main

SCENE = "/world/platform/cylinders"  # one of the robot's drawn entities (Cheope's platform)


def _rerun(path: Path, out: Path, capsys: pytest.CaptureFixture[str]) -> tuple[dict, str]:
    assert main(["replay", str(path), "--rerun", str(out), "--json"]) == 0  # the cycles are all there
    captured = capsys.readouterr()
    assert out.is_file()
    return json.loads(captured.out), captured.err


@pytest.mark.parametrize(
    "text,what",
    [
        ("[1, 2, 3]", "the configuration is a JSON array, not an object of sections"),
        ('{"loop": {"rate_hz": -5}}', "loop.rate_hz = -5"),  # a table this version does not load
    ],
    ids=["no-table", "not-loaded"],
)
def test_a_bad_config_record_leaves_the_scene_out_and_says_so(tmp_path, capsys, text, what):
    path = with_config_record(tmp_path / "rec.mcap", text)
    result, err = _rerun(path, tmp_path / "out.rrd", capsys)
    assert SCENE not in result["entities"] and "/plots/actuators/target_1" in result["entities"]
    assert err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith(f"cheope replay: {path}: metadata record cheope.config: ")
    assert what in err and err.rstrip().endswith("written without the robot's 3D scene")
    assert result["scene_left_out"] == err.removeprefix("cheope replay: ").rstrip()


def test_a_good_record_draws_the_scene_without_a_word(tmp_path, capsys):
    result, err = _rerun(SHIPPED, tmp_path / "out.rrd", capsys)
    assert SCENE in result["entities"] and result["scene_left_out"] is None and err == ""
