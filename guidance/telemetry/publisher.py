"""The car side: ``Telemetry`` publishes on Zenoh (latest-value slots and FIFOs)."""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from functools import partial
from typing import TYPE_CHECKING, Any

import zenoh

from guidance.core.messages import Health, Say, Speech
from guidance.core.speech import words
from guidance.errors import UserError
from guidance.outputs.messages import encode, schema_tag
from guidance.outputs.sink import Build, MessageSink
from guidance.telemetry.config import TelemetryConfig
from guidance.telemetry.keys import (
    KEY_PREFIX,
    KINDS,
    LATEST_KINDS,
    goal_key,
    key_for,
    liveliness_key,
)
from guidance.telemetry.redact import redact_text
from guidance.telemetry.session import (
    _close_at_exit,
    _quiet_close,
    callback_threads,
    goal_sender,
    no_router_took,
    open_session,
    parse_goal,
    remote_goal_problem,
    session_config,
)

if TYPE_CHECKING:
    import asyncio


log = logging.getLogger(__name__)

# -- the car side ---------------------------------------------------------------------------------


@dataclass(slots=True)
class _Pending:
    kind: str
    build: Callable[[], Mapping[str, Any]]


@dataclass(slots=True)
class _Link:
    """Zenoh entities of one open session (replaced as a whole on reconnect)."""

    session: zenoh.Session
    publishers: dict[str, zenoh.Publisher] = field(default_factory=dict)
    others: list[Any] = field(default_factory=list)
    threads: list[threading.Thread] = field(default_factory=list)
    """zenoh's threads running this link's Python callbacks: joined when it closes."""


GoalCallback = Callable[[float, float], None]

ADDRESS_IN_USE = "Address already in use"
JOIN_WAIT_S = 2.0
"""How long a car joining a taken endpoint waits to reach the zenoh peer there."""


def _reaches_a_peer(session: zenoh.Session, wait_s: float) -> bool:
    deadline = time.monotonic() + wait_s
    while not session.info.peers_zid():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.05)
    return True


def join_taken(
    config: TelemetryConfig, error: str
) -> tuple[tuple[str, ...], tuple[str, ...]] | None:
    """A peer whose ``tcp/HOST:PORT`` listen endpoint another process holds (two simulated
    drives side by side, both on the default endpoint): listen on ``tcp/HOST:0`` instead and
    connect to the taken endpoint, so a monitor connected to it learns this car through
    zenoh's gossip and sees both (issue 41). None when that does not apply (another error,
    client mode, a zenoh config file, an endpoint that is not plain TCP)."""
    if not config.join_if_taken or ADDRESS_IN_USE not in error or config.mode != "peer":
        return None
    if config.zenoh_config:
        return None
    listen: list[str] = []
    for ep in config.listen:
        host, sep, port = ep.removeprefix("tcp/").rpartition(":")
        if not ep.startswith("tcp/") or not sep or not port.isdigit():
            return None
        listen.append(f"tcp/{host}:0")
    return tuple(listen), (*config.connect, *config.listen)


