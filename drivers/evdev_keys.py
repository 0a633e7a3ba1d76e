"""A USB numeric keypad (or any Linux input device) as the co-driver's input.

Under systemd stdin is ``/dev/null``, so the co-driver types on a keypad read straight from the
kernel's input layer: ``/dev/input/by-id/usb-...-event-kbd``, opened with python-evdev and
grabbed (its keys then reach only this process, not a console or a desktop). The reader takes
the raw ``struct input_event`` records from the device file (``llHHi`` on 64-bit Linux:
seconds, microseconds, type, code, value), decodes them (``decode_events``), turns key presses
into lines (``KeyLine``) and hands each line to ``drivers.keyboard.CoDriverLines``, the same
handling the terminal keyboard has. A FIFO or a file of recorded records reads the same way
(tests, replaying a keypad capture).

Key map (``KEY_MAP``; docs/app.md, "Co-driver keys"): keypad digits are exits seen from above,
like ``guidance.core.co_driver.KEYPAD_DIGITS`` (8 straight, 4 left, 6 right, 7/9 bear, 1/3
hard, 2 U-turn); 0 first means "the driver took": ``0 4 Enter`` is "turned left"; Enter ends
the line, Backspace removes the last key, ``.`` clears the line; ``+`` help, ``*`` repeat the
last prompt, ``/`` mute. A full keyboard types letters, digits and spaces as on the terminal.
"""

from __future__ import annotations

import contextlib
import functools
import os
import re
import select
import stat
import struct
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any, ClassVar

from evdev import ecodes

from drivers._reader import ThreadedSource
from drivers.keyboard import CoDriverLines, Feedback, SceneMessage

EVENT = struct.Struct("llHHi")
"""``struct input_event`` (linux/input.h) on 64-bit Linux: 24 bytes."""

KEY_DOWN = 1
"""``value`` of a key press (0 is the release, 2 the auto-repeat: both ignored)."""

ENTER = "\n"
BACKSPACE = "\b"
CLEAR = "clear"

KEY_MAP: dict[int, str] = {
    **{getattr(ecodes, f"KEY_KP{d}"): str(d) for d in range(10)},
    ecodes.KEY_KPENTER: ENTER,
    ecodes.KEY_ENTER: ENTER,
    ecodes.KEY_BACKSPACE: BACKSPACE,
    ecodes.KEY_KPDOT: CLEAR,
    ecodes.KEY_KPPLUS: "?",
    ecodes.KEY_KPASTERISK: "repeat",
    ecodes.KEY_KPSLASH: "mute",
    # a full keyboard: the terminal's line syntax
    **{getattr(ecodes, f"KEY_{d}"): str(d) for d in range(10)},
    **{getattr(ecodes, f"KEY_{c.upper()}"): c for c in "abcdefghijklmnopqrstuvwxyz"},
    ecodes.KEY_SPACE: " ",
    ecodes.KEY_MINUS: "-",
    ecodes.KEY_SLASH: "?",
}
"""Key code -> a character of the line, or an action (ENTER, BACKSPACE, CLEAR) or a command
sent at once ("?", "repeat", "mute")."""

TALK_KEY = ecodes.KEY_KP5
"""Held: the speech input listens (push-to-talk, ``drivers.speech``); unused otherwise."""

IMMEDIATE = frozenset({"?", "repeat", "mute"})
"""Keypad keys that act at once, without Enter."""
_KEYPAD_IMMEDIATE = frozenset({ecodes.KEY_KPPLUS, ecodes.KEY_KPASTERISK, ecodes.KEY_KPSLASH})
_TOOK_RE = re.compile(r"^0(\d+)$")


@dataclass(frozen=True, slots=True)
class InputEvent:
    """One decoded ``struct input_event``."""

    t_s: float
    type: int
    code: int
    value: int


def encode_event(type_: int, code: int, value: int, t_s: float = 0.0) -> bytes:
    """The bytes the kernel writes for one event (tests, captures)."""
    sec = int(t_s)
    return EVENT.pack(sec, round((t_s - sec) * 1e6), type_, code, value)


