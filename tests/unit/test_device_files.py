"""The EDS and DBC files describe exactly the frames the codecs produce."""

from __future__ import annotations

import canopen
import cantools
import pytest

from drivers import cob_ids
from drivers.pdo_codec import (
    FORCE_N_PER_COUNT,
    TORQUE_NM_PER_COUNT,
    encode_drive_rpdo,
    encode_drive_tpdo,
    encode_sensor_frame,
)


def _mapping(od, index):
    rec = od[index]
    return [rec[i].default for i in range(1, rec[0].default + 1)]


def test_drive_eds_pdo_mapping_matches_the_codec(repo_root):
    od = canopen.import_od(str(repo_root / "drivers/eds/cheope_drive.eds"), node_id=2)
    assert od[0x1400][1].default == cob_ids.rpdo1(2)
    assert od[0x1800][1].default == cob_ids.tpdo1(2)
    assert od[0x1400][2].default == 1 and od[0x1800][2].default == 1  # synchronous, every SYNC
    # (index << 16) | (subindex << 8) | bit length
    assert _mapping(od, 0x1600) == [0x60400010, 0x607A0020]  # controlword u16, target position i32
    assert _mapping(od, 0x1A00) == [0x60410010, 0x60640020]  # statusword u16, position actual i32
    assert od[0x1000].default == 0x00020192  # CiA 402 servo drive


def test_sensor_eds_pdo_mapping_matches_the_codec(repo_root):
    od = canopen.import_od(str(repo_root / "drivers/eds/force_sensor.eds"), node_id=16)
    assert od[0x1800][1].default == cob_ids.tpdo1(16)
    assert od[0x1801][1].default == cob_ids.tpdo2(16)
    assert _mapping(od, 0x1A00) == [0x20000110, 0x20000210, 0x20000310, 0x20020008, 0x20030008]
    assert _mapping(od, 0x1A01) == [0x20010110, 0x20010210, 0x20010310, 0x20020008, 0x20030008]


@pytest.fixture
def dbc(repo_root):
    return cantools.database.load_file(str(repo_root / "drivers/dbc/cheope.dbc"))


def test_dbc_decodes_drive_frames_like_the_codec(dbc):
    rx = dbc.decode_message(cob_ids.rpdo1(3), encode_drive_rpdo(0x000F, -123456), decode_choices=False)
    assert rx == {"Drive3_Controlword": 0x000F, "Drive3_TargetPosition": pytest.approx(-0.0123456)}
    tx = dbc.decode_message(cob_ids.tpdo1(1), encode_drive_tpdo(0x1637, 5823093), decode_choices=False)
    assert tx.pop("Drive1_PositionActual") == pytest.approx(0.5823093)
    # the statusword as its 16 bits, each a signal of its own: together the whole word
    assert len(tx) == 16 and sum(v << i for i, v in enumerate(tx.values())) == 0x1637


def test_dbc_names_the_nmt_states_the_statusword_bits_and_the_controlword_commands(dbc):
    """Value tables: what a CAN viewer shows instead of numbers."""
    for node in (1, 2, 3, 16):
        states = {
            str(dbc.decode_message(cob_ids.heartbeat(node), bytes([s])).popitem()[1])
            for s in (0x00, 0x04, 0x05, 0x7F)
        }
        assert states == {"Boot-up", "Stopped", "Operational", "Pre-operational"}
    fault = dbc.decode_message(cob_ids.tpdo1(2), encode_drive_tpdo(0x0218, 0))  # fault, quick stop active
    assert fault["Drive2_SW_Fault"] == "fault" and fault["Drive2_SW_QuickStop"] == "quick stop active"
    assert fault["Drive2_SW_OperationEnabled"] == "operation disabled"
    enable = dbc.decode_message(cob_ids.rpdo1(2), encode_drive_rpdo(0x000F, 0))
    assert enable["Drive2_Controlword"] == "Enable operation"
    nmt = dbc.decode_message(cob_ids.NMT, bytes([0x81, 0]))
    assert nmt == {"NMT_Command": "Reset node", "NMT_NodeId": "All nodes"}


def test_dbc_decodes_sensor_frames_like_the_codec(dbc):
    f = dbc.decode_message(
        cob_ids.tpdo1(16), encode_sensor_frame((1.5, -2.25, 40.0), FORCE_N_PER_COUNT, 4, 9)
    )
    assert (
        f["Fx"] == pytest.approx(1.5) and f["Fy"] == pytest.approx(-2.25) and f["Fz"] == pytest.approx(40.0)
    )
    assert f["F_Status"] == 4 and f["F_Counter"] == 9
    t = dbc.decode_message(cob_ids.tpdo2(16), encode_sensor_frame((0.5, 0, -1.25), TORQUE_NM_PER_COUNT, 0, 9))
    assert t["Tx"] == pytest.approx(0.5) and t["Tz"] == pytest.approx(-1.25)
