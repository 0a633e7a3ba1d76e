"""The monitor side: ``MonitorClient`` receives telemetry events.

Each message kind has its own zenoh subscriber, and the subscriber's handler is the drop policy:

* ``state`` and ``health`` (``RING_KINDS``): one ``zenoh.handlers.RingChannel(fleet_ring_size)``
  per kind for the whole fleet (16,384: 1.6 s of 1,000 cars at 10 Hz), drained whole at each
  look, of which each car keeps its newest ``ring_size`` (default 2; its newest one when
  that would be more than ``LOOK_STATES`` in all). So when the reader is
  behind, each car's oldest states are dropped, never a car: every car's newest state is
  handed out at the next look, whatever the number of cars. (A ring of 256 shared by the
  fleet and handed out in order, as before, held a quarter of a second of 100 cars.) The
  drops are seen as ``seq`` gaps (``FleetView.gaps``), like a message lost by the car or the
  network, and counted in ``MonitorClient.overwritten`` when it is this client that dropped
  them for a newer one.
* decisions, prompts, landmarks, turns, exits (``FIFO_KINDS``), liveliness and late-join
  replies: ``zenoh.handlers.FifoChannel(fifo_size)``. Every one matters and none is dropped
  here: when one is full, zenoh's receiving thread waits for the reader. While it waits, nothing
  else arrives from that link, the rings included. The car publishes with
  ``CongestionControl.DROP``, so it never waits for a slow monitor; it drops on its side
  instead, which the monitor again sees as ``seq`` gaps.

No Python code runs on zenoh's receiving threads for messages: a callback there needs the GIL,
and while the reader holds it (folding a batch) the thread waits up to the interpreter's
switch interval (5 ms) per sample; the link's socket then backs up and the router drops
states (``CongestionControl.DROP``). That capped an earlier client at about 200 samples a
second while it was busy (issue 24). A waker thread blocks in ``recv`` of a one-sample ring on
every message key instead (zenoh releases the GIL while it waits) and sets the event an idle
``get`` waits on; liveliness changes, rare, still wake it from a callback.
"""

from __future__ import annotations

import contextlib
import json
import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

import zenoh

from guidance.errors import UserError
from guidance.telemetry.config import TlsConfig, check_endpoint
from guidance.telemetry.goals import send_goal
from guidance.telemetry.keys import (
    _MODES,
    DEFAULT_CONNECT,
    KEY_PREFIX,
    KINDS,
    is_vehicle_id,
    parse_key,
    validate_vehicle_id,
)
from guidance.telemetry.redact import _zenoh_error_text
from guidance.telemetry.session import (
    _close_at_exit,
    _quiet_close,
    callback_threads,
    open_session,
    session_config,
)

log = logging.getLogger(__name__)

RING_KINDS = ("state", "health")
"""Kinds whose latest values matter: each car keeps its newest few at each look."""
FIFO_KINDS = tuple(k for k in KINDS if k not in RING_KINDS)
"""Kinds where every message matters: a ``FifoChannel`` that makes zenoh wait when full."""
REPLY_POLL_S = 0.002
"""zenoh's channels cannot be waited on together. Each message or liveliness change also sets
a wake-up event (the waker's ring and a liveliness callback, declared after the channels),
which an idle ``get`` waits on; late-join replies have no such wake-up, so while a query is
open ``get`` looks at its channel every 2 ms."""
IDLE_CHECK_S = 0.05
"""An idle ``get`` looks at the channels at least this often even without a wake-up."""
BUSY_FRACTION = 0.5
"""Under load the reader spends at most about this share of its time on what one look took:
after a look whose events took C seconds to hand out (and the caller to fold), the next look
waits until C / BUSY_FRACTION after it (but at most ``MAX_PAUSE_S`` more). With few cars a
look takes microseconds and so does the pause; at 1,000 cars a look of 0.15 s is followed by
0.15 s in which each car's newer states replace its older in the fleet's ring, and the next
look takes each car's newest: one core is never spent folding states nobody will see."""
LOOK_STATES = 1024
"""A look keeps each car's newest ``ring_size`` states (and health) while that is at most this
many in all, else each car's newest one: 1,024 states take the reader about 0.15 s to decode,
check and fold (``benchmarks/monitor_fleet.py``), so with the pause below every car's state is
shown well within a second at 1,000 cars. With a few cars a look keeps two per car, so a
reader a period late still sees every state."""
TOKENS_WAIT_S = 0.5
"""``open`` waits up to this long for the cars alive now (``_tokens_now``): normally in before
the first look, so a car's "alive" comes before its messages; an unreachable peer costs this."""
MIN_LOOK_S = 0.01
"""Looks that found something are at least this far apart: at thousands of messages a second
a reader that keeps up would otherwise look (and be woken) for each one, a thread hand-over
each time, and spend more on that than on the messages. A car at 50 Hz is 20 ms between
messages, so it never waits for this."""
MANY_NEW_CARS = 16
"""More cars than this asked for by one ``get`` are asked with one query of the fleet."""
PACED_LOOK = 100
"""Only a look of at least this many events is followed by a pause: with a few cars the
reader is never busy because of them, and a look a loaded machine slowed down is not a
reason to hold back the next (and conflate their states)."""
MAX_PAUSE_S = 0.25
"""The longest pause between looks, so what is shown is never held back much more than this
(a look that itself took longer is followed by the next at once)."""
_SETTLE_S = (0.0002, 0.0005, 0.001)
"""After a wake-up that found nothing yet (the callback ran before the sample reached its
channel), the channels are looked at again after these pauses."""

