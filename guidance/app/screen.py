"""The operator screen of ``guidance run`` and the co-driver's commands (docs/app.md, "Operator
screen").

``OperatorScreen`` draws an ``OperatorView`` (guidance/app/operator_view.py, the pure fold) on
its own thread, so drawing never runs on the event loop: on a terminal a rich live view
redrawn 4 times a second; otherwise (the systemd journal, a pipe) plain lines, one per event
(prompt, key, health flip, exit taken) and a status line every 30 s.

``Operator`` is the glue ``guidance run`` hangs on ``App.listeners``: it folds each input and
its outputs into the view, refreshes the inputs' health and the target twice a second, speaks
a different exit taken, and carries out the co-driver's commands (repeat the last instruction,
mute) through ``MutableSpeaker``. ``banner_rows`` is the start-up banner.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import sys
import termios
import threading
import time
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, TextIO

from guidance.app.operator_view import OperatorView, clock_text
from guidance.core import speech
from guidance.core.messages import Priority, Say, Speech

if TYPE_CHECKING:
    from guidance.app.config import AppConfig
    from guidance.app.ports import Speaker
    from guidance.core.pipeline import Pipeline

log = logging.getLogger(__name__)

STYLES = {"ok": "green", "warn": "bold yellow", "bad": "bold red", "": ""}
REFRESH_HZ = 4.0
STATUS_PERIOD_S = 30.0
LIVE_PERIOD_S = 0.5
"""How often ``Operator`` reads health and target from the pipeline (wall clock)."""


def _printable(text: str) -> str:
    """Text from outside (typed lines, device names) without terminal control characters."""
    return "".join(c if c.isprintable() else "?" for c in text)


class OperatorScreen:
    """Draws an ``OperatorView`` on ``stream`` from a thread of its own (see the module).

    ``live``: a rich live view (default: when ``stream`` is a terminal), else plain lines.
    The view is changed only under ``lock`` (``fold``); drawing reads it under the same lock.
    """

    def __init__(
        self,
        view: OperatorView,
        *,
        stream: TextIO | None = None,
        live: bool | None = None,
        wall: Callable[[], float] = time.time,
        refresh_hz: float = REFRESH_HZ,
        status_period_s: float = STATUS_PERIOD_S,
    ) -> None:
        self.view = view
        self.stream = stream if stream is not None else sys.stdout
        self.live = self.stream.isatty() if live is None else live
        self.wall = wall
        self.lock = threading.RLock()
        self._period_s = 1.0 / refresh_hz
        self._status_period_s = status_period_s
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._printed_seq = 0
        self._next_status = 0.0
        self._live: Any = None
        self._log_handler: logging.Handler | None = None
        self._moved_handlers: list[logging.Handler] = []
        self.keys: TextIO | None = sys.stdin
        """The terminal the co-driver types on: it does not echo while the live view is on."""
        self._echo_restore: tuple[int, list[Any]] | None = None

    # -- changing the view (any thread) ----------------------------------------------------------
    def fold(self, fn: Callable[[OperatorView], object]) -> None:
        with self.lock:
            fn(self.view)

    def ack(self, text: str) -> None:
        """The co-driver input's feedback (its reader thread)."""
        now = self.wall()
        self.fold(lambda v: v.ack(_printable(text), now))

    def echo(self, text: str) -> None:
        """One key acknowledged (the co-driver input's reader thread): the TYPING line."""
        now = self.wall()
        self.fold(lambda v: v.add(now, "typing", _printable(text)))

    def print_banner(self, rows: Sequence[tuple[str, str]]) -> None:
        """The start-up banner, before the live view starts."""
        width = max(len(label) for label, _ in rows)
        lines = [f"{label:<{width}}  {_printable(value)}" for label, value in rows]
        if self.live:
            from rich.console import Console
            from rich.panel import Panel
            from rich.text import Text

            Console(file=self.stream).print(
                Panel(Text("\n".join(lines)), title="guidance run", expand=False)
            )
        else:
            for line in lines:
                self.stream.write(f"guidance: {line}\n")
            self.stream.flush()

    # -- drawing ----------------------------------------------------------------------------------
    def start(self) -> None:
        if self.live:
            from rich.console import Console
            from rich.live import Live

            console = Console(file=self.stream)
            self._live = Live(
                console=console, auto_refresh=False, redirect_stdout=False, redirect_stderr=False
            )
            self._live.start()
            self._route_logging()
            self._echo_off()
        self._thread = threading.Thread(target=self._run, name="operator-screen", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        self._next_status = 0.0  # a last status line for the journal
        self.draw()  # the last state stays on the screen / in the journal
        if self._live is not None:
            self._live.stop()
            self._live = None
        self._restore_logging()
        self._echo_on()

    def _echo_off(self) -> None:
        """While the live view owns the terminal, typed keys are not echoed: an echoed line
        (a key typed before the co-driver input reads key by key, or with no input reading
        the terminal at all) moves the cursor under the view, and each redraw then left a
        stale copy of the panel's header above it."""
        try:
            fd = self.keys.fileno() if self.keys is not None else -1
            if fd < 0 or not os.isatty(fd):
                return
            saved = termios.tcgetattr(fd)
            quiet = termios.tcgetattr(fd)
            quiet[3] &= ~(termios.ECHO | termios.ECHONL)
            termios.tcsetattr(fd, termios.TCSANOW, quiet)
        except (OSError, ValueError, termios.error):
            return
        self._echo_restore = (fd, saved)

    def _echo_on(self) -> None:
        if self._echo_restore is not None:
            fd, saved = self._echo_restore
            self._echo_restore = None
            with contextlib.suppress(OSError, termios.error):
                termios.tcsetattr(fd, termios.TCSADRAIN, saved)

    def _route_logging(self) -> None:
        """While the live view owns the terminal, log lines that would be written to that
        terminal are shown on the screen (LOG rows) instead of scrolling through it."""
        root = logging.getLogger()
        self._moved_handlers = [
            h
            for h in root.handlers
            if isinstance(h, logging.StreamHandler)
            and callable(getattr(h.stream, "isatty", None))
            and h.stream.isatty()
        ]
        for h in self._moved_handlers:
            root.removeHandler(h)
        self._log_handler = _ScreenLogHandler(self)
        root.addHandler(self._log_handler)

    def _restore_logging(self) -> None:
        root = logging.getLogger()
        if self._log_handler is not None:
            root.removeHandler(self._log_handler)
            self._log_handler = None
        for h in self._moved_handlers:
            root.addHandler(h)
        self._moved_handlers = []

    def _run(self) -> None:
        while not self._stop.wait(self._period_s):
            try:
                self.draw()
            except Exception:  # the screen must never take the car down
                log.exception("operator screen: drawing failed; continuing")

    def draw(self) -> None:
        if self._live is not None:
            with self.lock:
                rows = self.view.rows()
                title = self._title()
            self._live.update(render_rows(rows, title), refresh=True)
        else:
            self._print_plain()

    def _title(self) -> str:
        vehicle = f"vehicle {self.view.vehicle_id}  " if self.view.vehicle_id else ""
        return f"guidance  {vehicle}{clock_text(self.wall())}"

    def _print_plain(self) -> None:
        now = self.wall()
        with self.lock:
            new = [e for e in self.view.events if e.seq > self._printed_seq]
            status = self.view.status_line() if now >= self._next_status else None
        lines = [f"{clock_text(e.wall_s)} {e.kind}: {e.text}" for e in new]
        if new:
            self._printed_seq = new[-1].seq
        if status is not None:
            self._next_status = now + self._status_period_s
            lines.append(f"{clock_text(now)} status: {status}")
        if lines:
            self.stream.write("".join(f"guidance: {line}\n" for line in lines))
            self.stream.flush()


class ScreenTextStream:
    """A stream for the text speaker while the live view owns the terminal: each line it
    writes (``[prompt 1041.73 s SAFETY] ...``) becomes a SAID row, its monotonic time and
    priority tag dropped (the row has the wall-clock time), instead of being printed over
    the live view."""

    def __init__(self, screen: OperatorScreen) -> None:
        self.screen = screen

    def write(self, text: str) -> int:
        for line in text.splitlines():
            said = line.split("] ", 1)[1] if line.startswith("[prompt ") and "] " in line else line
            if said.strip():
                self._add(_printable(said), "bad" if " SAFETY]" in line else "")
        return len(text)

    def _add(self, said: str, style: str) -> None:
        now = self.screen.wall()
        self.screen.fold(lambda v: v.add(now, "voice", said, style))

    def flush(self) -> None:
        pass

    def isatty(self) -> bool:
        return False


class _ScreenLogHandler(logging.Handler):
    def __init__(self, screen: OperatorScreen) -> None:
        super().__init__(logging.WARNING)
        self.screen = screen

    def emit(self, record: logging.LogRecord) -> None:
        try:
            text = _printable(f"{record.name}: {record.getMessage()}")
        except Exception:  # pragma: no cover - a bad format string
            text = str(record.msg)
        now = self.screen.wall()
        self.screen.fold(lambda v: v.add(now, "log", text, "warn"))


def render_rows(rows: Sequence[tuple[str, str, str]], title: str) -> Any:
    """The rich renderable of the screen: a labelled grid in a panel."""
    from rich.panel import Panel
    from rich.table import Table
    from rich.text import Text

    grid = Table.grid(padding=(0, 1))
    grid.add_column(style="bold", no_wrap=True)
    grid.add_column(overflow="fold")
    previous = ""
    for label, text, style in rows:
        grid.add_row("" if label == previous else label, Text(text, style=STYLES.get(style, "")))
        previous = label
    return Panel(grid, title=title, title_align="left")


# -- the glue guidance run uses -------------------------------------------------------------------
class MutableSpeaker:
    """A speaker the co-driver can mute: guidance and information prompts are dropped while
    muted (counted); warnings (``Priority.SAFETY``) are always spoken."""

    def __init__(self, inner: Speaker) -> None:
        self.inner = inner
        self._muted = False
        self.dropped_muted = 0
        self.dropped_at_mute = 0
        """``dropped_muted`` when it was last muted (the screen shows those since)."""

    @property
    def muted(self) -> bool:
        return self._muted

    @muted.setter
    def muted(self, value: bool) -> None:
        if value and not self._muted:
            self.dropped_at_mute = self.dropped_muted
        self._muted = value

    def say(self, text: str, priority: int = 0, t_s: float | None = None) -> None:
        if self.muted and priority < Priority.SAFETY:
            self.dropped_muted += 1
            return
        self.inner.say(text, priority, t_s)

    def close(self, drain: bool = True) -> None:
        self.inner.close(drain)

    def __getattr__(self, name: str) -> Any:  # stats(), health(), ... of the real speaker
        return getattr(self.inner, name)


class Operator:
    """``App.listeners`` entry and co-driver command handler of ``guidance run``."""

    def __init__(
        self,
        screen: OperatorScreen,
        pipeline: Pipeline,
        *,
        speaker: MutableSpeaker | None = None,
        co_driver: Any = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.screen = screen
        self.pipeline = pipeline
        self.speaker = speaker
        self.co_driver = co_driver
        self.clock = clock
        self.loop: asyncio.AbstractEventLoop | None = None
        self._next_live = 0.0

    def __call__(self, msg: Any, out: Any) -> None:
        """On the loop, after each input and tick."""
        now = self.screen.wall()
        self.screen.fold(lambda v: v.apply(msg, out, now))
        for taken in out.exits_taken:
            if not taken.followed:
                self.speak(Say(Speech.DIFFERENT_EXIT), Priority.GUIDANCE, taken.t_s)
        if now >= self._next_live:
            self._next_live = now + LIVE_PERIOD_S
            self.refresh()

    def speak(self, say: Say, priority: Priority, t_s: float) -> None:
        """An event in the sentence table's words, in the car's units (``speech.words``)."""
        self.say(speech.words(say, self.pipeline.config.units), priority, t_s)

    def say(self, text: str, priority: Priority, t_s: float) -> None:
        """Speak (when there is a voice) and show it with the pipeline's prompts (on the loop)."""
        if self.speaker is not None:
            self.speaker.say(text, priority, t_s)
        now = self.screen.wall()
        style = "bad" if priority >= Priority.SAFETY else ""
        self.screen.fold(lambda v: v.add(now, "prompt", text, style))

    def show_voice(self) -> None:
        """The VOICE row: on, or muted with the prompts not spoken since."""
        sp = self.speaker
        if sp is None:
            return
        muted, unsaid = sp.muted, sp.dropped_muted - sp.dropped_at_mute
        self.screen.fold(lambda v: v.set_voice(muted, unsaid))

    def refresh(self) -> None:
        self.show_voice()
        p = self.pipeline
        t = p.t_s if p.t_s is not None else self.clock()
        inputs = p.statuses(t)
        target = p.target()
        desc, ok = co_driver_state(self.co_driver)
        self.screen.fold(
            lambda v: v.set_live(
                inputs=inputs,
                target=target,
                heading_known=p.estimate.heading_known,
                speed_mps=p.estimate.speed_mps,
                co_driver=desc,
                co_driver_ok=ok,
            )
        )

    def on_command(self, command: str) -> str:
        """The co-driver's "repeat" or "mute" (from the input's reader thread)."""
        if command == "mute":
            if self.speaker is None:
                return "no voice in this run"
            self.speaker.muted = not self.speaker.muted
            self.show_voice()
            return "voice muted (warnings still spoken)" if self.speaker.muted else "voice on"
        if command == "repeat":
            with self.screen.lock:
                text = self.screen.view.last_turn_prompt
            if not text:
                return "nothing to repeat yet"
            if self.loop is not None:
                self.loop.call_soon_threadsafe(
                    lambda: self.say(text, Priority.GUIDANCE, self.clock())
                )
            return f"repeating: {text}"
        return f"unknown command {command}"


def co_driver_state(source: Any) -> tuple[str, bool]:
    """(what the screen says about the co-driver input, whether it works)."""
    if source is None:
        return "NONE: intersections cannot be reported", False
    describe = getattr(source, "describe", None)
    text = describe() if callable(describe) else str(getattr(source, "name", source))
    connected = getattr(source, "connected", True)
    return text, bool(connected)


def banner_rows(cfg: AppConfig, *, voice: str, co_driver: str) -> list[tuple[str, str]]:
    """The start-up banner: vehicle, config, inputs, voice, telemetry and recording."""
    rows = [("vehicle", cfg.vehicle_id), ("config", cfg.path)]
    rows.append(("method", cfg.pipeline.navigator.method.value))
    for kind, dev in (("odometry", cfg.odometry), ("compass", cfg.compass), ("camera", cfg.camera)):
        if dev is None:
            rows.append((kind, "off"))
            continue
        c = dev.config
        where = getattr(c, "channel", None) or getattr(c, "port", None) or getattr(c, "source", "")
        iface = getattr(c, "interface", "")
        rate = f", expected {dev.expected_rate_hz:g} Hz" if dev.expected_rate_hz else ""
        rows.append((kind, f"{dev.backend} {iface} {where}".replace("  ", " ") + rate))
    rows.append(("co-driver", co_driver))
    rows.append(("voice", voice))
    tel = cfg.telemetry
    if tel.enabled:
        ends = ", ".join((*tel.listen, *tel.connect))
        rows.append(("telemetry", f"zenoh {tel.mode} {ends}".strip()))
    else:
        rows.append(("telemetry", "off"))
    rec = cfg.recording
    rows.append(("recording", rec.directory if rec.enabled else "off"))
    rows.append(("checkpoint", cfg.checkpoint.path or "off"))
    return rows
