"""The co-driver keyboard as a roadway-scene source, and the line handling every co-driver input
shares (the terminal keyboard here, a USB keypad in ``drivers.evdev_keys``).

``CoDriverLines`` turns one typed line into what happens next: an ``IntersectionScene`` or a
``TurnCompleted`` for the sink (parsed by ``guidance.core.co_driver``), a ``CancelReport`` for
the sink ("cancel": the last report taken back), a command (help, repeat the last prompt, mute),
or an answer to a line that does not parse. Every line gets an
acknowledgement on ``feedback`` (the operator screen, or stderr), so the co-driver knows it was
taken. ``KeyboardScene`` reads the lines from stdin (or any text stream) on its own thread.
"""

from __future__ import annotations

import contextlib
import logging
import os
import select
import sys
import termios
import threading
import time
import tty
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from typing import TextIO

from drivers._reader import ThreadedSource
from guidance.core.co_driver import (
    MAX_LINE_CHARS,
    ExitsTyped,
    SceneParseError,
    parse_line,
    to_scene,
)
from guidance.core.messages import CancelReport, IntersectionScene, TurnCompleted

log = logging.getLogger(__name__)

SceneMessage = IntersectionScene | TurnCompleted | CancelReport
Feedback = Callable[[str], None]
"""Where acknowledgements, answers and help go: one line of text each."""

COMMANDS: dict[str, str] = {
    "?": "help",
    "help": "help",
    "repeat": "repeat",
    "again": "repeat",
    "*": "repeat",
    "mute": "mute",
    "/": "mute",
    "cancel": "cancel",
}
"""Lines that are commands, not scene reports (the keypad sends ``*`` and ``/``)."""

HELP_LINES: tuple[str, ...] = (
    "exits ahead: l s r (left straight right), bl br (bear), hl hr (hard), u (U-turn),"
    " l30 r60 or +30 -120 (degrees, left positive); keypad 8 4 6 7 9 1 3 2",
    "turn taken: tl, turned left, t 4 (keypad: 0 then the exit key, e.g. 0 4)",
    "commands: ? or help (this help), repeat (keypad *), mute (keypad /), cancel (the last"
    " report, while the car has not reached it)",
    "report each intersection once, as soon as you see it (right after the previous one is"
    " fine), as seen from the street the car will be on; the next report tells the car the"
    " previous one is behind; turns are seen by the car, a turn report only settles it sooner",
)

_LABEL_WORDS = {
    "s": "straight",
    "f": "straight",
    "straight": "straight",
    "ahead": "straight",
    "l": "left",
    "left": "left",
    "r": "right",
    "right": "right",
    "bl": "bear left",
    "br": "bear right",
    "hl": "hard left",
    "hr": "hard right",
    "u": "U-turn",
    "uturn": "U-turn",
}


def label_words(label: str) -> str:
    """A parser label as words: "bl" -> "bear left", "l30" -> "30 deg left", "+30" -> "+30 deg"."""
    if label in _LABEL_WORDS:
        return _LABEL_WORDS[label]
    if label[:1] in ("l", "r") and label[1:].replace(".", "", 1).isdigit():
        return f"{label[1:]} deg {'left' if label[0] == 'l' else 'right'}"
    return f"{label} deg"


