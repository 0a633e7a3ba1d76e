"""The co-driver keypad (``drivers.evdev_keys``): the key map, the raw ``input_event`` records a
USB keypad produces read from a FIFO through the driver's own reading and decoding, a device
that is missing and then appears, and a real uinput keypad where the kernel offers one."""

from __future__ import annotations

import math
import os
import struct
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from evdev import ecodes

from drivers.evdev_keys import (
    EVENT,
    EvdevKeys,
    EvdevKeysConfig,
    KeyLine,
    decode_events,
    encode_event,
    key_press_records,
)
from drivers.keyboard import HELP_LINES
from guidance.core.messages import IntersectionScene, TurnCompleted

KP = {str(d): getattr(ecodes, f"KEY_KP{d}") for d in range(10)}
ENTER = ecodes.KEY_KPENTER


def keys(text: str) -> list[int]:
    """Keypad codes for digits; '\\n' is the keypad Enter."""
    return [ENTER if c == "\n" else KP[c] for c in text]


# ----------------------------------------------------------------------------- decoding


def test_input_event_is_the_kernel_layout_on_64_bit_linux() -> None:
    """struct input_event { struct timeval time; __u16 type; __u16 code; __s32 value; }."""
    assert EVENT.size == 24 == struct.calcsize("qqHHi")
    raw = struct.pack("qqHHi", 1700000000, 250000, ecodes.EV_KEY, ecodes.KEY_KP4, 1)
    assert encode_event(ecodes.EV_KEY, ecodes.KEY_KP4, 1, 1700000000.25) == raw
    events, rest = decode_events(raw + raw[:10])
    assert rest == raw[:10]  # half a record waits for the rest
    assert [(e.type, e.code, e.value) for e in events] == [(1, ecodes.KEY_KP4, 1)]
    assert events[0].t_s == pytest.approx(1700000000.25)


def test_key_map_digits_enter_took_backspace_clear_and_commands() -> None:
    line = KeyLine()
    echoes = []
    for code in keys("846"):
        got, echo = line.press(code)
        assert got is None
        echoes.append(echo)
    assert echoes == ["key KEY_KP8: 8_", "key KEY_KP4: 84_", "key KEY_KP6: 846_"]
    assert line.press(ENTER) == ("846", "key Enter: '846'")
    for code in keys("04"):  # 0 first: the exit the driver took
        line.press(code)
    assert line.press(ENTER)[0] == "t 4"
    line.press(KP["9"])
    line.press(ecodes.KEY_BACKSPACE)
    line.press(KP["8"])
    assert line.press(ENTER)[0] == "8"
    line.press(KP["7"])
    assert line.press(ecodes.KEY_KPDOT) == (None, "key KEY_KPDOT: _")
    assert line.press(ENTER) == ("", "key Enter: empty line")
    assert line.press(ecodes.KEY_KPPLUS)[0] == "?"
    assert line.press(ecodes.KEY_KPASTERISK)[0] == "repeat"
    assert line.press(ecodes.KEY_KPSLASH)[0] == "mute"
    got, echo = line.press(ecodes.KEY_F1)  # every key is answered, even an unused one
    assert got is None and "not used" in echo
    for code in (ecodes.KEY_T, ecodes.KEY_L, ecodes.KEY_ENTER):  # a full keyboard types text
        got, _ = line.press(code)
    assert got == "tl"


# ----------------------------------------------------------------------------- the reader


@pytest.fixture
def fifo(tmp_path: Path) -> Iterator[tuple[Path, int]]:
    """A FIFO standing in for /dev/input/eventN, held open for writing by the test."""
    path = tmp_path / "keypad"
    os.mkfifo(path)
    fd = os.open(path, os.O_RDWR)  # a writer that never blocks and never gives end-of-file
    yield path, fd
    os.close(fd)


class Collect:
    def __init__(self) -> None:
        self.got: list[object] = []
        self.feedback: list[str] = []
        self.changed = threading.Condition()

    def sink(self, msg: object) -> None:
        with self.changed:
            self.got.append(msg)
            self.changed.notify_all()

    def say(self, text: str) -> None:
        with self.changed:
            self.feedback.append(text)
            self.changed.notify_all()

    def wait(self, predicate: Callable[[], bool], timeout_s: float = 120.0) -> bool:
        """Poll: some conditions (connected) change without a notification. The bound only
        ends a test that would hang: it returns as soon as the condition holds (a loaded
        machine may take seconds; tests are not timed)."""
        deadline = time.monotonic() + timeout_s
        while not predicate():
            if time.monotonic() > deadline:
                return False
            with self.changed:
                self.changed.wait(0.01)
        return True


