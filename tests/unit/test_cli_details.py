"""The command line's details: help texts, choices, -v anywhere, strict JSON, the progress line."""

from __future__ import annotations

import argparse
import io
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from controller.cli import build_parser
from controller.cli_output import ProgressLine, progress_line, strict_json
from controller.errors import InputError
from controller.tools.fault_scenarios import SCENARIOS, run_all
from logs.cli import rerun_input_and_output

DATA = Path(__file__).resolve().parents[1] / "data"


def _subparser(*path: str) -> argparse.ArgumentParser:
    parser = build_parser()
    for name in path:
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        parser = sub.choices[name]
    return parser


def _option(parser: argparse.ArgumentParser, flag: str) -> argparse.Action:
    return parser._option_string_actions[flag]


def _reject_constant(name: str) -> object:
    raise ValueError(f"not strict JSON: {name}")


@pytest.mark.parametrize(
    "command", ["run", "faults", "bus-load", "analyze", "plan", "plan-bench", "demo", "status"]
)
def test_every_json_option_says_what_it_prints(command: str):
    text = _option(_subparser(command), "--json").help
    assert text and "JSON" in text


def test_config_help_names_the_file_each_robot_loads():
    run_help = _option(_subparser("run"), "--config").help or ""
    for kind, name in (("cheope", "cheope.toml"), ("uru", "uru.toml"), ("nspu", "nspu.toml")):
        assert f"{name} for --robot {kind}" in run_help
    for command in ("plan", "plan-bench"):
        only = _option(_subparser(command), "--config").help or ""
        assert "nspu.toml" in only and "cheope.toml" not in only


@pytest.mark.parametrize("command", ["plan", "plan-bench"])
def test_plan_commands_offer_only_the_robot_they_plan_for(command: str):
    assert list(_option(_subparser(command), "--robot").choices or ()) == ["nspu"]
    r = subprocess.run(
        [sys.executable, "-m", "controller", command, "--robot", "cheope"],
        capture_output=True,
        text=True,
        check=False,
        timeout=60,
    )
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "invalid choice: 'cheope'" in r.stderr


def _parsers(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()):
    """The parser and every subcommand's below it, with the words that reach each."""
    yield path, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _parsers(sub, (*path, name))


def test_every_help_page_prints():
    """``cheope --help`` once died on a plug-in's "95 % of" (argparse reads help as a format)."""
    pages = dict(_parsers(build_parser()))
    assert ("contour-scan",) in pages and ("logs", "info") in pages
    for path, parser in pages.items():
        text = parser.format_help()
        assert text.startswith("usage:"), path
    assert "95 % of those" in " ".join(build_parser().format_help().split())


@pytest.mark.parametrize(
    ("argv", "option"),
    [
        (["list", "--timeout", "inf"], "--timeout"),  # reached Zenoh as int(inf * 1000): a traceback
        (["status", "--timeout", "nan"], "--timeout"),
        (["stop", "--timeout", "-1"], "--timeout"),
        (["list", "--key-prefix", ""], "--key-prefix"),  # an invalid key expression inside Zenoh
        (["status", "--key-prefix", "a/**"], "--key-prefix"),
        (["monitor", "--duration", "nan"], "--duration"),  # ran forever
        (["monitor", "--count", "0"], "--count"),
        (["contour-scan", "--jobs", "1000"], "--jobs"),  # forked a thousand processes
        (["contour-stress", "--jobs", "0"], "--jobs"),
        (["soak", "--sample-s", "-1"], "--sample-s"),  # started both processes, then failed
        (["soak", "--warmup-s", "-1"], "--warmup-s"),
        (["ros2", "--wait-subscriber", "-5"], "--wait-subscriber"),
        (["plan-bench", "--seed", "-1"], "--seed"),  # numpy's "expected non-negative integer"
        (["plan-bench", "--pairs", "0"], "--pairs"),
    ],
)
def test_a_bad_value_is_refused_by_its_option_before_anything_starts(argv, option, capsys):
    with pytest.raises(SystemExit) as stopped:
        build_parser().parse_args(argv)
    assert stopped.value.code == 2
    err = capsys.readouterr().err
    assert f"argument {option}:" in err and "Traceback" not in err


def test_faults_refuses_a_scenario_it_does_not_have_and_names_those_it_has():
    """``--only bogus`` printed an empty table and exited 0."""
    with pytest.raises(
        InputError, match=r"--only bogus: no such scenario; the scenarios: .*" + SCENARIOS[0].name
    ):
        run_all(only=("bogus",))


def test_soak_refuses_a_warm_up_as_long_as_the_run_and_a_file_for_a_directory(tmp_path):
    from controller.tools.bench.soak import run_soak_command

    parser = _subparser("soak")
    with pytest.raises(InputError, match="--warmup-s 60: must be shorter than --duration 60"):
        run_soak_command(parser.parse_args(["--duration", "60", "--warmup-s", "60"]), [])
    a_file = tmp_path / "good.mcap"
    a_file.write_bytes(b"")
    with pytest.raises(InputError, match="is not a directory"):
        run_soak_command(parser.parse_args(["--output-dir", str(a_file)]), [])


