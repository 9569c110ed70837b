"""COB-IDs of the CANopen predefined connection set (CiA 301) used by this project."""

NMT = 0x000
SYNC = 0x080
# RPDO1 (0x201) to RPDO4 (0x57F) of every node, and TPDO2 to TPDO4 between them: frames a CSP drive
# acts on only at the SYNC after them, or never (another device's TPDO)
RPDO1_TO_RPDO4 = range(0x200, 0x580)


def emcy(node_id: int) -> int:
    return 0x080 + node_id


def tpdo1(node_id: int) -> int:
    return 0x180 + node_id


def rpdo1(node_id: int) -> int:
    return 0x200 + node_id


def tpdo2(node_id: int) -> int:
    return 0x280 + node_id


def sdo_response(node_id: int) -> int:
    return 0x580 + node_id


def sdo_request(node_id: int) -> int:
    return 0x600 + node_id


def heartbeat(node_id: int) -> int:
    return 0x700 + node_id


def validate_node_id(node_id: int) -> int:
    if not 1 <= node_id <= 127:
        raise ValueError(f"CANopen node id must be in 1..127, got {node_id}")
    return node_id


def function_name(cob_id: int) -> str:
    """The CiA 301 predefined connection set's name of an 11-bit COB-ID's function."""
    if cob_id == NMT:
        return "NMT"
    if cob_id == SYNC:
        return "SYNC"
    code, node = cob_id >> 7, cob_id & 0x7F
    names = {
        1: "EMCY",
        3: "TPDO1",
        4: "RPDO1",
        5: "TPDO2",
        6: "RPDO2",
        7: "TPDO3",
        8: "RPDO3",
        9: "TPDO4",
        10: "RPDO4",
        11: "SDO response",
        12: "SDO request",
        14: "heartbeat",
    }
    if cob_id > 0x7FF or code not in names or node == 0:
        return "other"
    return names[code]
