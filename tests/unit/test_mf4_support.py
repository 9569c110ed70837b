"""python-can's MF4 format stays out of the controller's processes until an ``.mf4`` is written.

With asammdf installed (the dev set-up), ``import can`` alone imported pandas and pyarrow into the
loop's, the simulator's and the writer's processes, with a normal-priority allocator thread
(controller/mf4_support.py).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[2]

# What the three processes of a run import first: the loop's service, the simulator's server, the
# recording's writer (each package's __init__ imports controller first).
_PROCESS_IMPORTS = """
import json, os, sys
import {first}
import can
threads = sorted(open(f"/proc/self/task/{{t}}/comm").read().strip() for t in os.listdir("/proc/self/task"))
print(json.dumps({{"loaded": sorted(m for m in ("asammdf", "pandas", "pyarrow") if sys.modules.get(m)),
                   "threads": threads}}))
"""


def _run(code: str) -> dict[str, Any]:
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT, timeout=120
    )
    result: dict[str, Any] = json.loads(out.stdout.splitlines()[-1])
    return result


@pytest.mark.parametrize("first", ["controller.shell.service", "sim_backend.server", "logs.session_writer"])
def test_the_runs_processes_import_python_can_without_pandas_or_pyarrow(first: str) -> None:
    seen = _run(_PROCESS_IMPORTS.format(first=first))
    assert seen["loaded"] == []
    assert "jemalloc_bg_thd" not in seen["threads"]


# asammdf comes with the dev set-up (the mf4 extra), as for tests/unit/test_can_export.py's mf4 case
def test_a_file_written_after_load_reads_back_in_the_same_process(tmp_path: Path) -> None:
    out = tmp_path / "x.mf4"
    code = f"""
import json, sys
import controller, can
from controller import mf4_support
hidden = sys.modules.get("asammdf") is None
mf4_support.load()
with can.MF4Writer({str(out)!r}) as w:
    w.on_message_received(can.Message(arbitration_id=0x181, data=bytes([1, 2, 3]), timestamp=1.0))
back = [(m.arbitration_id, list(m.data)) for m in can.LogReader({str(out)!r})]
print(json.dumps({{"hidden_before_load": hidden, "read_back": back}}))
"""
    seen = _run(code)
    assert seen["hidden_before_load"] is True
    assert seen["read_back"] == [[0x181, [1, 2, 3]]]
