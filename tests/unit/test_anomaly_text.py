"""One line per cycle's bus anomaly (controller/core/safety_monitor.py): what, how many, where."""

from __future__ import annotations

from controller.core.cycle_data import Anomaly, BusAnomaly
from controller.core.safety_monitor import anomaly_text


def test_a_29_bit_frame_is_named_by_its_whole_identifier_not_as_a_cob_id() -> None:
    text = anomaly_text(BusAnomaly(Anomaly.EXTENDED_FRAME, 0x701, 2))
    assert (
        text == "2 frame(s) with a 29-bit identifier (CANopen's COB-IDs are 11-bit) (identifier 0x00000701)"
    )


def test_an_unknown_11_bit_frame_is_named_by_its_cob_id() -> None:
    assert anomaly_text(BusAnomaly(Anomaly.UNKNOWN_FRAME, 0x123, 1)) == (
        "1 frame(s) from a COB-ID no configured node uses (COB-ID 0x123)"
    )
