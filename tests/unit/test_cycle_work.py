"""The cycle's work stays within its budget (controller/tools/bench/cycle_work.py, docs/measurements/speed.md).

Deterministic counts of the interpreter over a fixed window of a simulated-time run, not timing:
the same code and configuration give the same figures on any machine, busy or not. A change that
makes the cycle about 1.3 times costlier fails here: raising the budget is then a decision, taken
in the tool's ``BUDGET_PER_CYCLE`` and in the docs' table together.
"""

from __future__ import annotations

import re
from pathlib import Path

import can
import pytest

from controller.tools.bench.cycle_work import (
    BUDGET_PER_CYCLE,
    DEFAULT_TASK_WINDOWS,
    count_work,
    functions_per_cycle,
    measured_run,
    over_budget,
    reference_run,
)
from drivers.cob_ids import tpdo1

SPEED_PAGE = Path(__file__).resolve().parents[2] / "docs" / "measurements" / "speed.md"


@pytest.mark.parametrize("task", sorted(DEFAULT_TASK_WINDOWS))
def test_the_cycle_stays_within_its_budget(task: str):
    skip, cycles = DEFAULT_TASK_WINDOWS[task]
    result = count_work(task, skip, cycles)
    assert not over_budget(result), (over_budget(result), result)
    # every part of the cycle was counted: a window that measured nothing would pass any budget
    for part, bytecodes in result["bytecodes_per_cycle_by_part"].items():
        assert bytecodes > 100, (part, result)


def test_a_script_the_controller_does_not_reproduce_is_refused():
    """The measured cycles must be the reference run's: a device's answer changed changes the outputs."""
    script = reference_run("path", [], 200)
    for answers in script.per_send[150:]:  # from cycle ~50 on, drive 1 reports FAULT (CiA 402 0x0008)
        for i, msg in enumerate(answers):
            if msg.arbitration_id == tpdo1(1):
                answers[i] = can.Message(
                    arbitration_id=msg.arbitration_id,
                    data=b"\x08\x00" + bytes(msg.data[2:]),
                    is_extended_id=False,
                )
    with pytest.raises(RuntimeError, match="differ from the reference run's from cycle"):
        measured_run("path", [], script, 100, 50, count=False, marker=False)


def test_the_docs_state_the_budget_the_test_holds():
    text = SPEED_PAGE.read_text()
    for task, budget in BUDGET_PER_CYCLE.items():
        row = re.search(rf"^\| budget, {task} task \|(.*)$", text, re.M)
        assert row is not None, f"no budget row for the {task} task in {SPEED_PAGE.name}"
        numbers = [int(n.replace(" ", "")) for n in re.findall(r"\d[\d ]*\d|\d", row.group(1))]
        assert numbers[:2] == [budget["bytecodes"], budget["c_calls"]], row.group(0)


def test_the_compiled_functions_are_named_and_ranked_per_cycle():
    # callgrind_annotate --inclusive=yes lines as valgrind 3.19 writes them: a function's own entry
    # (with its object) and its lines' shares by source file (without: not counted), an
    # interpreter function, a line without percentages, and a line of another section
    annotated = """\
129,010,552 (59.22%)  /w/build/mypyc/controller/__native_compiled_law.c:CPyDef_control_law___ControlLaw___step [/w/x.so]
 30,606,894 (14.05%)  /p/Objects/object.c:PyObject_GetAttr [/p/libpython3.11.so.1.0]
 13,389,600 ( 6.15%)  /w/build/mypyc/controller/__native_compiled_law.c:CPyDef_contact_guard____median_of [/w/x.so]
  2,474,880 ( 1.14%)  /p/include/python3.11/object.h:CPyDef_contact_guard____median_of
 14,000,000 ( 6.43%)  /w/build/mypyc/controller/__native_compiled_law.c:CPyDef_contact_guard____median_of
 54,256,503 (24.90%)  /w/build/mypyc/controller/__native_compiled_law.c:CPyDef_control_law___ControlLaw____running [/w/x.so]
 17,126,463  /w/build/mypyc/controller/__native_compiled_law.c:CPyDef_path_task___PathTask___step [/w/x.so]
 3,600      cpy_r_r15 = CPyDef_contact_guard____median_of(cpy_r_window, cpy_r_r12);
"""
    assert functions_per_cycle(annotated, 300, 2) == {
        "control_law.ControlLaw.step": 430035,
        "control_law.ControlLaw._running": 180855,
    }
    by_function = functions_per_cycle(annotated, 300, 9)
    assert by_function["contact_guard._median_of"] == 44632
    assert by_function["path_task.PathTask.step"] == 57088
    assert len(by_function) == 4
