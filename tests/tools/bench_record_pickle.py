"""What the task values' keys cost the recorder's pipe, on the cycles of a recorded session.

    .venv/bin/python tests/tools/bench_record_pickle.py SESSION.mcap

The session's cycles are rebuilt as the CYCLE records the recorder pickles into its writer's pipe
(``tests/tools/bench_recording_size.py`` ``records``), and each is pickled (the loop's side) and
unpickled (the writer's side) as it is, and with its task values as a tuple of values alone (what
a record would carry if the keys went once, when they change). Prints bytes and µs per record
(the median of 5 passes over at most 2 000 cycles). Not a pytest benchmark: it asserts nothing.
"""

from __future__ import annotations

import json
import pickle
import statistics
import sys
import time
from pathlib import Path

from bench_recording_size import records

from logs.session_writer import CYCLE

TASK_VALUES = 13  # the task values' place in a cycle's values (logs/cycle_encoding.py)
VALUES = 7  # the cycle's values' place in a CYCLE record (logs/recorder.py on_cycle)


def without_keys(record: tuple[object, ...]) -> tuple[object, ...]:
    values = list(record[VALUES])  # type: ignore[call-overload]
    task = values[TASK_VALUES]
    values[TASK_VALUES] = None if task is None else tuple(task.values())
    return (*record[:VALUES], tuple(values), *record[VALUES + 1 :])


def per_record_us(work: list[object], fn: object) -> float:
    passes = []
    for _ in range(5):
        t0 = time.perf_counter()
        for x in work:
            fn(x)  # type: ignore[operator]
        passes.append((time.perf_counter() - t0) / len(work) * 1e6)
    return round(statistics.median(passes), 2)


def main(src: Path) -> dict[str, dict[str, float]]:
    cycles = [r for r in records(src)[0] if r[0] == CYCLE][-2000:]
    out = {}
    for name, recs in (
        ("as recorded", cycles),
        ("task values without keys", [without_keys(r) for r in cycles]),
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