_T = TypeVar("_T")


def pause_after(look_s: float) -> float:
    """How long the reader waits before its next look, after one whose events took
    ``look_s`` seconds to hand out (``BUSY_FRACTION``, ``MAX_PAUSE_S``)."""
    return min(MAX_PAUSE_S, max(0.0, look_s) * (1.0 / BUSY_FRACTION - 1.0))


# -- the monitor side ------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class TelemetryEvent:
    """One thing a monitor saw: a message, or a car appearing ("alive") or vanishing ("gone")."""

    kind: str
    vehicle_id: str
    key: str
    message: Mapping[str, Any] | None
    received_s: float
    """Monitor's monotonic clock when the client took it from zenoh's channel: as it arrives
    while a reader waits in ``get``, later when the reader is behind."""
    late_join: bool = False
    """True when it came from the query of the latest values, not a live publication."""
    source: str = ""
    """The publishing zenoh session's id when the sample says (zenoh's source info: the
    project's cars set it), else "" (``guidance.tools.monitor_ids``)."""


def _drain(channel: zenoh.Handler[_T], limit: int) -> tuple[list[_T], bool]:
    """Up to ``limit`` items waiting in ``channel``, and whether the channel has closed (its
    query finished, its session closed)."""
    items: list[_T] = []
    try:
        while len(items) < limit:
            item = channel.try_recv()
            if item is None:
                break
            items.append(item)
    except zenoh.ZError:  # "channel is empty and closed"
        return items, True
    return items, False


