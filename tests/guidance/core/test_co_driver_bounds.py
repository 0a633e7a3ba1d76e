"""Issue 40, low: the co-driver's lines are bounded (``guidance.core.co_driver``): "lsr" x
33,334 blocked the loop for 1.5 s and an 8 MB line cost 120 MB. A line is at most
``MAX_LINE_CHARS`` characters and ``MAX_EXITS`` exits, angles in ASCII digits only."""

from __future__ import annotations

import time

import pytest

from guidance.core.co_driver import MAX_EXITS, MAX_LINE_CHARS, SceneParseError, parse_line


def test_a_long_line_or_too_many_exits_is_refused_in_bounded_time() -> None:
    for line in ("lsr" * 33_334, "l " * 4_000_000, "x" * (8 << 20)):
        t0 = time.process_time()
        with pytest.raises(SceneParseError, match="characters"):
            parse_line(line)
        assert time.process_time() - t0 < 0.05  # refused before it is split
    with pytest.raises(SceneParseError, match="exits"):
        parse_line(" ".join(["l"] * (MAX_EXITS + 1)))
    assert len(parse_line(" ".join(["l", "s", "r", "u", "bl", "br", "hl", "hr"])).labels) == 8
    assert parse_line("x" * 0 + "l30 r45") is not None
    assert len("turned left") < MAX_LINE_CHARS


@pytest.mark.parametrize("token", ["l\u0663\u0660", "+\u0664\u0665", "l1_0", "+1e2", "l1234"])
def test_an_angle_is_ascii_digits_only(token: str) -> None:
    with pytest.raises(SceneParseError):
        parse_line(token)