def test_ctrl_c_in_a_command_without_a_stop_of_its_own_is_one_line(monkeypatch, capsys):
    import controller.cli as cli

    def interrupted(args):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "cmd_bus_load", interrupted)
    assert cli.main(["bus-load"]) == 130
    assert capsys.readouterr().err == "cheope bus-load: interrupted\n"


def _killed_by_the_system(item):  # a scenario's process that the system (or Ctrl-C) ends
    os._exit(1)


def test_a_scenario_process_that_dies_is_one_named_error_not_a_traceback(monkeypatch):
    """Ctrl-C reaches the scan's workers too: one ended first and ``BrokenProcessPool`` came out
    as a traceback."""
    from controller.config import load_config
    from controller.errors import CheopeError
    from controller.tools.contour import scan

    monkeypatch.setattr(scan, "_run_one", _killed_by_the_system)  # the workers fork with it
    todo = iter([scan.ContourScenario("a", ()), scan.ContourScenario("b", ())])
    with pytest.raises(CheopeError, match=r"a scenario's process ended before its row \(0 of 2 done\)"):
        scan.run_scenarios(load_config(), {}, todo, None, 2, None, "cheope-test-")


def test_output_into_a_closed_pipe_ends_quietly():
    """``cheope plan --json | head -c 10`` printed "error: [Errno 32] Broken pipe" and exited 2."""
    script = (
        "import os, sys\n"
        "r, w = os.pipe(); os.close(r); os.dup2(w, 1)\n"  # stdout: a pipe nobody reads any more
        "from controller.cli import main\n"
        "sys.exit(main(['bus-load', '--json']))\n"
    )
    r = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=120, check=False
    )
    assert r.returncode == 141 and r.stderr == ""


def test_version_prints_the_installed_version(capsys):
    """``cheope --version`` said "the following arguments are required: command"."""
    from importlib import metadata

    with pytest.raises(SystemExit) as stopped:
        build_parser().parse_args(["--version"])
    assert stopped.value.code == 0
    assert capsys.readouterr().out == f"cheope {metadata.version('cheope-controller')}\n"


def test_bench_duration_help_states_the_default():
    text = _option(_subparser("bench"), "--duration").help or ""
    assert "issue" not in text and "default 300" in text


@pytest.mark.parametrize(
    "argv",
    [
        ["-v", "bus-load"],
        ["bus-load", "-v"],
        ["logs", "info", "-v", "x.mcap"],
        ["-v", "logs", "info", "x.mcap"],
        ["replay", "x.mcap", "--verify", "--verbose"],
    ],
)
def test_verbose_before_or_after_the_command(argv: list[str]):
    assert build_parser().parse_args(argv).verbose is True


def test_without_verbose_it_is_off():
    assert build_parser().parse_args(["bus-load"]).verbose is False
    assert build_parser().parse_args(["logs", "info", "x.mcap"]).verbose is False


def test_replay_rerun_takes_a_recording_after_it_as_the_input():
    assert rerun_input_and_output(None, "session.mcap") == ("session.mcap", None)
    assert rerun_input_and_output("session.mcap", "out.rrd") == ("session.mcap", "out.rrd")
    assert rerun_input_and_output("session.mcap", "") == ("session.mcap", None)
    with pytest.raises(InputError, match=re.escape("must be a .rrd")):
        rerun_input_and_output("a.mcap", "b.mcap")  # never overwrite a recording with Rerun's data
    with pytest.raises(InputError, match="which recording"):
        rerun_input_and_output(None, "out.rrd")


def test_replay_rerun_with_the_file_after_it_converts_that_file(tmp_path: Path):
    src = tmp_path / "session.mcap"
    src.write_bytes((DATA / "path_quarter_lap.mcap").read_bytes())
    r = subprocess.run(
        [sys.executable, "-m", "controller", "replay", "--rerun", str(src), "--json"],
        capture_output=True,
        text=True,
        check=False,
        timeout=120,
        env={"PATH": "/nonexistent", "HOME": str(tmp_path)},
    )  # no viewer can start: FILE.rrd
    assert r.returncode == 0, r.stderr
    result = json.loads(r.stdout)
    assert result["cycles"] > 0 and Path(result["output"]) == src.with_suffix(".rrd")
    assert {"/world/rods/capsules", "/world/sliders/boxes", "/world/platform/cylinders"} <= set(
        result["entities"]
    )
    assert (
        src.with_suffix(".rrd").stat().st_size > 0 and src.read_bytes()[:8] == b"\x89MCAP0\r\n"
    )  # input intact


def test_strict_json_has_null_for_nan_and_infinity():
    text = strict_json({"a": float("nan"), "b": [1.0, float("inf"), {"c": -float("inf")}], "d": (2.5,)})
    assert json.loads(text, parse_constant=_reject_constant) == {
        "a": None,
        "b": [1.0, None, {"c": None}],
        "d": [2.5],
    }