class MonitorClient:
    """Subscribes to one vehicle or all (``vehicle="all"``): messages and liveliness.

    ``get(timeout_s)`` returns the next event. The queues are zenoh's own channels, one per
    kind (see the module): ``fleet_ring_size`` for state and health (of which each car keeps
    its newest ``ring_size`` at each look), ``fifo_size`` for the others, for liveliness and
    for each late-join query. A ``get`` that finds its batch empty takes
    everything waiting in the channels at once: first the cars that appeared, then late-join
    replies, then the messages (state, health, then the FIFO kinds), then the cars that went,
    so a car's last messages come before its "gone". Order across kinds is kept only within a
    kind; batches are a few milliseconds apart while the reader keeps up.

    ``received`` counts the messages handed out, ``undecodable`` those that were not a JSON
    object, ``bad_keys`` the samples (messages, late-join replies, liveliness tokens) whose key
    is not ``guidance/<vehicle id>[/<kind>]`` with a valid vehicle id: a key comes from the
    network, so a rogue peer's ``guidance/a b`` is one dropped, counted sample here, and every
    event handed out names a valid vehicle id (``validate_vehicle_id`` never fails on it).
    ``overwritten`` counts the states and health a car dropped at a look for its newer ones;
    what the fleet's ring itself overwrote nothing counts (zenoh does not say), and the FIFOs
    drop nothing.
    """

    def __init__(
        self,
        connect: Sequence[str] = (DEFAULT_CONNECT,),
        *,
        vehicle: str = "all",
        mode: str = "peer",
        zenoh_config: str = "",
        tls: TlsConfig | None = None,
        ring_size: int = 2,
        fifo_size: int = 1024,
        fleet_ring_size: int = 16_384,
        look_states: int = LOOK_STATES,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        for ep in connect:
            check_endpoint(ep)
        if mode not in _MODES:
            raise UserError(f"mode must be one of {_MODES}, not {mode!r}")
        if vehicle != "all":
            validate_vehicle_id(vehicle)
        if min(ring_size, fifo_size, fleet_ring_size, look_states) < 1:
            raise UserError(
                f"ring, FIFO and look sizes must be at least 1, not {ring_size}, {fifo_size}, "
                f"{fleet_ring_size}, {look_states}"
            )
        self.connect = tuple(connect)
        self.vehicle = vehicle
        self.ring_size = ring_size
        self.fifo_size = fifo_size
        self.fleet_ring_size = fleet_ring_size
        self.look_states = look_states
        self._mode = mode
        self._zenoh_config = zenoh_config
        self._tls = tls
        self._clock = clock
        self._session: zenoh.Session | None = None
        self._entities: list[zenoh.Subscriber[zenoh.Handler[zenoh.Sample]]] = []
        self._messages: list[tuple[zenoh.Handler[zenoh.Sample], int, int | None]] = []
        """(channel, how many to take at a look, newest kept per key or None for all)."""
        self._waker: threading.Thread | None = None
        self._liveliness: zenoh.Handler[zenoh.Sample] | None = None
        self._replies: list[zenoh.Handler[zenoh.Reply]] = []
        self._replies_lock = threading.Lock()
        self._batch: deque[TelemetryEvent] = deque()
        self._wake = threading.Event()
        self._reader_waiting = threading.Event()
        """Set while ``get`` waits: only then does the waker listen (one wake-up per wait,
        not one per message: 10,000 a second at 1,000 cars, each taking the GIL)."""
        self._wakers: list[zenoh.Subscriber[Any]] = []
        self._callback_threads: list[threading.Thread] = []
        self.received = 0
        self.undecodable = 0
        self.bad_keys = 0
        self.overwritten = 0
        self.queries = 0
        """Queries for the latest values sent (``query_latest``)."""
        """States and health this client dropped for a newer one of the same car (behind)."""
        self._goals_sent = 0
        self._look_s: float | None = None
        """When the batch being handed out was taken (monotonic), if it is to be followed by a
        pause (``PACED_LOOK``); None otherwise."""
        self._next_look_s = 0.0
        self._tokens: list[zenoh.Sample] = []  # cars alive at open (_tokens_now), not handed out
        self._lively_seen: set[str] = set()
        """Cars whose token this client saw come or go live (newer than ``_tokens``)."""
        self._history_thread: threading.Thread | None = None
        self._wanted: set[str] = set()
        """Cars whose latest values are to be asked for at the next ``get``."""

    @property
    def _vehicle_chunk(self) -> str:
        return "*" if self.vehicle == "all" else self.vehicle

    def open(self) -> MonitorClient:
        """Open the session and subscribe; raises ``UserError`` on a bad endpoint or config.

        An endpoint that is valid but not (yet) reachable is not an error: zenoh
        keeps trying, and no events arrive until it connects.
        """
        conf = session_config(
            mode=self._mode,
            connect=self.connect,
            zenoh_config=self._zenoh_config,
            tls=self._tls,
        )
        session = open_session(conf)
        self._session = session
        _close_at_exit(self)
        v = self._vehicle_chunk
        for kind in RING_KINDS:  # the latest values matter: each car's newest are kept
            ring: zenoh.handlers.RingChannel[zenoh.Sample] = zenoh.handlers.RingChannel(
                self.fleet_ring_size
            )
            self._subscribe(session, kind, ring, self.fleet_ring_size, self.ring_size)
        for kind in FIFO_KINDS:  # every one matters: zenoh waits for the reader
            fifo: zenoh.handlers.FifoChannel[zenoh.Sample] = zenoh.handlers.FifoChannel(
                self.fifo_size
            )
            self._subscribe(session, kind, fifo, self.fifo_size, None)
        # No history here: the cars already alive are asked by another, short-lived session
        # (``_tokens_now``). A liveliness query (history=True, or a liveliness get) on this
        # session left every state after it about a second late at 1,000 cars (zenoh 1.x;
        # a data query does not; measured in docs/telemetry.md); a token's removal still
        # reaches this subscriber whether or not it saw the token appear.
        lively = session.liveliness().declare_subscriber(
            f"{KEY_PREFIX}/{v}", zenoh.handlers.FifoChannel(self.fifo_size)
        )
        self._entities.append(lively)
        self._liveliness = lively.handler
        self._history_thread = threading.Thread(
            target=self._tokens_now, name="monitor-tokens", daemon=True
        )
        self._history_thread.start()
        self._history_thread.join(TOKENS_WAIT_S)  # their "alive" before their messages
        # Declared last, so zenoh has pushed a sample into its channel before these wake a
        # waiting get (they hold nothing the reader takes).
        waker = session.declare_subscriber(f"{KEY_PREFIX}/{v}/*", zenoh.handlers.RingChannel(1))
        before = threading.enumerate()
        self._wakers = [
            waker,
            session.liveliness().declare_subscriber(f"{KEY_PREFIX}/{v}", self._wake_up),
        ]
        self._callback_threads = callback_threads(before)  # the liveliness callback's: joined
        self._waker = threading.Thread(
            target=self._wake_on, args=(waker.handler,), name="monitor-waker", daemon=True
        )
        self._waker.start()
        return self

    def _tokens_now(self) -> None:
        """The liveliness tokens alive now, asked by a session of its own that is closed once
        they are in (see ``open``); handed out as "alive" at the next look, except for a car
        whose token this client has already seen come or go. If that session cannot open (a
        config that fixes the zenoh id, say) the main one asks instead."""
        key = f"{KEY_PREFIX}/{self._vehicle_chunk}"
        own: zenoh.Session | None = None
        asker: zenoh.Session | None
        try:
            own = open_session(
                session_config(
                    mode=self._mode,
                    connect=self.connect,
                    zenoh_config=self._zenoh_config,
                    tls=self._tls,
                )
            )
            asker = own
        except Exception as exc:
            log.info("monitor: asking for the cars alive on the main session (%s)", exc)
            asker = self._session
        try:
            if asker is None:
                return
            replies = asker.liveliness().get(key, zenoh.handlers.FifoChannel(65_536), timeout=2.0)
            for reply in replies:
                if reply.ok is not None:
                    with self._replies_lock:
                        self._tokens.append(reply.ok)
                    self._wake.set()
        except Exception as exc:  # the client closed meanwhile, or zenoh refused the query
            log.debug("monitor: liveliness query ended: %s", _zenoh_error_text(exc))
        finally:
            if own is not None:
                _quiet_close(own, [])

    def _wake_up(self, _sample: zenoh.Sample) -> None:
        self._wake.set()

    def _wake_on(self, channel: zenoh.Handler[zenoh.Sample]) -> None:
        """The waker thread: blocks in zenoh (GIL released) until a message arrives, sets the
        wake-up event, again; ends when the session closes its channel."""
        try:
            while True:
                self._reader_waiting.wait()
                channel.recv()
                self._reader_waiting.clear()
                self._wake.set()
        except Exception:  # zenoh.ZError "channel is empty and closed": the client closed
            return

    def _subscribe(
        self,
        session: zenoh.Session,
        kind: str,
        channel: zenoh.handlers.RingChannel[zenoh.Sample]
        | zenoh.handlers.FifoChannel[zenoh.Sample],
        size: int,
        keep: int | None,
    ) -> None:
        """One kind's subscriber; its channel (of ``size``) and ``keep`` (newest per car at
        each look, None: all) are the kind's drop policy."""
        sub = session.declare_subscriber(f"{KEY_PREFIX}/{self._vehicle_chunk}/{kind}", channel)
        self._entities.append(sub)
        self._messages.append((sub.handler, size, keep))

    def __enter__(self) -> MonitorClient:
        return self.open()

    def __exit__(self, *_exc: object) -> None:
        self.close()

    def close(self) -> None:
        session, self._session = self._session, None
        self._entities.clear()
        wakers, self._wakers = self._wakers, []
        self._messages = []
        self._liveliness = None
        with self._replies_lock:
            self._replies.clear()
        for entity in wakers:  # closes the waker's channel: its thread ends
            with contextlib.suppress(Exception):
                entity.undeclare()
        self._reader_waiting.set()  # a waker waiting for the reader goes on to the closed channel
        threads, self._callback_threads = self._callback_threads, []
        if session is not None:
            _quiet_close(session, threads)
        waker, self._waker = self._waker, None
        if waker is not None and waker is not threading.current_thread():
            waker.join(2.0)
        history, self._history_thread = self._history_thread, None
        if history is not None and history is not threading.current_thread():
            history.join(3.0)

    def query_latest(self, vehicle_id: str | None = None, timeout_s: float = 2.0) -> None:
        """Ask the cars (or one) for their latest messages; replies arrive later as events.

        Non-blocking. The monitor asks once when it opens and again when a car
        appears, so a monitor joining late sees each car's state at once. A car's query goes
        out at the next ``get``; when more than ``MANY_NEW_CARS`` are asked for by then (a
        monitor opening on a running fleet, the fleet coming back after a router restart)
        they are asked with one query of the fleet, not one each: a thousand queries, each
        answered with every kind's latest, took a fifth of a monitor's first seconds.
        """
        if vehicle_id is not None:
            self._wanted.add(validate_vehicle_id(vehicle_id))
            return
        self._wanted.clear()
        self._query(self._vehicle_chunk, timeout_s)

    def _ask_wanted(self) -> None:
        wanted, self._wanted = self._wanted, set()
        if len(wanted) > MANY_NEW_CARS:
            self._query(self._vehicle_chunk, 2.0)
            return
        for vid in sorted(wanted):
            self._query(vid, 2.0)

    def _query(self, chunk: str, timeout_s: float) -> None:
        session = self._session
        if session is None:
            return
        self.queries += 1
        try:
            replies = session.get(
                f"{KEY_PREFIX}/{chunk}/*",
                zenoh.handlers.FifoChannel(self.fifo_size),
                timeout=timeout_s,
            )
        except Exception as exc:
            log.warning("monitor: query for latest values failed: %s", _zenoh_error_text(exc))
            return
        with self._replies_lock:
            self._replies.append(replies)

    def get(self, timeout_s: float | None = None) -> TelemetryEvent | None:
        """The next event, waiting up to ``timeout_s`` (None: for ever); None if none came."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        woken = False
        while True:
            if not self._batch and self._look_s is not None:  # the last look is handed out
                now = time.monotonic()
                cost = now - self._look_s
                self._next_look_s = now + pause_after(cost)
                self._look_s = None
            if not self._batch:
                if self._wanted:
                    self._ask_wanted()
                rest = self._next_look_s - time.monotonic()
                if deadline is not None:
                    rest = min(rest, deadline - time.monotonic())
                if rest > 0:
                    time.sleep(rest)
                self._wake.clear()
                taken = time.monotonic()
                self._take_waiting()
                for pause in _SETTLE_S if woken else ():
                    if self._batch:
                        break
                    time.sleep(pause)
                    self._take_waiting()
                if self._batch:
                    self._next_look_s = max(self._next_look_s, taken + MIN_LOOK_S)
                if len(self._batch) >= PACED_LOOK:
                    self._look_s = taken
            if self._batch:
                return self._batch.popleft()
            now = time.monotonic()
            if deadline is not None and now >= deadline:
                return None
            with self._replies_lock:
                wait = REPLY_POLL_S if self._replies else IDLE_CHECK_S
            if deadline is not None:
                wait = min(wait, deadline - now)
            self._reader_waiting.set()
            woken = self._wake.wait(wait)
            self._reader_waiting.clear()

    def pending(self) -> int:
        """Events taken from zenoh and not yet handed out (a caller may flush its output when
        none are left, instead of after each)."""
        return len(self._batch)

    def send_goal(self, vehicle_id: str, x_m: float, y_m: float, wait_s: float = 3.0) -> bool:
        """Ask a car for a new goal once its goal subscription is known (``goals.send_goal``);
        False if no car listening for goals appeared within ``wait_s``. The car obeys only if
        its config, range check and ACL allow."""
        session = self._session
        if session is None:
            raise UserError("monitor session is not open")
        self._goals_sent += 1
        return send_goal(session, vehicle_id, x_m, y_m, self._goals_sent, wait_s)

    def peers(self) -> int:
        session = self._session
        if session is None:
            return 0
        info = session.info
        return len(info.peers_zid()) + len(info.routers_zid())

    def _take_waiting(self) -> None:
        """Move everything waiting in the channels into the batch, in the order the class
        describes; at most one channel's capacity from each."""
        lively: list[TelemetryEvent] = []
        with self._replies_lock:
            tokens, self._tokens = self._tokens, []
        for e in map(self._liveliness_event, tokens):
            if e is not None and e.vehicle_id not in self._lively_seen:
                lively.append(e)
        if self._liveliness is not None:
            samples, _closed = _drain(self._liveliness, self.fifo_size)
            live = [e for e in map(self._liveliness_event, samples) if e is not None]
            self._lively_seen.update(e.vehicle_id for e in live)
            lively += live
        appeared = next((i for i, e in enumerate(lively) if e.kind != "alive"), len(lively))
        self._batch.extend(lively[:appeared])
        with self._replies_lock:
            queries = list(self._replies)
        for replies in queries:
            items, closed = _drain(replies, self.fifo_size)
            for reply in items:
                if reply.ok is not None:
                    self._keep(self._message_event(reply.ok, late_join=True))
            if closed:
                with self._replies_lock:
                    self._replies.remove(replies)
        for channel, size, keep in self._messages:
            samples = _drain(channel, size)[0]
            if keep is not None and len(samples) > keep:
                samples = self._newest(samples, keep)
            for sample in samples:
                self._keep(self._message_event(sample, late_join=False))
        self._batch.extend(lively[appeared:])

    def _newest(self, samples: list[zenoh.Sample], keep: int) -> list[zenoh.Sample]:
        """The newest ``keep`` samples of each key (the newest one when that is more than
        ``LOOK_STATES`` in all), keys in the order first seen, each key's in arrival order;
        the others are counted in ``overwritten``."""
        by_key: dict[str, list[zenoh.Sample]] = {}
        for sample in samples:
            ring = by_key.get(key := str(sample.key_expr))
            if ring is None:
                by_key[key] = [sample]
            else:
                ring.append(sample)
        if len(by_key) * keep > self.look_states:
            keep = 1
        kept = [sample for ring in by_key.values() for sample in ring[-keep:]]
        self.overwritten += len(samples) - len(kept)
        return kept

    def _keep(self, event: TelemetryEvent | None) -> None:
        if event is not None:
            self._batch.append(event)

    def _message_event(self, sample: zenoh.Sample, late_join: bool) -> TelemetryEvent | None:
        key = str(sample.key_expr)
        parsed = parse_key(key)
        if parsed is None or not is_vehicle_id(parsed[0]) or parsed[1] not in KINDS:
            self._bad_key(key)
            return None
        vehicle_id, kind = parsed
        try:
            message = json.loads(sample.payload.to_bytes())
            if not isinstance(message, dict):
                raise ValueError("not an object")
        except ValueError:
            self.undecodable += 1
            return None
        self.received += 1
        info = sample.source_info
        source = str(info.source_id.zid) if info is not None else ""
        return TelemetryEvent(kind, vehicle_id, key, message, self._clock(), late_join, source)

    def _liveliness_event(self, sample: zenoh.Sample) -> TelemetryEvent | None:
        key = str(sample.key_expr)
        parts = key.split("/")
        if len(parts) != 2 or parts[0] != KEY_PREFIX or not is_vehicle_id(parts[1]):
            self._bad_key(key)
            return None
        kind = "alive" if sample.kind == zenoh.SampleKind.PUT else "gone"
        return TelemetryEvent(kind, parts[1], key, None, self._clock())

    def _bad_key(self, key: str) -> None:
        """A sample under a key no car publishes: dropped and counted, never an event (its id
        would reach ``query_latest`` and the displays). Logged the first 10 times, then every
        100th, with the key shown escaped and cut (it is network text)."""
        self.bad_keys += 1
        n = self.bad_keys
        if n <= 10 or n % 100 == 0:
            shown = ascii(key[:80]) + ("..." if len(key) > 80 else "")
            log.warning("monitor: dropped a sample under the foreign key %s (%d so far)", shown, n)
