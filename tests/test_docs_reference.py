"""docs/ is reference (issue 37, item 6): today's design and figures and how to reproduce them.

How a figure was reached, round by round, lives in docs/history/ (one file per round), not in
the reference pages: no "first round", "the round before", "round 3" wording in README.md or
docs/*.md. Each history page is named by a reference page (so it is found), and names the
reference it leads to.
"""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
REFERENCE = (ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")))
HISTORY = sorted((ROOT / "docs" / "history").glob("*.md"))

_ORDINAL = (
    r"first|second|third|fourth|fifth|sixth|seventh|eighth|ninth|tenth|\d+(?:st|nd|rd|th)"
    r"|earlier|previous|later|last|next|this|that|each|every|the"
)
ROUND_WORDING = re.compile(
    rf"\b(?:{_ORDINAL})\s+rounds?\b(?!\s+trips?\b)|(?<!-)\brounds?\s+(?:\d+|one|two|three|four|before)\b"
    r"|\b(?:this|last|previous|earlier|next)\s+session\b|\bsession\s+before\b",
    re.IGNORECASE,
)
"""A round of work named as such ("the third round", "the round before", "round 4", "the
last session's change"); not a round trip, a round robin or a round ellipse, nor a zenoh
session or other sessions' jobs on the machine."""


def round_wording(text: str) -> list[str]:
    """The lines of ``text`` (numbered) that speak of rounds of work."""
    return [
        f"{n}: {line.strip()[:100]}"
        for n, line in enumerate(text.splitlines(), 1)
        if ROUND_WORDING.search(" ".join(line.split()))
    ]


def test_the_pattern_finds_history_and_not_other_rounds() -> None:
    history = (
        "Where a step's time went (first round)",
        "before the third round of speed work",
        "The rounds before, in order",
        "Reliability, round 4",
        "the tree before the round",
        "the last session's change",
        "the monitor of the session before",
    )
    other = (
        "the round trip is within 1 cm",
        "photos of the candidates, round robin",
        "about 1.7 for a round ellipse",
        "rounds of three publish calls",
        "round(x, 2)",
        "other sessions' jobs",
        "each its own zenoh client session",
        "matcher_worker_threads.py --rounds 3",
    )
    assert all(round_wording(t) for t in history)
    assert not any(round_wording(t) for t in other)


def test_reference_pages_hold_no_round_by_round_history() -> None:
    found = {
        p.relative_to(ROOT).as_posix(): lines
        for p in REFERENCE
        if (lines := round_wording(p.read_text()))
    }
    assert not found, f"move these to docs/history/ (one file per round): {found}"


def test_every_history_page_is_named_by_a_reference_page_and_names_its_reference() -> None:
    assert HISTORY, "docs/history/ holds the history moved out of the reference pages"
    reference = "\n".join(p.read_text() for p in REFERENCE)
    for page in HISTORY:
        assert page.stem in reference, f"no reference page names {page.name}"
        text = page.read_text()
        assert text.startswith("# "), page.name
        named = set(re.findall(r"docs/\w+\.md", text))
        assert named, f"{page.name} names no reference page it leads to"
        for doc in named:
            assert (ROOT / doc).is_file(), f"{page.name}: {doc} does not exist"
