"""The exit status of a run over a bus (`cheope run`, and `cheope demo` since it exited 0 with its
recording lost: an outside tester's finding)."""

from __future__ import annotations

from controller import cli


def test_done_fault_and_a_lost_recording_have_their_own_status():
    assert cli.run_exit_code({"final_mode": "DONE", "recording": {"error": ""}}) == cli.EXIT_DONE
    assert cli.run_exit_code({"final_mode": "FAULT", "recording": {"error": "gone"}}) == cli.EXIT_FAULT
    lost = {"final_mode": "DONE", "recording": {"error": "the writer process stopped reading"}}
    assert cli.run_exit_code(lost) == cli.EXIT_RECORDING_LOST == 3


def test_done_before_the_task_finished_is_said_and_in_the_summary(capsys):
    """A run stopped by --duration ends DONE, exit 0, as documented; an outside tester read "DONE"
    after --duration 15 as the experiment done (44dbcbc). The summary says whether the task
    finished, and stderr says so when it did not."""
    import json

    assert cli.main(["demo", "--task", "path", "--simulated-time", "--json", "--duration", "1"]) == 0
    out, err = capsys.readouterr()
    assert json.loads(out)["task_finished"] is False
    assert "cheope demo: note: the task did not finish: the run was stopped first" in err
    assert cli.main(["demo", "--task", "path", "--simulated-time", "--json"]) == 0
    out, err = capsys.readouterr()
    assert json.loads(out)["task_finished"] is True and "did not finish" not in err


def test_a_run_stopped_by_its_lost_recording_says_so_not_a_signal(capsys):
    """recording.on_failure = "stop" ends the run DONE before its task's end: the note names the
    recording's failure (a full disk), not --duration or a signal."""
    error = "writing /media/x.mcap failed: [Errno 28] No space left on device"
    cli.say_if_unfinished(
        {"final_mode": "DONE", "task_finished": False, "recording": {"error": error, "on_failure": "stop"}},
        "cheope run",
    )
    err = capsys.readouterr().err
    assert 'the recording failed and recording.on_failure = "stop"' in err and "No space left" in err
    assert "a signal" not in err
    cli.say_if_unfinished(
        {"final_mode": "DONE", "task_finished": False, "recording": {"error": ""}}, "cheope run"
    )
    assert "--duration, a signal or cheope stop" in capsys.readouterr().err


def test_plots_that_cannot_be_written_do_not_cost_the_runs_summary(tmp_path, monkeypatch, capsys):
    """An outside tester's --output-dir on a full disk: after the whole run, "error: [Errno 28] No
    space left on device", exit 2, no summary. The summary is printed, the plots' failure named."""
    import errno
    import json

    from controller.tools.contour import experiment

    def full_disk(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(experiment, "plot_contour", full_disk)
    argv = [
        "demo",
        "--task",
        "contour",
        "--simulated-time",
        "--json",
        "--duration",
        "2",
        "--output-dir",
        str(tmp_path),
    ]
    assert cli.main(argv) == 0
    out, err = capsys.readouterr()
    summary = json.loads(out)
    assert summary["final_mode"] == "DONE" and summary["plots"] == []
    assert summary["plots_error"] == f"cannot write the plots in {tmp_path}: No space left on device"
    assert "cheope demo: warning: cannot write the plots in" in err


def test_laps_well_below_their_commanded_speed_are_said(capsys):
    """An outside tester's part with five times the estimated friction: every lap at 10 mm/s, DONE,
    exit 0, nothing said. A lap below 75 % of its commanded speed is named on stderr."""
    laps = [
        {"lap": 1, "speed_commanded_m_s": 0.02, "speed_achieved_m_s": 0.0198},
        {"lap": 2, "speed_commanded_m_s": 0.04, "speed_achieved_m_s": 0.0101},
        {"lap": 3, "speed_commanded_m_s": 0.06, "speed_achieved_m_s": 0.0101},
    ]
    cli.say_if_laps_ran_slow({"final_mode": "DONE", "contour": {"laps": laps}}, "cheope demo")
    err = capsys.readouterr().err
    assert "cheope demo: note: lap(s) 2 at 10.1 of 40, 3 at 10.1 of 60 mm/s ran below 75% of" in err
    shipped = [{"lap": 3, "speed_commanded_m_s": 0.06, "speed_achieved_m_s": 0.0596}]
    cli.say_if_laps_ran_slow({"contour": {"laps": shipped}}, "cheope demo")
    cli.say_if_laps_ran_slow({"final_mode": "DONE"}, "cheope run")  # no contour: nothing to say
    cli.say_if_laps_ran_slow({"contour": {"laps": [{"lap": 1, "speed_commanded_m_s": None}]}}, "cheope demo")
    assert capsys.readouterr().err == ""


def test_a_tracer_of_the_controller_is_said_on_stderr(capsys):
    """A traced loop waits for its tracer (controller/shell/tracer_watch.py): the run says who traced it."""
    tracers = [{"pid": 4242, "name": "strace", "seen_s": [29.0, 39.0], "looks": 11}]
    cli.say_if_the_controller_was_traced({"cpu_shield": {"tracers": tracers}}, "cheope demo")
    err = capsys.readouterr().err
    assert "cheope demo: note: the controller was traced: strace (pid 4242)" in err
    assert "in 11 look(s)" in err and "between 29 and 39 s" in err
    cli.say_if_the_controller_was_traced({"cpu_shield": {"cpus": [1]}}, "cheope demo")
    cli.say_if_the_controller_was_traced({}, "cheope demo")  # no shield: nothing to say
    assert capsys.readouterr().err == ""