class CoDriverLines:
    """One co-driver line -> a scene message, a command or an answer, and an acknowledgement.

    ``heading_fn`` gives the estimated heading (rad) that turns relative exits into absolute
    ones, ``clock`` stamps the message. ``on_command`` receives "repeat" and "mute" and returns
    what to acknowledge ("voice muted"); None: the co-driver is told the command is not
    available. Counters: lines, rejected,
    intersections, turns, commands.
    """

    def __init__(
        self,
        name: str,
        heading_fn: Callable[[], float],
        *,
        clock: Callable[[], float] = time.monotonic,
        feedback: Feedback | None = None,
        echo: Feedback | None = None,
        on_command: Callable[[str], str] | None = None,
    ) -> None:
        self.name = name
        self._heading_fn = heading_fn
        self._clock = clock
        self.feedback: Feedback = feedback if feedback is not None else _stderr_feedback
        self.echo: Feedback = echo if echo is not None else self.feedback
        """Where each key's acknowledgement goes (the screen's typing line)."""
        self.on_command = on_command
        self._counts: Counter[str] = Counter()
        self._lock = threading.Lock()

    def stats(self) -> dict[str, int]:
        with self._lock:
            return dict(self._counts)

    def _count(self, key: str) -> None:
        with self._lock:
            self._counts[key] += 1

    def handle(self, line: str, sink: Callable[[SceneMessage], None]) -> SceneMessage | None:
        """Act on one line; returns the message delivered to ``sink``, if any."""
        t_s = self._clock()
        text = line.strip().lower()
        if not text:
            return None
        self._count("lines")
        command = COMMANDS.get(text)
        if command == "cancel":  # for the pipeline, like a report: it answers in words
            self._count("cancels")
            cancel = CancelReport(t_s, source="co-driver")
            sink(cancel)
            self.feedback("ok: cancel the last report")
            return cancel
        if command is not None:
            self._count("commands")
            self._command(command)
            return None
        try:
            typed = parse_line(text)
        except SceneParseError as exc:
            self._count("rejected")
            log.info("%s: %s", self.name, exc)
            self.feedback(f"? {exc} (? for help)")
            return None
        if typed is None:  # pragma: no cover - empty lines returned above
            return None
        msg = to_scene(typed, t_s, self._heading_fn())
        self._count("intersections" if isinstance(msg, IntersectionScene) else "turns")
        sink(msg)
        if isinstance(typed, ExitsTyped):
            self.feedback("ok: exits " + ", ".join(label_words(lab) for lab in typed.labels))
        else:
            self.feedback(f"ok: turned {label_words(typed.label)}")
        return msg

    def _command(self, command: str) -> None:
        if command == "help":
            for text in HELP_LINES:
                self.feedback(text)
            return
        if self.on_command is None:
            self.feedback(f"ok: {command} (not available in this run)")
            return
        self.feedback(f"ok: {self.on_command(command)}")


def _stderr_feedback(text: str) -> None:
    sys.stderr.write(text + "\n")
    sys.stderr.flush()


def _stream_feedback(stream: TextIO) -> Feedback:
    def write(text: str) -> None:
        stream.write(text + "\n")
        stream.flush()

    return write


# --------------------------------------------------------------------------- the source


@dataclass(frozen=True, slots=True)
class KeyboardTiming:
    """The reader base's timing for a keyboard: silence is the co-driver's, not a fault."""

    stale_after_s: float = 86400.0
    reconnect_max_s: float = 5.0


