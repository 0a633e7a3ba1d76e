"""``[scene]``'s speech settings (issue 39): when the microphone listens, and what is refused."""

from __future__ import annotations

import pytest

from guidance.app.settings import read_scene
from guidance.errors import UserError


def test_talk_is_push_to_talk_with_a_keypad_and_always_without() -> None:
    alone = read_scene({"input": "speech"}, None)
    assert alone.listens and alone.talk_mode == "wake"
    beside = read_scene({"input": "evdev", "device": "/dev/input/kp", "speech": True}, None)
    assert beside.listens and beside.talk_mode == "key" and beside.microphone == "default"
    typed = read_scene({"input": "keyboard", "speech": True}, None)
    assert typed.talk_mode == "wake"
    assert read_scene({"input": "speech", "talk": "always"}, None).talk_mode == "always"
    assert not read_scene({}, None).listens


def test_push_to_talk_without_a_keypad_is_refused_with_the_way_out() -> None:
    with pytest.raises(UserError, match=r"needs input = 'evdev'.*talk = 'wake'"):
        read_scene({"input": "keyboard", "speech": True, "talk": "key"}, None)
    with pytest.raises(UserError, match="talk"):
        read_scene({"input": "speech", "talk": "sometimes"}, None)