def test_plan_json_is_strict_json_for_a_refused_plan():
    # the paper's example crosses det M = 0: the report has NaN figures, printed as null
    r = subprocess.run(
        [sys.executable, "-m", "controller", "plan", "--paper-example", "--json"],
        capture_output=True,
        text=True,
        check=False,
        timeout=120,
    )
    assert r.returncode == 1, r.stderr
    report = json.loads(r.stdout, parse_constant=_reject_constant)
    assert report["ok"] is False and None in report.values()


class _Terminal(io.StringIO):
    def __init__(self, tty: bool) -> None:
        super().__init__()
        self.tty = tty

    def isatty(self) -> bool:
        return self.tty


def test_progress_line_only_on_a_terminal_and_erased_at_the_end():
    term = _Terminal(tty=True)
    with progress_line("cheope faults", term) as progress:
        progress("scenario 1/2: drive silent")
    text = term.getvalue()
    assert "cheope faults: 0 s  scenario 1/2: drive silent" in text and text.endswith("\r\x1b[K")
    pipe = _Terminal(tty=False)
    with progress_line("cheope faults", pipe) as progress:
        progress("scenario 1/2: drive silent")
    assert pipe.getvalue() == ""


def test_progress_line_shows_the_time_elapsed():
    now = [100.0]
    line = ProgressLine("cheope analyze", _Terminal(tty=True), clock=lambda: now[0])
    now[0] = 103.4
    line.update("cheope: workspace")
    assert line.line() == "cheope analyze: 3 s  cheope: workspace"


def test_faults_reports_each_scenario_before_running_it():
    heard: list[str] = []
    rows = run_all(only=(SCENARIOS[0].name,), progress=heard.append)
    assert heard == [f"scenario 1/1: {SCENARIOS[0].name}"] and len(rows) == 1


def _subcommands(parser, prefix=()):
    import argparse

    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in {id(p): (n, p) for n, p in action.choices.items()}.values():
                yield from _subcommands(sub, (*prefix, name))
            return
    yield prefix, parser


def test_every_argument_of_every_command_says_what_it_is():
    from controller.cli import build_parser

    missing = [
        f"cheope {' '.join(cmd)} {a.option_strings or a.dest}"
        for cmd, p in _subcommands(build_parser())
        for a in p._actions
        if not a.help and a.dest != "help"
    ]
    assert not missing, missing


def test_every_command_that_reports_has_json():
    """Each command prints something a script wants: ``--json`` on all of them (issue 40)."""
    from controller.cli import build_parser

    without = [
        " ".join(cmd) for cmd, p in _subcommands(build_parser()) if "--json" not in p._option_string_actions
    ]
    assert without == [], without


def test_fd_on_the_command_line_plans_the_bus_load_for_can_fd():
    """``cheope demo --rate 1000 --fd`` was refused on the classical bus's load (101.8 %)."""
    from controller.assembly import planned_bus_load
    from controller.cli import _config

    cfg = _config(build_parser().parse_args(["demo", "--rate", "1000", "--fd"]))
    assert cfg.bus.fd is True
    assert planned_bus_load(cfg).percent < 70.0


def test_one_spelling_per_idea_and_the_old_ones_still_read():
    """--bus, --output-dir, --duration everywhere (issue 40); --can, --plot, --keep, --out and
    --max-duration still parse, unlisted in the help."""
    from controller.cli import build_parser

    ap = build_parser()
    new = ap.parse_args(["demo", "--bus", "virtual:x", "--duration", "5", "--output-dir", "d"])
    old = ap.parse_args(["demo", "--can", "virtual:x", "--max-duration", "5", "--plot", "d"])
    assert (
        (new.bus, new.duration, new.output_dir)
        == (old.bus, old.duration, old.output_dir)
        == ("virtual:x", 5.0, "d")
    )
    for command, old_flag in (
        ("faults", "--keep"),
        ("analyze", "--out"),
        ("plan", "--plot"),
        ("bench", "--out"),
        ("soak", "--keep"),
    ):
        assert ap.parse_args([command, old_flag, "x"]).output_dir == "x"
    spellings = {
        flag
        for _, p in _subcommands(ap)
        for a in p._actions
        if a.help != "==SUPPRESS=="
        for flag in a.option_strings
    }
    assert not spellings & {"--can", "--plot", "--keep", "--out", "--max-duration"}
    assert {"--bus", "--output-dir", "--duration"} <= spellings


def test_a_ctrl_c_while_the_command_is_imported_is_one_line_not_a_traceback():
    """The command's imports take about a second: a Ctrl-C in them printed the traceback of
    whichever import it hit. Here the import of controller.cli raises it, as a Ctrl-C there does."""
    script = (
        "import sys\n"
        "class Interrupt:\n"
        "    def find_spec(self, name, path=None, target=None):\n"
        "        if name == 'controller.cli':\n"
        "            raise KeyboardInterrupt\n"
        "sys.meta_path.insert(0, Interrupt())\n"
        "from controller.cli_entry import main\n"
        "sys.exit(main())\n"
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert done.returncode == 130
    assert done.stderr == "cheope: interrupted\n"
