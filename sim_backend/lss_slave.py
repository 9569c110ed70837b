"""An LSS slave (CiA 305) for a simulated node without a node id (quirk ``unconfigured``).

Requests come on 0x7E5, answers go on 0x7E4. The slave takes part in the LSS fast scan (CS 0x51)
while it has no node id and is waiting, switches to the configuration state on a selective switch
(CS 0x40..0x43) or a fast scan that found it, takes a node id (CS 0x11), stores it (CS 0x17)
and, switched back to waiting (CS 0x04) with a new id, starts as a CANopen node with it. Pure: a
request in, an answer (or none) out; the simulator process sends it and boots the node.
"""

from __future__ import annotations

from dataclasses import dataclass, field

LSS_REQUEST, LSS_RESPONSE = 0x7E5, 0x7E4
CS_SWITCH_STATE_GLOBAL = 0x04
CS_CONFIGURE_NODE_ID = 0x11
CS_STORE_CONFIGURATION = 0x17
CS_SWITCH_SELECTIVE = (0x40, 0x41, 0x42, 0x43)
CS_SWITCH_SELECTIVE_RESPONSE = 0x44
CS_IDENTIFY_NON_CONFIGURED_REMOTE_SLAVE = 0x4C
CS_IDENTIFY_SLAVE = 0x4F
CS_IDENTIFY_NON_CONFIGURED_SLAVE = 0x50
CS_FAST_SCAN = 0x51
CS_INQUIRE = (0x5A, 0x5B, 0x5C, 0x5D)  # vendor, product, revision, serial
CS_INQUIRE_NODE_ID = 0x5E
UNCONFIGURED = 0xFF
WAITING, CONFIGURATION = 0, 1
FAST_SCAN_RESET = 0x80  # bit checker 128: every unconfigured slave answers
ERROR_NONE, ERROR_OUT_OF_RANGE, ERROR_MANUFACTURER = 0, 1, 0xFF


def _answer(cs: int, *payload: int) -> bytes:
    return bytes((cs, *payload)).ljust(8, b"\0")


@dataclass
class LssSlave:
    """``identity``: vendor, product, revision, serial (0x1018 sub 1..4); ``accepts``: the node ids it
    takes (the simulated drive of an axis takes that axis' id only: the simulator's nodes are fixed)."""

    identity: tuple[int, int, int, int]
    accepts: frozenset[int]
    node_id: int = UNCONFIGURED  # active
    pending_id: int = UNCONFIGURED
    state: int = WAITING
    _selective: int = 0  # selective switch: parts of the address matched so far
    _scan_sub: int = 0  # fast scan: the part of the address being scanned
    started: bool = field(default=False)  # set once it has started with its new id

    def on_request(self, data: bytes) -> bytes | None:  # noqa: C901  (one branch per LSS command)
        """A request of the LSS master; the answer to send, or None."""
        if len(data) != 8:
            return None
        cs = data[0]
        if cs == CS_SWITCH_STATE_GLOBAL:
            self.state = data[1]
            self._selective = 0
            if self.state == WAITING and self.node_id == UNCONFIGURED and self.pending_id != UNCONFIGURED:
                self.node_id = self.pending_id  # CiA 305: an unconfigured node starts with its new id
                self.started = True
            return None
        if cs in CS_SWITCH_SELECTIVE:
            part = cs - CS_SWITCH_SELECTIVE[0]
            value = int.from_bytes(data[1:5], "little")
            if part == self._selective and value == self.identity[part]:
                self._selective += 1
                if self._selective == 4:
                    self.state, self._selective = CONFIGURATION, 0
                    return _answer(CS_SWITCH_SELECTIVE_RESPONSE)
            else:
                self._selective = 0
            return None
        if cs == CS_IDENTIFY_NON_CONFIGURED_REMOTE_SLAVE:
            return _answer(CS_IDENTIFY_NON_CONFIGURED_SLAVE) if self.node_id == UNCONFIGURED else None
        if cs == CS_FAST_SCAN:
            return self._fast_scan(data)
        if self.state != CONFIGURATION:
            return None
        if cs == CS_CONFIGURE_NODE_ID:
            new = data[1]
            if not (1 <= new <= 127 or new == UNCONFIGURED):
                return _answer(cs, ERROR_OUT_OF_RANGE)
            if new != UNCONFIGURED and new not in self.accepts:
                return _answer(cs, ERROR_MANUFACTURER)
            self.pending_id = new
            return _answer(cs, ERROR_NONE)
        if cs == CS_STORE_CONFIGURATION:
            return _answer(cs, ERROR_NONE)
        if cs in CS_INQUIRE:
            return _answer(cs, *self.identity[cs - CS_INQUIRE[0]].to_bytes(4, "little"))
        if cs == CS_INQUIRE_NODE_ID:
            return _answer(cs, self.node_id)
        return None

    def _fast_scan(self, data: bytes) -> bytes | None:
        """CiA 305 fast scan: answer while the bits at and above the checked one match the part of
        the address being scanned; the last bit of the serial number confirmed, configuration state."""
        if self.node_id != UNCONFIGURED or self.state != WAITING:
            return None
        id_number = int.from_bytes(data[1:5], "little")
        bit_check, sub, nxt = data[5], data[6], data[7]
        if bit_check == FAST_SCAN_RESET:
            self._scan_sub = 0
            return _answer(CS_IDENTIFY_SLAVE)
        if sub != self._scan_sub or bit_check > 31:
            return None
        mask = (0xFFFFFFFF << bit_check) & 0xFFFFFFFF
        if (self.identity[sub] ^ id_number) & mask:
            return None
        if bit_check == 0:
            self._scan_sub = nxt
            if nxt < sub:  # the whole address matched: this slave is the one
                self.state = CONFIGURATION
        return _answer(CS_IDENTIFY_SLAVE)
