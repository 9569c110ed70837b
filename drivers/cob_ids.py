"""COB-IDs of the CANopen predefined connection set (CiA 301) used by this project."""

NMT = 0x000
SYNC = 0x080


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
