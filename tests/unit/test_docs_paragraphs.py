"""The documentation reads in paragraphs of about 150 words at most: a longer one mixes things a
reader wants apart (issue 40 found a 554-word paragraph with measurement history in reference text).

A paragraph: consecutive lines of prose; headings, tables, list items, figures and code blocks
end one (a list item is a paragraph of its own). The generated configuration-keys page is not
prose. ``LONG`` names the paragraphs longer than the limit that are still to split, by page and
their first words: the test fails for any other, and for one of them that grew.
"""

from __future__ import annotations

from pathlib import Path

DOCS = Path(__file__).resolve().parents[2] / "docs"
LIMIT_WORDS = 160  # "about 150"
GENERATED = {"configuration-keys.md"}
# page -> {first words: words now}; to split, not to grow (their pages belong to other open work)
LONG: dict[str, dict[str, int]] = {
    "reference/canopen.md": {
        "**SYNC from the kernel**": 474,
        "The kernel's intervals have": 204,
        "**A real drive on `socketcan:can0`:**": 233,
        "**Homing** (`drivers/homing.py`, CiA": 188,
        "Emergency codes of the": 187,
    },
    "concepts/supervision.md": {
        "- *A measurement is": 237,
        "**A second sender on": 233,
    },
    "concepts/contour-tracking.md": {
        "`controller/tasks/contour_tracking.py`, a pure task": 285,
        "Why: the compliance k": 268,
        "The simulated drives latch": 191,
        "The normal is not": 183,
        "The simulated world: a": 178,
        "Before (08b8a67, 3 runs": 174,
    },
    "measurements/history.md": {"The rounded star misses": 313, "Measured again at d299c9a": 167},
    "reference/cli.md": {"- `udp_multicast` (default): python-can's": 279},
    "concepts/robots.md": {
        "**Closed loop** (issue 20": 253,
        "**The 3-nSPU planner** (`controller/robots/nspu/planning/`,": 220,
    },
    "tutorial/real-drive.md": {"1. **Bring the interface up**": 223},
    "measurements/speed.md": {"`cheope bench` runs the": 209},
    "concepts/design-decisions.md": {"- **A late or": 183},
    "guides/service.md": {
        "**Bounded memory.** Nothing grows": 182,
        "**systemd.** `docs/systemd/cheope-controller.service` is": 164,
    },
    "concepts/architecture.md": {"**Who reads the configuration.**": 164},
}


def paragraphs(text: str) -> list[str]:
    out: list[str] = []
    current: list[str] = []
    fenced = False

    def close() -> None:
        if current:
            out.append(" ".join(line.strip() for line in current))
            current.clear()

    for line in text.splitlines():
        stripped = line.strip()
        if stripped.startswith("```"):
            close()
            fenced = not fenced
            continue
        if fenced:
            continue
        if not stripped or stripped.startswith(("|", "#", "![", "<")):
            close()
            continue
        if stripped.startswith(("- ", "* ")) or stripped[:3].rstrip(".").isdigit():
            close()
        current.append(line)
    close()
    return out


def test_no_paragraph_is_much_over_150_words():
    too_long = []
    for page in sorted(DOCS.rglob("*.md")):
        if page.name in GENERATED:
            continue
        name = page.relative_to(DOCS).as_posix()
        allowed = LONG.get(name, {})
        for paragraph in paragraphs(page.read_text()):
            words = len(paragraph.split())
            if words <= LIMIT_WORDS:
                continue
            known = [n for start, n in allowed.items() if paragraph.startswith(start)]
            if not known or words > known[0]:
                too_long.append(f"{name}: {words} words: {paragraph[:70]}...")
    assert not too_long, "paragraphs over about 150 words (split them):\n" + "\n".join(too_long)


def test_the_paragraphs_are_found_as_a_reader_sees_them():
    text = (
        "First line\nsecond line.\n\n| a | b |\n\n- item one\n  goes on\n- item two\n\n```\ncode\n```\nlast"
    )
    assert paragraphs(text) == ["First line second line.", "- item one goes on", "- item two", "last"]
