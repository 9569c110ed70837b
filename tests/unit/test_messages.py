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


def test_the_tracker_and_plans_ready_round_trip_into_the_steps_inputs():
    """Replay feeds the step what it got: the tracker's sample and the off-loop planner's progress."""
    from controller.core.cycle_data import CycleInputs, DriveFeedback, TrackerFeedback
    from logs.messages import inputs_from_pb, inputs_to_pb

    inputs = CycleInputs(drives=(DriveFeedback(0x1637, 0.1 + 0.2, True),),
                         tracker=TrackerFeedback((1 / 3, -0.0251, 0.2713), (0.075, 0.31, -0.532), 0, 42, True),
                         plans_ready=2)
    msg = pb.CycleInputs()
    inputs_to_pb(inputs, msg)
    assert inputs_from_pb(pb.CycleInputs.FromString(msg.SerializeToString())) == inputs
    without = CycleInputs(drives=inputs.drives)
    msg = pb.CycleInputs()
    inputs_to_pb(without, msg)
    assert inputs_from_pb(msg) == without and not msg.HasField("tracker")