def key_press_records(codes: list[int], t_s: float = 0.0) -> bytes:
    """What a keyboard sends for pressing and releasing each key in turn: EV_MSC scan, EV_KEY
    down, EV_SYN, EV_KEY up, EV_SYN (the records a USB HID keypad produces)."""
    out = bytearray()
    for k, code in enumerate(codes):
        t = t_s + 0.1 * k
        out += encode_event(ecodes.EV_MSC, ecodes.MSC_SCAN, 0x70000 + code, t)
        out += encode_event(ecodes.EV_KEY, code, KEY_DOWN, t)
        out += encode_event(ecodes.EV_SYN, ecodes.SYN_REPORT, 0, t)
        out += encode_event(ecodes.EV_KEY, code, 0, t + 0.05)
        out += encode_event(ecodes.EV_SYN, ecodes.SYN_REPORT, 0, t + 0.05)
    return bytes(out)


def decode_events(buf: bytes) -> tuple[list[InputEvent], bytes]:
    """Whole records in ``buf`` and the bytes of an incomplete one left over."""
    n = len(buf) // EVENT.size
    events = [
        InputEvent(sec + usec * 1e-6, type_, code, value)
        for sec, usec, type_, code, value in EVENT.iter_unpack(buf[: n * EVENT.size])
    ]
    return events, buf[n * EVENT.size :]


def key_name(code: int) -> str:
    """``KEY_KP4`` for 75; the number for a code evdev does not name."""
    name: Any = ecodes.KEY.get(code, str(code))
    return name[0] if isinstance(name, list) else str(name)


class KeyLine:
    """Key presses -> lines (pure): ``press(code)`` returns (line or None, echo).

    The echo acknowledges every key (what it did and the line so far); the line is what the
    co-driver finished, ready for ``CoDriverLines`` ("0" then digits becomes "t <digits>").
    """

    def __init__(self) -> None:
        self.buffer = ""

    def press(self, code: int) -> tuple[str | None, str]:
        key = KEY_MAP.get(code)
        if key is None:
            return None, f"key {key_name(code)}: not used (+ for help)"
        if code in _KEYPAD_IMMEDIATE or (key in IMMEDIATE and not self.buffer):
            return key, f"key {key_name(code)}: {key}"
        if key == ENTER:
            line, self.buffer = self.buffer, ""
            m = _TOOK_RE.match(line)
            if m:
                line = "t " + m.group(1)
            return line, f"key Enter: {line!r}" if line else "key Enter: empty line"
        if key == BACKSPACE:
            self.buffer = self.buffer[:-1]
        elif key == CLEAR:
            self.buffer = ""
        else:
            self.buffer += key
        return None, f"key {key_name(code)}: {self.buffer}_"


@dataclass(frozen=True, slots=True)
class EvdevKeysConfig:
    """``[scene] input = "evdev"``: the device and how it is read."""

    device: str
    """``/dev/input/by-id/...-event-kbd`` (stable across reboots and ports), or a FIFO/file
    of raw ``input_event`` records."""
    grab: bool = True
    """Take the device exclusively (EVIOCGRAB): its keys reach no console or desktop."""
    stale_after_s: float = 86400.0
    """A keypad is quiet for long stretches: silence is not a fault."""
    reconnect_max_s: float = 5.0


