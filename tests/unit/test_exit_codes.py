"""The exit status of a run over a bus (`cheope run`, and `cheope demo` since it exited 0 with its
recording lost: an outside tester's finding)."""

from __future__ import annotations

from controller import cli


def test_done_fault_and_a_lost_recording_have_their_own_status():
    assert cli.run_exit_code({"final_mode": "DONE", "recording": {"error": ""}}) == cli.EXIT_DONE
    assert cli.run_exit_code({"final_mode": "FAULT", "recording": {"error": "gone"}}) == cli.EXIT_FAULT
    lost = {"final_mode": "DONE", "recording": {"error": "the writer process stopped reading"}}
    assert cli.run_exit_code(lost) == cli.EXIT_RECORDING_LOST == 3