def test_keypad_records_from_a_fifo_reach_the_sink_with_acknowledgements(
    fifo: tuple[Path, int],
) -> None:
    path, fd = fifo
    c = Collect()
    commands: list[str] = []

    def on_command(cmd: str) -> str:
        commands.append(cmd)
        return f"did {cmd}"

    src = EvdevKeys(EvdevKeysConfig(str(path)), lambda: 0.0, feedback=c.say, echo=c.say,
                    on_command=on_command, clock=lambda: 7.0)  # fmt: skip
    src.start(c.sink)
    try:
        assert c.wait(lambda: src.connected)
        records = (
            key_press_records(keys("486\n"))
            + key_press_records(keys("04\n"))
            + key_press_records([ecodes.KEY_KPPLUS, ecodes.KEY_KPASTERISK, ecodes.KEY_KP5, ENTER])
        )
        for k in range(0, len(records), 37):  # chunks that split records
            os.write(fd, records[k : k + 37])
        assert c.wait(
            lambda: len(c.got) == 2 and len(commands) == 1 and c.feedback[-1].startswith("?")
        )
    finally:
        src.stop()
    scene, turn = c.got
    assert isinstance(scene, IntersectionScene) and scene.t_s == 7.0
    assert scene.exit_headings_rad == pytest.approx((math.pi / 2, 0.0, -math.pi / 2))
    assert scene.labels == ("l", "s", "r")
    assert isinstance(turn, TurnCompleted) and turn.source == "co-driver"
    assert turn.heading_change_rad == pytest.approx(math.pi / 2)
    fb = c.feedback
    assert fb[:4] == [
        "key KEY_KP4: 4_",
        "key KEY_KP8: 48_",
        "key KEY_KP6: 486_",
        "key Enter: '486'",
    ]
    assert "ok: exits left, straight, right" in fb
    assert "key Enter: 't 4'" in fb and "ok: turned left" in fb
    assert all(h in fb for h in HELP_LINES)  # + shows the help
    assert commands == ["repeat"] and "ok: did repeat" in fb
    assert fb[-2:] == ["key Enter: '5'", fb[-1]] and "unknown exit '5'" in fb[-1]
    assert src.stats()["keys"] == 11
    assert src.stats()["intersections"] == 1 and src.stats()["turns"] == 1
    assert src.stats()["rejected"] == 1


def test_a_missing_device_is_reported_and_read_once_it_appears(tmp_path: Path) -> None:
    path = tmp_path / "by-id-keypad"
    c = Collect()
    src = EvdevKeys(EvdevKeysConfig(str(path), reconnect_max_s=0.2), lambda: 0.0, feedback=c.say)
    src.start(c.sink)
    try:
        deadline = time.monotonic() + 5.0
        while "MISSING" not in src.describe() and time.monotonic() < deadline:
            time.sleep(0.02)
        assert "MISSING (No such file or directory)" in src.describe()
        assert not src.connected and src.health().status == "disconnected"
        os.mkfifo(path)  # plugged in
        fd = os.open(path, os.O_RDWR)
        try:
            assert c.wait(lambda: src.connected)
            assert src.describe().endswith(": connected")
            os.write(fd, key_press_records(keys("8\n")))
            assert c.wait(lambda: len(c.got) == 1)
        finally:
            os.close(fd)
    finally:
        src.stop()
    assert isinstance(c.got[0], IntersectionScene)


def test_end_of_a_recorded_capture_ends_the_source(tmp_path: Path) -> None:
    """A file of records (a keypad capture) is read to its end once, not re-read."""
    path = tmp_path / "capture.bin"
    path.write_bytes(key_press_records(keys("46\n8\n")))
    c = Collect()
    src = EvdevKeys(EvdevKeysConfig(str(path)), lambda: 0.0, feedback=c.say)
    src.start(c.sink)
    try:
        assert c.wait(lambda: src.health().status == "ended")
    finally:
        src.stop()
    assert [len(m.exit_headings_rad) for m in c.got] == [2, 1]  # type: ignore[attr-defined]


# ----------------------------------------------------------------------------- a real device


@pytest.mark.skipif(
    not os.path.exists("/dev/uinput"),
    reason="/dev/uinput does not exist here (no uinput module, or a container without it): "
    "the real-device path is covered by the FIFO tests' decoding only",
)
def test_a_uinput_keypad_through_the_kernel() -> None:  # pragma: no cover - needs /dev/uinput
    from evdev import UInput

    codes = [*KP.values(), ENTER, ecodes.KEY_KPPLUS, ecodes.KEY_KPASTERISK, ecodes.KEY_KPSLASH]
    try:
        ui = UInput({ecodes.EV_KEY: codes}, name="guidance-test-keypad")
    except OSError as exc:
        pytest.skip(f"cannot create a uinput device: {exc}")
    with ui:
        c = Collect()
        assert ui.device is not None
        src = EvdevKeys(EvdevKeysConfig(str(ui.device.path)), lambda: 0.0, feedback=c.say)
        src.start(c.sink)
        try:
            assert c.wait(lambda: src.connected)
            time.sleep(0.2)  # the device node settles
            for code in keys("46\n"):
                ui.write(ecodes.EV_KEY, code, 1)
                ui.syn()
                ui.write(ecodes.EV_KEY, code, 0)
                ui.syn()
            assert c.wait(lambda: len(c.got) == 1)
        finally:
            src.stop()
        assert "guidance-test-keypad" in src.describe()
        assert isinstance(c.got[0], IntersectionScene)
