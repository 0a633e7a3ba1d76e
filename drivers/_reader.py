"""The reader-thread machinery the live drivers share (CAN odometry, serial compass, camera).

``ThreadedSource`` is what is the same in every live source around its own reading: the health
tracker, the counters and their lock, starting and stopping the daemon thread(s), handing data to
the sink without ever letting a failing sink stop the reader (counted as ``sink_errors``, logged
once when it starts failing and once when it works again), the doubling reconnect backoff, and
logging a device lost and found once per flip. A driver supplies the reading (``_run``, or
``_workers`` for more than one thread) and, through small hooks, what it opens and closes.

Back-pressure (issue 14): a consumer that can say how much it has not processed yet
(``set_backlog``, the app's queue) makes ``_deliver_bounded`` hold data instead of queueing
more while it is behind: a driver that can merge its messages (``_merge``: the CAN odometry
sums its increments and keeps the last time) folds the held one and the new one into one
(counted ``coalesced``); one that cannot drops the older (counted ``dropped_behind``).
"""

from __future__ import annotations

import contextlib
import functools
import logging
import threading
from collections import Counter
from collections.abc import Callable, Iterable, Mapping
from typing import ClassVar, Generic, Protocol, Self, TypeVar

from drivers.health import HealthTracker
from guidance.core.messages import Health, RawRecord, RawSink

T = TypeVar("T")

JOIN_TIMEOUT_S = 5.0
"""How long ``stop()`` waits for each thread (reads time out well within this)."""
BACKLOG_LIMIT = 32
"""Messages handed over and not yet processed beyond which ``_deliver_bounded`` holds data."""


class SourceTiming(Protocol):
    """The part of a driver's configuration the base reads."""

    @property
    def stale_after_s(self) -> float: ...

    @property
    def reconnect_max_s(self) -> float: ...


def rejection_counters(counts: Mapping[str, int], reasons: Iterable[str]) -> dict[str, int]:
    """``rejected_<reason>`` for every reason of a parser or decoder, zeros included."""
    return {f"rejected_{reason}": counts.get(reason, 0) for reason in reasons}


"""``(kind, t_s, fields)``: "can" with id, data, is_extended_id, is_error_frame, channel;
"nmea" with line, port."""