class Telemetry(MessageSink):
    """The car's telemetry: one zenoh session, non-blocking ``publish_*`` calls.

    ``on_goal(x_m, y_m)`` receives accepted remote goals (only with
    ``allow_remote_goal``); with ``loop`` it is called on that event loop via
    ``call_soon_threadsafe``, otherwise on a zenoh thread. ``clock`` gives
    wall-clock time for the ``wall_time_unix_s`` field only.
    """

    def __init__(
        self,
        config: TelemetryConfig,
        *,
        on_goal: GoalCallback | None = None,
        loop: asyncio.AbstractEventLoop | None = None,
        clock: Callable[[], float] = time.time,
    ) -> None:
        if config.enabled and config.allow_remote_goal:
            problem = remote_goal_problem(config.zenoh_config)
            if problem is not None:
                raise UserError(problem)  # refuse to start: nobody may steer the car unchecked
        self.config = config
        self.origin_lat_lon_deg = config.origin_lat_lon_deg
        self.vehicle_id = config.vehicle_id
        self._on_goal = on_goal
        self._loop = loop
        self._clock = clock
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._slots: dict[str, _Pending] = {}
        self._fifos: dict[str, deque[_Pending]] = {
            k: deque() for k in KINDS if k not in LATEST_KINDS
        }
        self._seq = dict.fromkeys(KINDS, 0)
        self._latest: dict[str, bytes] = {}
        self._dropped: dict[str, int] = {}
        self._published = 0
        self._goals_accepted = 0
        self._goals_refused = 0
        self._status = "disabled" if not config.enabled else "starting"
        self._connected = False
        self._peers = 0
        self._routers = 0
        self._last_error = ""
        self._link: _Link | None = None
        self._thread: threading.Thread | None = None

    # -- lifecycle ----------------------------------------------------------------------------
    def start(self) -> None:
        """Start the publisher thread, which opens the session; returns at once."""
        if not self.config.enabled or self._thread is not None:
            return
        self._thread = threading.Thread(
            target=self._run, name=f"telemetry-{self.vehicle_id}", daemon=True
        )
        self._thread.start()
        _close_at_exit(self)

    def close(self, timeout_s: float = 3.0) -> None:
        """Stop publishing, drop the liveliness token and close the session (idempotent)."""
        self._stop.set()
        self._wake.set()
        thread, self._thread = self._thread, None
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout_s)
            if thread.is_alive():
                log.warning("telemetry: publisher thread did not stop within %.1f s", timeout_s)
        self._close_link()
        if self.config.enabled:
            self._status = "closed"
            self._connected = False

    def __enter__(self) -> Telemetry:
        self.start()
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    # -- publishing (any thread, never blocks) -----------------------------------------------
    def publish(self, kind: str, t_s: float, build: Build) -> bool:
        """The sink port (``guidance.outputs.sink``): latest-value slot or FIFO by kind."""
        return self._put(kind, partial(build, vehicle_id=self.vehicle_id))

    def own_health(self) -> Health:
        return self.health()

    def _put(self, kind: str, build: Callable[..., Mapping[str, Any]]) -> bool:
        if not self.config.enabled or self._stop.is_set():
            return False
        wall = self._clock()
        with self._lock:
            seq = self._seq[kind] + 1
            self._seq[kind] = seq
            item = _Pending(kind, partial(build, seq=seq, wall_time_unix_s=wall))
            if kind in LATEST_KINDS:
                if kind in self._slots:
                    self._count_drop_locked("superseded")
                self._slots[kind] = item
            else:
                fifo = self._fifos[kind]
                if len(fifo) >= self.config.fifo_size:
                    fifo.popleft()
                    self._count_drop_locked("fifo_full")
                fifo.append(item)
        self._wake.set()
        return True

    def _count_drop_locked(self, reason: str) -> None:
        self._dropped[reason] = self._dropped.get(reason, 0) + 1

    def _count_drop(self, reason: str) -> None:
        with self._lock:
            self._count_drop_locked(reason)

    # -- health -------------------------------------------------------------------------------
    def health(self) -> Health:
        """``status`` "disabled", "starting", "up", "down" (no session, retrying) or "closed";
        ``alive``: the zenoh session is open; ``valid``: messages can leave the car (peer mode
        with a session, client mode with a router connected). ``counters``: peers, routers,
        published, goals_accepted, goals_refused, dropped and ``dropped_<reason>`` for each
        reason; ``info``: mode. The warning is for the operator: telemetry is optional."""
        with self._lock:
            dropped = dict(self._dropped)
        status = self._status
        alive = status == "up"
        valid = alive and (self._connected or self.config.mode != "client")
        down = status == "down" or (alive and not valid)
        return Health(
            "telemetry",
            status,
            alive,
            valid,
            detail=self._last_error,
            warning=words(Say(Speech.COMPONENT, input="telemetry", status="down")) if down else "",
            counters={
                "peers": self._peers,
                "routers": self._routers,
                "published": self._published,
                "goals_accepted": self._goals_accepted,
                "goals_refused": self._goals_refused,
                "dropped": sum(dropped.values()),
                **{f"dropped_{reason}": n for reason, n in dropped.items()},
            },
            info={"mode": self.config.mode},
        )

    def has_subscribers(self, kind: str | None = None) -> bool:
        """True when a subscriber for ``kind`` (every kind when None) is known to the session.

        A monitor's liveliness can arrive before its subscription does; a message published in
        between reaches nobody. zenoh's matching status says when it would.
        """
        link = self._link
        if link is None:
            return False
        try:
            kinds = KINDS if kind is None else (kind,)
            # zenoh-python 1.10 returns a MatchingStatus (its stub says bool): accept both.
            statuses = (link.publishers[k].matching_status for k in kinds)
            return all(bool(getattr(st, "matching", st)) for st in statuses)
        except Exception:  # the session closed meanwhile
            return False

    # -- publisher thread ---------------------------------------------------------------------
    def _run(self) -> None:
        next_link_check = 0.0
        while not self._stop.is_set():
            try:
                if self._link is None:
                    if not self._try_open():
                        self._stop.wait(self.config.retry_period_s)
                        continue
                    next_link_check = 0.0
                now = time.monotonic()
                if now >= next_link_check:
                    self._check_link()
                    next_link_check = now + 1.0
                self._wake.wait(0.5)
                self._wake.clear()
                self._drain()
            except Exception:  # keep publishing whatever went wrong once
                log.exception("telemetry: publisher loop error")
                self._stop.wait(0.5)
        self._drain()

    def _try_open(self) -> bool:
        cfg = self.config
        try:
            session, listen, connect = self._open_session()
        except UserError as exc:
            self._set_down(str(exc))
            return False
        except Exception as exc:  # zenoh may raise anything from its Rust side
            self._set_down(f"{type(exc).__name__}: {exc}")
            return False
        link = _Link(session)
        before = threading.enumerate()
        try:
            for kind in KINDS:
                link.publishers[kind] = session.declare_publisher(
                    key_for(self.vehicle_id, kind),
                    encoding=zenoh.Encoding.APPLICATION_JSON.with_schema(schema_tag(kind)),
                    congestion_control=zenoh.CongestionControl.DROP,
                    express=True,
                )
            link.others.append(session.liveliness().declare_token(liveliness_key(self.vehicle_id)))
            link.others.append(
                session.declare_queryable(
                    f"{KEY_PREFIX}/{self.vehicle_id}/*", self._on_query, complete=True
                )
            )
            if cfg.allow_remote_goal:
                link.others.append(
                    session.declare_subscriber(goal_key(self.vehicle_id), self._on_goal_sample)
                )
        except Exception as exc:
            self._set_down(f"declaring telemetry entities failed: {exc}")
            _quiet_close(session, callback_threads(before))
            return False
        link.threads = callback_threads(before)
        self._link = link
        self._status = "up"
        self._last_error = ""
        where = ", ".join(listen if cfg.mode == "peer" else connect)
        log.info(
            "telemetry up: vehicle %s, %s mode on %s%s",
            self.vehicle_id,
            cfg.mode,
            where,
            ", remote goal ENABLED" if cfg.allow_remote_goal else "",
        )
        return True

    def _open_session(self) -> tuple[zenoh.Session, tuple[str, ...], tuple[str, ...]]:
        """The session as configured, or (``join_if_taken``, the listen endpoint held by
        another process) one that joins that process as a peer; with the endpoints used."""
        cfg = self.config

        def conf(listen: tuple[str, ...], connect: tuple[str, ...]) -> zenoh.Config:
            return session_config(
                mode=cfg.mode,
                listen=listen,
                connect=connect,
                multicast_scouting=cfg.multicast_scouting,
                zenoh_config=cfg.zenoh_config,
                tls=cfg.tls,
            )

        try:
            return open_session(conf(cfg.listen, cfg.connect)), cfg.listen, cfg.connect
        except UserError as exc:
            joined = join_taken(cfg, str(exc))
            if joined is None and cfg.mode == "client" and cfg.connect:
                raise UserError(no_router_took(cfg.connect, str(exc))) from None
            if joined is None:
                raise
            listen, connect = joined
            c = conf(listen, connect)
            # zenoh's peer waits for ever for its connect endpoints by default
            c.insert_json5("connect/timeout_ms", str(int(JOIN_WAIT_S * 1000)))
            c.insert_json5("connect/exit_on_failure", "true")
            try:
                session = open_session(c)
            except UserError as joining:  # what holds the endpoint is not a zenoh peer
                raise UserError(f"{exc}; joining it as a peer failed: {joining}") from None
            if not _reaches_a_peer(session, JOIN_WAIT_S):
                _quiet_close(session)
                raise UserError(f"{exc}; no zenoh peer there to join") from None
        log.warning(
            "telemetry: %s is taken (another car on this machine?): vehicle %s joins it as a "
            "peer and listens on %s; monitors connected there see both",
            ", ".join(cfg.listen), self.vehicle_id, ", ".join(listen),
        )  # fmt: skip
        return session, listen, connect

    def _set_down(self, error: str) -> None:
        error = redact_text(error)
        if self._status != "down" or error != self._last_error:
            log.warning(
                "telemetry down (retrying every %.0f s): %s", self.config.retry_period_s, error
            )
        self._status = "down"
        self._connected = False
        self._last_error = error

    def _check_link(self) -> None:
        link = self._link
        if link is None:
            return
        try:
            info = link.session.info
            self._peers = len(info.peers_zid())
            self._routers = len(info.routers_zid())
        except Exception as exc:
            self._set_down(f"session lost: {exc}")
            self._close_link()
            return
        connected = self._routers > 0 if self.config.mode == "client" else True
        if connected != self._connected and self.config.mode == "client":
            if connected:
                log.info("telemetry: router connected")
            else:
                log.warning("telemetry: no router connected; zenoh keeps reconnecting")
        self._connected = connected

    def _drain(self) -> None:
        with self._lock:
            items = list(self._slots.values())
            self._slots.clear()
            for fifo in self._fifos.values():
                items.extend(fifo)
                fifo.clear()
        link = self._link
        for item in items:
            try:
                payload = encode(item.build())
            except Exception as exc:  # a malformed message must not stop the publisher
                log.error("telemetry: cannot encode a %s message: %r", item.kind, exc)
                self._count_drop("encode_error")
                continue
            self._latest[item.kind] = payload
            if link is None:
                self._count_drop("session_down")
                continue
            try:
                publisher = link.publishers[item.kind]
                # zenoh's source info names this session: a monitor tells two cars configured
                # with one vehicle id apart (guidance.tools.monitor_ids)
                publisher.put(payload, source_info=zenoh.SourceInfo(publisher.id, self._published))
            except Exception as exc:
                self._count_drop("put_error")
                self._last_error = redact_text(f"put failed: {exc}")
                continue
            self._published += 1

    def _close_link(self) -> None:
        link, self._link = self._link, None
        if link is not None:
            _quiet_close(link.session, link.threads)

    # -- zenoh callbacks (zenoh threads) -------------------------------------------------------
    def _on_query(self, query: zenoh.Query) -> None:
        try:
            for kind, payload in list(self._latest.items()):
                key = key_for(self.vehicle_id, kind)
                if zenoh.KeyExpr(key).intersects(query.key_expr):
                    query.reply(
                        key,
                        payload,
                        encoding=zenoh.Encoding.APPLICATION_JSON.with_schema(schema_tag(kind)),
                    )
        except Exception:
            log.exception("telemetry: answering a query failed")

    def _on_goal_sample(self, sample: zenoh.Sample) -> None:
        try:
            if str(sample.key_expr) != goal_key(self.vehicle_id):  # e.g. put on guidance/**
                raise ValueError("sent to a key with wildcards (every car), not to this car")
            goal = parse_goal(sample.payload.to_bytes(), self.config.max_goal_range_m)
        except ValueError as exc:
            self._goals_refused += 1
            if self._goals_refused <= 10 or self._goals_refused % 100 == 0:
                log.warning(
                    "telemetry: remote goal refused (%s); %d refused so far",
                    exc,
                    self._goals_refused,
                )
            return
        self._goals_accepted += 1
        log.warning(
            "telemetry: remote goal accepted from %s: x %.1f m, y %.1f m",
            goal_sender(sample),
            goal[0],
            goal[1],
        )
        callback = self._on_goal
        if callback is None:
            return
        try:
            if self._loop is not None:
                self._loop.call_soon_threadsafe(callback, goal[0], goal[1])
            else:
                callback(goal[0], goal[1])
        except Exception:
            log.exception("telemetry: handing the remote goal to the application failed")
