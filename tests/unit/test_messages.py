"""The committed generated code matches cheope.proto, and messages round-trip."""

from __future__ import annotations

from controller.messages import cheope_pb2 as pb
from controller.messages.generate import HERE, generate


def test_generated_code_is_up_to_date(tmp_path):
    fresh = generate(tmp_path)
    assert fresh.read_text() == (HERE / "cheope_pb2.py").read_text(), \
        "cheope_pb2.py is stale: run python -m controller.messages.generate"


def test_cycle_round_trips_doubles_exactly():
    c = pb.Cycle(cycle=7, t_s=7 * 0.0025)
    c.inputs.drives.add(statusword=0x1637, position=0.1 + 0.2, fresh=True)
    c.outputs.targets.extend([1 / 3, 2 / 3, 0.58230929])
    back = pb.Cycle.FromString(c.SerializeToString())
    assert back.inputs.drives[0].position == 0.1 + 0.2
    assert list(back.outputs.targets) == [1 / 3, 2 / 3, 0.58230929]
    assert not back.inputs.HasField("sensor")