class KeyboardScene(ThreadedSource[SceneMessage]):
    """``RoadwayScene`` from co-driver lines on a text stream (stdin by default).

    A reader thread (``drivers._reader.ThreadedSource``: blocking I/O stays off the event loop,
    a failing sink is counted and logged once) reads lines and hands each to ``CoDriverLines``,
    which calls ``sink`` with an ``IntersectionScene`` or ``TurnCompleted``. ``heading_fn``
    gives the current estimated heading (rad); ``clock`` stamps the line (the message clock).
    ``feedback`` (a text stream or a callable; default stderr) gets the acknowledgement of
    every line, the answer to a bad one and the help. The end of the input is the status
    "ended" (the co-driver's keyboard is gone).

    With ``echo`` (the live operator screen) and a terminal, the terminal is read key by key
    (cbreak mode, no terminal echo: the screen owns the terminal) and every key is
    acknowledged on ``echo`` with the line so far; the terminal's mode is restored on stop.
    """

    sink_kind = "scene"
    unit = "lines"
    may_outlive_stop = True  # readline on a terminal cannot be woken

    def __init__(
        self,
        heading_fn: Callable[[], float],
        *,
        stream: TextIO | None = None,
        feedback: TextIO | Feedback | None = None,
        echo: Feedback | None = None,
        on_command: Callable[[str], str] | None = None,
        clock: Callable[[], float] = time.monotonic,
        name: str = "keyboard",
    ) -> None:
        super().__init__(name, KeyboardTiming(), clock=clock)
        self._stream = stream
        write = feedback if feedback is None or callable(feedback) else _stream_feedback(feedback)
        self.lines = CoDriverLines(
            name, heading_fn, clock=clock, feedback=write, echo=echo, on_command=on_command
        )
        self._per_key = echo is not None
        # A thread blocked in readline on a terminal cannot be woken: it is a daemon and
        # delivers nothing after stop(). Key by key, the reader wakes within 0.2 s.
        self.join_timeout_s = 1.0 if self._per_key else 0.2

    def _source_stats(self) -> dict[str, int]:
        return self.lines.stats()

    def describe(self) -> str:
        """What the operator screen shows for this input."""
        return "keyboard (stdin)" if self._stream is None else f"keyboard ({self.name})"

    def handle_line(self, line: str, sink: Callable[[SceneMessage], None]) -> SceneMessage | None:
        """Act on one line; returns what was delivered (for tests and replay)."""
        return self.lines.handle(line, sink)

    def _run(self, sink: Callable[[SceneMessage], None]) -> None:
        def deliver(msg: SceneMessage) -> None:  # a failing sink: counted, logged once
            self._deliver(sink, msg)

        stream = self._stream if self._stream is not None else sys.stdin
        if self._per_key and _is_tty(stream):
            self._run_keys(stream.fileno(), deliver)
            return
        while not self._stop.is_set():
            try:
                line = _bounded_line(stream)
            except (OSError, ValueError) as exc:  # closed stream
                log.warning("%s: input closed (%s)", self.name, exc)
                self._health.ended()
                return
            if not line:  # end of input: the co-driver's keyboard is gone
                log.info("%s: end of input", self.name)
                self._health.ended()
                return
            if self._stop.is_set():
                return
            self.handle_line(line, deliver)

    def _run_keys(self, fd: int, sink: Callable[[SceneMessage], None]) -> None:
        """Key by key from a terminal in cbreak mode; Ctrl-C still interrupts."""
        saved = termios.tcgetattr(fd)
        try:
            tty.setcbreak(fd)
            buffer = ""
            while not self._stop.is_set():
                if not select.select([fd], [], [], 0.2)[0]:
                    continue
                data = os.read(fd, 256).decode("utf-8", "replace")
                if not data:
                    return
                for ch in data:
                    buffer = self._key(ch, buffer, sink)
        except (OSError, termios.error) as exc:
            log.warning("%s: terminal input closed (%s)", self.name, exc)
        finally:
            with contextlib.suppress(OSError, termios.error):
                termios.tcsetattr(fd, termios.TCSADRAIN, saved)

    def _key(self, ch: str, buffer: str, sink: Callable[[SceneMessage], None]) -> str:
        """One typed character: acknowledged on echo; Enter hands the line on."""
        if ch in "\r\n":
            self.lines.echo(f"key Enter: {buffer!r}" if buffer else "key Enter: empty line")
            self.handle_line(buffer, sink)
            return ""
        if ch in "\x7f\b":
            buffer = buffer[:-1]
        elif ch == "\x15":  # Ctrl-U: clear the line
            buffer = ""
        elif ch.isprintable():
            if len(buffer) >= MAX_LINE_CHARS:  # the parser refuses it anyway: stop growing
                self.lines.echo(f"key {ch!r}: the line is full ({MAX_LINE_CHARS} characters)")
                return buffer
            buffer += ch
        else:
            self.lines.echo(f"key {ch.encode('unicode_escape').decode()}: not used (? for help)")
            return buffer
        self.lines.echo(f"typing: {buffer}_")
        if buffer == "?":  # help at once, as on the keypad
            self.handle_line(buffer, sink)
            return ""
        return buffer


def _bounded_line(stream: TextIO) -> str:
    """One line of at most ``MAX_LINE_CHARS + 1`` characters (the parser refuses it then); the
    rest of a longer line is read and dropped a piece at a time, never held whole."""
    line = stream.readline(MAX_LINE_CHARS + 1)
    if len(line) > MAX_LINE_CHARS and not line.endswith("\n"):
        while (rest := stream.readline(4096)) and not rest.endswith("\n"):
            pass
    return line


def _is_tty(stream: TextIO) -> bool:
    try:
        return os.isatty(stream.fileno())
    except (OSError, ValueError, AttributeError):
        return False