class EvdevKeys(ThreadedSource[SceneMessage]):
    """Co-driver keys from a Linux input device (see the module docstring)."""

    sink_kind: ClassVar[str] = "scene"
    unit: ClassVar[str] = "lines"
    announce_first_connect: ClassVar[bool] = True

    def __init__(
        self,
        config: EvdevKeysConfig,
        heading_fn: Callable[[], float],
        *,
        clock: Callable[[], float] = time.monotonic,
        feedback: Feedback | None = None,
        echo: Feedback | None = None,
        on_command: Callable[[str], str] | None = None,
        name: str = "keypad",
    ) -> None:
        super().__init__(name, config, clock=clock)
        self.config = config
        self._device = config.device
        self.lines = CoDriverLines(
            name, heading_fn, clock=clock, feedback=feedback, echo=echo, on_command=on_command
        )
        self.keys = KeyLine()
        self.on_talk: Callable[[bool], None] | None = None
        """Told when the talk key (``TALK_KEY``) goes down (True) and up (False)."""
        self.device_name = ""
        self.error = ""

    @property
    def connected(self) -> bool:
        return bool(self._connected)

    def describe(self) -> str:
        """What the operator screen shows for this input."""
        what = f"keypad {self.device_name or self.config.device}"
        if self._connected:
            return f"{what}: connected"
        return f"{what}: MISSING ({self.error})" if self.error else f"{what}: opening"

    def _source_stats(self) -> dict[str, int]:
        return self.lines.stats()

    # reading ------------------------------------------------------------------------------------
    def _run(self, sink: Callable[[SceneMessage], None]) -> None:
        delay = 0.25
        while not self._stop.is_set():
            try:
                fd, device = self._open()
            except OSError as exc:
                self.error = exc.strerror or str(exc)
                self._set_connected(False, self.error)
                self._stop.wait(delay)
                delay = self._backoff(delay)
                continue
            self.error = ""
            self._set_connected(True)
            delay = 0.25
            try:
                for event in self._events(fd):
                    self.on_event(event, sink)
                if not self._stop.is_set():  # end of a file or FIFO: nothing more will come
                    self._log.info("%s: end of input on %s", self.name, self.config.device)
                    self._health.ended()
                    return
            except OSError as exc:  # unplugged: ENODEV
                self.error = exc.strerror or str(exc)
                self._set_connected(False, self.error)
            finally:
                _close(fd, device)

    def _open(self) -> tuple[int, Any]:
        """A non-blocking fd on the device; an evdev ``InputDevice`` for a real one."""
        path = self.config.device
        if stat.S_ISCHR(os.stat(path).st_mode):
            from evdev import InputDevice

            device = InputDevice(path)
            self.device_name = device.name
            if self.config.grab:
                device.grab()
            return device.fd, device
        return os.open(path, os.O_RDONLY | os.O_NONBLOCK), None

    def _events(self, fd: int) -> Iterator[InputEvent]:
        """Decoded records until the end of input or ``stop()``."""
        rest = b""
        while not self._stop.is_set():
            ready, _, _ = select.select([fd], [], [], 0.2)
            if not ready:
                continue
            chunk = os.read(fd, 64 * EVENT.size)
            if not chunk:
                return
            events, rest = decode_events(rest + chunk)
            yield from events

    def _deliver_scene(self, sink: Callable[[SceneMessage], None], msg: SceneMessage) -> None:
        self._deliver(sink, msg)

    def on_event(self, event: InputEvent, sink: Callable[[SceneMessage], None]) -> None:
        """One decoded record: a key press is echoed and may finish a line; the talk key's
        press and release go to ``on_talk``."""
        talk = self.on_talk
        if event.type == ecodes.EV_KEY and event.code == TALK_KEY and talk is not None:
            if event.value in (0, KEY_DOWN):
                talk(event.value == KEY_DOWN)
                self.lines.echo("key 5: talk" if event.value else "key 5 up: heard")
            return
        if event.type != ecodes.EV_KEY or event.value != KEY_DOWN:
            return
        self._count("keys")
        line, echo = self.keys.press(event.code)
        self.lines.echo(echo)
        if line:
            self._health.data(True)
            try:
                self.lines.handle(line, functools.partial(self._deliver_scene, sink))
            except Exception:  # pragma: no cover - feedback or a command handler failed
                self._log.exception("%s: handling %r failed; continuing", self.name, line)


def _close(fd: int, device: Any) -> None:
    if device is not None:
        with contextlib.suppress(OSError):  # already gone
            device.close()  # releases the grab too
    else:
        os.close(fd)
