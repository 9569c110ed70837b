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
    rx = dbc.decode_message(cob_ids.rpdo1(3), encode_drive_rpdo(0x000F, -123456))
    assert rx == {"Drive3_Controlword": 0x000F, "Drive3_TargetPosition": pytest.approx(-0.0123456)}
    tx = dbc.decode_message(cob_ids.tpdo1(1), encode_drive_tpdo(0x1637, 5823093))
    assert tx == {"Drive1_Statusword": 0x1637, "Drive1_PositionActual": pytest.approx(0.5823093)}


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
