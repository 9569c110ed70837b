"""``replay --verify`` on a recording whose first chunk is damaged names the damage.

It said the file "starts at cycle 93 (sequence 93) without a keyframe: verify it with the session's
earlier files", a file of one session's middle, while ``logs info --check`` named the damaged
chunk (an outside tester's finding). Both read the file with the one walk (logs/reader.py); the
check now says the walk's words, and why it has no start.
"""

from __future__ import annotations

import struct
from pathlib import Path

import pytest

from controller.cli import main
from logs.reader import read_info
from logs.replay_verify import verify

RECORDING = Path(__file__).resolve().parents[1] / "data" / "contour_contact.mcap"


def _chunk(raw: bytes, k: int) -> tuple[int, int]:
    """(offset, length with its 9-byte header) of chunk record ``k`` (0: the first)."""
    pos = 8
    while True:
        opcode, length = struct.unpack_from("<BQ", raw, pos)
        if opcode == 0x06:
            if k == 0:
                return pos, 9 + length
            k -= 1
        pos += 9 + length


def _flipped(raw: bytearray, offset: int, length: int) -> None:
    raw[offset + length // 2] ^= 0xFF  # in the compressed data: the chunk fails its CRC


def _zeroed(raw: bytearray, offset: int, length: int) -> None:
    raw[offset : offset + length] = bytes(length)  # the record header too: the walk resumes after it


@pytest.mark.parametrize("damage", [_flipped, _zeroed])
def test_a_damaged_first_chunk_is_named_not_taken_for_a_missing_keyframe(damage, tmp_path, capsys):
    raw = bytearray(RECORDING.read_bytes())
    damage(raw, *_chunk(bytes(raw), 0))
    path = tmp_path / "damaged.mcap"
    path.write_bytes(raw)

    assert main(["replay", str(path), "--verify"]) == 3  # nothing checked: part of the file unreadable
    said = capsys.readouterr().out.strip()
    assert "without a keyframe" not in said and "earlier files" not in said
    assert said.startswith(
        "NOT VERIFIED: nothing verified: the start of damaged.mcap (its keyframe or first cycles, "
        "before cycle 93, sequence 93) is in a damaged part of the file"
    )
    damage_named = read_info(path).problems  # what logs info --check says
    assert damage_named and all(problem in said for problem in damage_named)


def test_cycles_lost_with_a_zeroed_chunk_are_said_lost_in_the_damage(tmp_path):
    """A zeroed chunk is a damaged record header the walk resumes after (no damaged chunk counted):
    the gap it left was "missing (the file does not say why...)" beside the damage named."""
    raw = bytearray(RECORDING.read_bytes())
    _zeroed(raw, *_chunk(bytes(raw), 3))
    path = tmp_path / "zeroed.mcap"
    path.write_bytes(raw)
    gap = next(p for p in verify(path).problems if "before cycle" in p)
    assert "lost in a damaged part of the file" in gap and "does not say why" not in gap
