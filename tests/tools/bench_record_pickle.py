"""What the task fields' names cost the recorder's pipe, on the cycles of a recorded session.

    .venv/bin/python tests/tools/bench_record_pickle.py SESSION.mcap

The session's cycles are rebuilt as the CYCLE records the recorder pickles into its writer's pipe
(``controller.tools.bench.writer_work.session_records``), and each is pickled (the loop's side) and
unpickled (the writer's side) with its task fields' names, as a record whose names changed
carries them, and without (``logs.cycle_encoding.with_task_names`` of None: what the recorder
sends while they are unchanged). Prints bytes and µs per record (the median of 5 passes over at
most 2 000 cycles). Not a pytest benchmark: it asserts nothing.
"""

from __future__ import annotations

import json
import pickle
import statistics
import sys
import time
from pathlib import Path

from controller.tools.bench.writer_work import session_records
from logs.cycle_encoding import TASK_FIELDS_AT, with_task_names
from logs.session_writer import CYCLE

VALUES = 7  # the cycle's values' place in a CYCLE record (logs/recorder.py on_cycle)


def without_names(record: tuple[object, ...]) -> tuple[object, ...]:
    values = record[VALUES]
    if values[TASK_FIELDS_AT] is None:  # type: ignore[index]
        return record
    return (*record[:VALUES], with_task_names(values, None), *record[VALUES + 1 :])  # type: ignore[arg-type]


def per_record_us(work: list[object], fn: object) -> float:
    passes = []
    for _ in range(5):
        t0 = time.perf_counter()
        for x in work:
            fn(x)  # type: ignore[operator]
        passes.append((time.perf_counter() - t0) / len(work) * 1e6)
    return round(statistics.median(passes), 2)


def main(src: Path) -> dict[str, dict[str, float]]:
    cycles = [r for r in session_records(src)[0] if r[0] == CYCLE][-2000:]
    out = {}
    for name, recs in (
        ("with the names", cycles),
        ("without the names", [without_names(r) for r in cycles]),
    ):
        blobs = [pickle.dumps(r, pickle.HIGHEST_PROTOCOL) for r in recs]
        out[name] = {
            "bytes": round(sum(map(len, blobs)) / len(blobs)),
            "dumps_us": per_record_us(recs, lambda r: pickle.dumps(r, pickle.HIGHEST_PROTOCOL)),
            "loads_us": per_record_us(blobs, pickle.loads),
        }
    return out


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    print(json.dumps(main(Path(sys.argv[1])), indent=1))
