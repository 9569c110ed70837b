"""What the shipped Foxglove layout (logs/foxglove_layout.json) names, and Foxglove message paths resolved
on decoded Protobuf messages: shared by the recorded (tests/integration/test_foxglove_layout.py) and the
live (tests/integration/test_live_views.py) checks.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any

import logs

_STEP = re.compile(r"(?P<name>\w+)(?:\[(?P<index>\d+)\])?")


def layout() -> dict[str, Any]:
    return json.loads((Path(logs.__file__).parent / "foxglove_layout.json").read_text())


def panels(kind: str) -> list[dict[str, Any]]:
    """The panels of one kind (``3D``, ``Plot``, ``RosOut``) by their ``Kind!id`` keys."""
    return [v for k, v in layout()["configById"].items() if k.startswith(f"{kind}!")]


def plot_paths() -> list[list[str]]:
    """Each plot panel's message paths (``/cycle.inputs.drives[0].position``)."""
    return [[p["value"] for p in plot["paths"]] for plot in panels("Plot")]


def named_topics() -> set[str]:
    """Every topic a panel of the layout reads: the 3D panel's topics, the log panel's, the plots'."""
    topics = {t for p in panels("3D") for t in p["topics"]}
    topics |= {p["topicToRender"] for p in panels("RosOut")}
    topics |= {path.split(".", 1)[0] for paths in plot_paths() for path in paths}
    return topics


def resolve(message: Any, path: str) -> float | None:
    """The number a Foxglove message path (after the topic) picks in ``message``, None where it picks nothing.

    Handles what the layout uses: fields, ``[i]`` into repeated fields, and a key into a map field.
    """
    value: Any = message
    for step in path.split(".", 1)[1].split("."):
        m = _STEP.fullmatch(step)
        assert m is not None, path
        name, index = m["name"], m["index"]
        if isinstance(value, (int, float)) or value is None:
            return None
        if hasattr(value, "DESCRIPTOR") and name in value.DESCRIPTOR.fields_by_name:
            field = value.DESCRIPTOR.fields_by_name[name]
            if field.has_presence and not value.HasField(name):
                return None
            value = getattr(value, name)
        elif hasattr(value, "keys"):  # a map field: the step is the key
            if name not in value:
                return None
            value = value[name]
        else:
            return None
        if index is not None:
            value = value[int(index)] if int(index) < len(value) else None
    return float(value) if isinstance(value, (int, float)) and math.isfinite(value) else None
