"""The terminal keyboard with the live operator screen: a real pseudo-terminal read key by key
(cbreak mode), every key acknowledged, the line handled on Enter, help at once on "?", and
the terminal's mode restored when the source stops."""

from __future__ import annotations

import math
import os
import termios
import time
from collections.abc import Callable

import pytest

from drivers.keyboard import HELP_LINES, KeyboardScene
from guidance.core.messages import IntersectionScene


def _wait(predicate: Callable[[], bool], timeout_s: float = 120.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.01)
    return True


def test_terminal_keys_are_acknowledged_one_by_one() -> None:
    master, slave = os.openpty()
    before = termios.tcgetattr(slave)
    stream = os.fdopen(slave, "r")
    echoes: list[str] = []
    feedback: list[str] = []
    got: list[object] = []
    scene = KeyboardScene(lambda: 0.0, stream=stream, feedback=feedback.append,
                          echo=echoes.append)  # fmt: skip
    scene.start(got.append)
    try:
        assert _wait(lambda: not termios.tcgetattr(slave)[3] & termios.ICANON)  # cbreak
        os.write(master, b"l\x7fs r\r")
        assert _wait(lambda: len(got) == 1)
        os.write(master, b"?")
        assert _wait(lambda: len(feedback) >= 1 + len(HELP_LINES))
    finally:
        scene.stop()
        after = termios.tcgetattr(slave)
        stream.close()
        os.close(master)
    assert echoes == [
        "typing: l_",
        "typing: _",
        "typing: s_",
        "typing: s _",
        "typing: s r_",
        "key Enter: 's r'",
        "typing: ?_",
    ]
    assert isinstance(got[0], IntersectionScene)
    assert got[0].exit_headings_rad == pytest.approx((0.0, -math.pi / 2))
    assert feedback[0] == "ok: exits straight, right"
    assert feedback[1:] == list(HELP_LINES)
    assert after == before  # the terminal is given back as it was


def test_an_8_mb_line_is_read_in_pieces_and_the_next_line_still_counts() -> None:
    """Issue 40, low: an 8 MB co-driver line cost the car 120 MB; now at most
    ``MAX_LINE_CHARS + 1`` characters of it are held, the rest dropped unread in pieces."""
    import io

    from drivers.keyboard import _bounded_line
    from guidance.core.co_driver import MAX_LINE_CHARS

    stream = io.StringIO("l" * (8 << 20) + "\nl s r\n")
    first = _bounded_line(stream)
    assert len(first) == MAX_LINE_CHARS + 1
    assert _bounded_line(stream) == "l s r\n"
    assert _bounded_line(stream) == ""
