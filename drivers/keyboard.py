"""The co-driver keyboard as a roadway-scene source.

``KeyboardScene`` is the ``RoadwayScene`` source: a thread reads lines from stdin (or any text
stream), parses them with ``guidance.core.co_driver`` and hands the events to the app's sink.
"""

from __future__ import annotations

import logging
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable
from typing import TextIO

from guidance.core.co_driver import SceneParseError, parse_line, to_scene
from guidance.core.messages import IntersectionScene, TurnCompleted

log = logging.getLogger(__name__)

# --------------------------------------------------------------------------- the source


class KeyboardScene:
    """``RoadwayScene`` from co-driver lines on a text stream (stdin by default).

    A daemon thread reads lines (blocking I/O stays off the event loop, HOUSE_STYLE) and calls
    ``sink`` with an ``IntersectionScene`` or ``TurnCompleted``. ``heading_fn`` gives the
    current estimated heading (rad) for turning relative exits into absolute ones; ``clock``
    stamps the line (the message clock). Unparseable lines are counted, logged and answered on
    ``feedback`` (stderr) so the co-driver can retype them.
    """

    def __init__(
        self,
        heading_fn: Callable[[], float],
        *,
        stream: TextIO | None = None,
        feedback: TextIO | None = None,
        clock: Callable[[], float] = time.monotonic,
        name: str = "keyboard",
    ) -> None:
        self.name = name
        self._heading_fn = heading_fn
        self._stream = stream
        self._feedback = feedback
        self._clock = clock
        self._counts: Counter[str] = Counter()
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()

    def start(self, sink: Callable[[IntersectionScene | TurnCompleted], None]) -> None:
        if self._thread is not None:
            raise RuntimeError(f"{self.name} already started")
        self._stop.clear()
        self._thread = threading.Thread(
            target=self._run, args=(sink,), name=f"{self.name}-reader", daemon=True
        )
        self._thread.start()

    def stop(self) -> None:
        """Stop taking lines. A thread blocked in ``readline`` on a terminal cannot be woken;
        it is a daemon and delivers nothing after this."""
        self._stop.set()
        thread, self._thread = self._thread, None
        if thread is not None:
            thread.join(timeout=0.2)

    def stats(self) -> dict[str, int]:
        with self._lock:
            return dict(self._counts)

    def handle_line(
        self, line: str, sink: Callable[[IntersectionScene | TurnCompleted], None]
    ) -> IntersectionScene | TurnCompleted | None:
        """Parse one line and deliver it; returns what was delivered (for tests and replay)."""
        t_s = self._clock()
        with self._lock:
            self._counts["lines"] += 1
        try:
            typed = parse_line(line)
        except SceneParseError as exc:
            with self._lock:
                self._counts["rejected"] += 1
            log.info("%s: %s", self.name, exc)
            out = self._feedback if self._feedback is not None else sys.stderr
            out.write(f"? {exc}\n")
            out.flush()
            return None
        if typed is None:
            return None
        msg = to_scene(typed, t_s, self._heading_fn())
        with self._lock:
            self._counts["intersections" if isinstance(msg, IntersectionScene) else "turns"] += 1
        sink(msg)
        return msg

    def _run(self, sink: Callable[[IntersectionScene | TurnCompleted], None]) -> None:
        stream = self._stream if self._stream is not None else sys.stdin
        while not self._stop.is_set():
            try:
                line = stream.readline()
            except (OSError, ValueError) as exc:  # closed stream
                log.warning("%s: input closed (%s)", self.name, exc)
                return
            if not line:  # end of input: the co-driver's keyboard is gone
                log.info("%s: end of input", self.name)
                return
            if self._stop.is_set():
                return
            try:
                self.handle_line(line, sink)
            except Exception:
                log.exception("%s: the scene sink raised; continuing", self.name)