class ThreadedSource(Generic[T]):
    """Base of the live sources: one or more daemon threads feeding a sink of ``T``.

    Subclasses set ``sink_kind`` (named in the sink-failure log lines), ``_device`` (named in the
    connection log lines) and implement ``_run(sink)``, or override ``_workers`` for several
    threads. Counters go in ``_counts`` under ``_lock``; ``stats()`` is ``_source_stats()`` plus
    them, and ``health()`` evaluates the tracker with ``stats()``.
    """

    sink_kind: ClassVar[str] = "data"
    """'the <sink_kind> sink raised; continuing'."""
    announce_first_connect: ClassVar[bool] = False
    """Log (info) the first successful open, not only losing and finding the device again."""
    unit: ClassVar[str] = "frames"
    """The counter of the units of data read ("frames", "lines"): ``stats()["read"]``."""
    join_timeout_s: float = JOIN_TIMEOUT_S
    """How long ``stop()`` waits for each thread."""
    may_outlive_stop: ClassVar[bool] = False
    """A thread may stay blocked in a read nothing can wake (``readline`` on a terminal): it is
    a daemon that delivers nothing after ``stop()``, so that is not an error."""

    def __init__(
        self,
        name: str,
        config: SourceTiming,
        *,
        clock: Callable[[], float],
    ) -> None:
        """``config`` gives ``stale_after_s`` (health) and ``reconnect_max_s`` (backoff)."""
        self.name = name
        self._log = logging.getLogger(type(self).__module__)
        """The driver's own module logger: log configuration and tests select it by name."""
        self._health = HealthTracker(
            name, stale_after_s=config.stale_after_s, clock=clock
        )
        self._reconnect_max_s = config.reconnect_max_s
        self._device = name
        self._lock = threading.Lock()
        self._counts: Counter[str] = Counter()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._connected: bool | None = None  # None: never tried yet
        self._sink_failing = False
        self._backlog: Callable[[], int] | None = None
        self._backlog_limit = BACKLOG_LIMIT
        self._held: T | None = None
        self._raw_sink: RawSink | None = None
        self._order: threading.Lock | None = None

    # raw input ---------------------------------------------------------------------------------

    def set_raw_sink(self, raw_sink: RawSink | None, order: threading.Lock | None = None) -> None:
        """Offer every raw unit read (a ``RawCanFrame``, a ``RawNmeaLine``) to ``raw_sink``
        before decoding it: the app records raw inputs through this supported hook
        (``/can``, ``/nmea``). A failing raw sink is logged once and never stops the reader.

        ``order``, one lock for every source recorded alike, is held from a unit's raw record
        to the hand-over of what it decoded: two readers' units are then recorded in the order
        their messages reach the consumer, so the raw records replay in the order the
        pipeline took them (without it, a CAN frame recorded before an NMEA line could reach
        the loop after it, and a replay of the raw records made another drive)."""
        self._raw_sink = raw_sink
        self._order = order

    def _in_order(self) -> contextlib.AbstractContextManager[object]:
        """The recording's order lock (``set_raw_sink``), or nothing when not recording."""
        return self._order if self._order is not None else contextlib.nullcontext()

    def set_status_sink(self, status_sink: Callable[[Health], None] | None) -> None:
        """Hand every change of this driver's status (``starting``, ``ok``, ``silent``,
        ``disconnected``, ``invalid``...) with its health record to ``status_sink``: what only
        the driver knows (its device is gone) reaches the app, the voice and the monitor."""
        self._health.on_flip = status_sink

    def _offer_raw(self, record: RawRecord) -> None:
        raw = self._raw_sink
        if raw is None:
            return
        try:
            raw(record)
        except Exception:
            self._count("raw_sink_errors")
            if self._counts["raw_sink_errors"] == 1:
                self._log.exception("%s: the raw-input sink raised; continuing", self.name)

    # the source --------------------------------------------------------------------------------

    def start(self, sink: Callable[[T], None]) -> None:
        """Start the thread(s); a device that is missing now is retried, not fatal."""
        if self._threads:
            raise RuntimeError(f"{self.name} already started")
        self._stop.clear()
        self._health.started()
        self._on_start()
        self._threads = [
            threading.Thread(target=target, name=f"{self.name}-{role}", daemon=True)
            for role, target in self._workers(sink)
        ]
        for t in self._threads:
            t.start()

    def stop(self) -> None:
        """Stop the thread(s) and release the device (idempotent)."""
        self._stop.set()
        self._wake()
        for t in self._threads:
            t.join(timeout=self.join_timeout_s)
            if t.is_alive():
                role = t.name.removeprefix(f"{self.name}-")
                if self.may_outlive_stop:  # blocked in a read nothing can wake: a daemon
                    self._log.debug("%s: %s thread left blocked in its read", self.name, role)
                else:  # pragma: no cover - a read ignored its timeout
                    self._log.error("%s: %s thread did not stop", self.name, role)
        self._threads = []
        self._on_stop()
        self._health.stopped()

    def stats(self) -> dict[str, int]:
        """The parser's or decoder's counters and the reader's, with ``read``: the units of data
        read (``unit``: frames, lines; one name whatever the device) next to the parser's
        ``rejected``: what the app's garbled-input check reads."""
        with self._lock:
            out = self._source_stats()
            out.update(self._counts)
        out["read"] = out.get(self.unit, 0)
        return out

    def health(self) -> Health:
        """alive: data arriving; valid: most of the recent data usable (see the class)."""
        return self._health.evaluate(self.stats())

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def set_backlog(self, backlog: Callable[[], int], limit: int = BACKLOG_LIMIT) -> None:
        """``backlog()``: how many handed-over messages the consumer has not processed yet;
        above ``limit`` the driver holds (merges or drops) instead of handing over more."""
        self._backlog = backlog
        self._backlog_limit = max(1, int(limit))

    # hooks ---------------------------------------------------------------------------------------

    def _merge(self, held: T, new: T) -> T | None:
        """One message standing for ``held`` followed by ``new``; None: cannot (drop ``held``)."""
        return None

    def _workers(self, sink: Callable[[T], None]) -> list[tuple[str, Callable[[], None]]]:
        """(role, target) of each thread; the thread is named '<name>-<role>'."""
        return [("reader", functools.partial(self._run, sink))]

    def _run(self, sink: Callable[[T], None]) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def _source_stats(self) -> dict[str, int]:
        """The parser's or decoder's counters (called under ``_lock``)."""
        return {}

    def _on_start(self) -> None:
        """After the tracker is started, before the threads (open a device, sync a clock)."""

    def _wake(self) -> None:
        """Wake threads waiting on something other than ``_stop`` (a condition)."""

    def _on_stop(self) -> None:
        """After the threads have stopped (close the device)."""

    # for the reader ------------------------------------------------------------------------------

    def _count(self, key: str, n: int = 1) -> None:
        with self._lock:
            self._counts[key] += n

    def _backoff(self, delay: float) -> float:
        """The next reconnect delay: doubled, at most ``reconnect_max_s``."""
        return min(2.0 * delay, self._reconnect_max_s)

    def _deliver(self, sink: Callable[[T], None], out: T) -> bool:
        """Hand ``out`` to the sink; a sink that raises is counted and logged, never fatal."""
        try:
            sink(out)
        except Exception:
            self._count("sink_errors")
            if not self._sink_failing:
                self._sink_failing = True
                self._log.exception("%s: the %s sink raised; continuing", self.name, self.sink_kind)
            return False
        if self._sink_failing:
            self._sink_failing = False
            self._log.warning("%s: the %s sink works again", self.name, self.sink_kind)
        return True

    def _behind(self) -> bool:
        backlog = self._backlog
        if backlog is None:
            return False
        try:
            return backlog() >= self._backlog_limit
        except Exception:  # a consumer's counter must never stop the reader
            return False

    def _deliver_bounded(self, sink: Callable[[T], None], out: T | None) -> bool:
        """``_deliver``, unless the consumer is behind: then hold ``out`` (merged with, or
        replacing, what was held). ``out`` None: only try to hand over what is held."""
        held = self._held
        if out is None:
            if held is None:
                return False
            out = held
        elif held is not None:
            merged = self._merge(held, out)
            self._count("coalesced" if merged is not None else "dropped_behind")
            if merged is not None:
                out = merged
        self._held = None
        if self._behind():
            self._held = out
            return False
        return self._deliver(sink, out)

    def _set_connected(self, up: bool, detail: object = "") -> None:
        """Tell the tracker the device is up or down; log once per flip: lost and back."""
        self._health.connected(up, str(detail) if detail else "")
        if up != self._connected:
            self._health.evaluate(self.stats())  # the flip reaches the status sink now
        if up == self._connected:
            return
        was, self._connected = self._connected, up
        if up:
            if was is False:
                self._log.warning("%s: %s is back", self.name, self._device)
            elif self.announce_first_connect:
                self._log.info("%s: reading %s", self.name, self._device)
        else:
            self._count("disconnects")
            self._log.warning(
                "%s: %s unavailable (%s); retrying with backoff up to %.1f s",
                self.name,
                self._device,
                detail,
                self._reconnect_max_s,
            )
