"""The monitor side: ``MonitorClient`` receives telemetry events."""

from __future__ import annotations

import json
import logging
import queue
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import zenoh

from guidance.errors import UserError
from guidance.telemetry.config import TlsConfig, check_endpoint
from guidance.telemetry.keys import (
    _MODES,
    DEFAULT_CONNECT,
    GOAL_SCHEMA,
    KEY_PREFIX,
    goal_key,
    parse_key,
    validate_vehicle_id,
)
from guidance.telemetry.messages import encode
from guidance.telemetry.redact import _zenoh_error_text
from guidance.telemetry.session import _close_at_exit, _quiet_close, open_session, session_config

log = logging.getLogger(__name__)


# -- the monitor side ------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class TelemetryEvent:
    """One thing a monitor saw: a message, or a car appearing ("alive") or vanishing ("gone")."""

    kind: str
    vehicle_id: str
    key: str
    message: Mapping[str, Any] | None
    received_s: float
    """Monitor's monotonic clock when it arrived."""
    late_join: bool = False
    """True when it came from the query of the latest values, not a live publication."""


class MonitorClient:
    """Subscribes to one vehicle or all (``vehicle="all"``): messages and liveliness.

    Events are queued from zenoh threads into a bounded queue read with
    ``get(timeout_s)``; when it is full, new events are dropped and counted.
    """

    def __init__(
        self,
        connect: Sequence[str] = (DEFAULT_CONNECT,),
        *,
        vehicle: str = "all",
        mode: str = "peer",
        zenoh_config: str = "",
        tls: TlsConfig | None = None,
        queue_size: int = 10_000,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        for ep in connect:
            check_endpoint(ep)
        if mode not in _MODES:
            raise UserError(f"mode must be one of {_MODES}, not {mode!r}")
        if vehicle != "all":
            validate_vehicle_id(vehicle)
        self.connect = tuple(connect)
        self.vehicle = vehicle
        self._mode = mode
        self._zenoh_config = zenoh_config
        self._tls = tls
        self._clock = clock
        self._queue: queue.Queue[TelemetryEvent] = queue.Queue(maxsize=queue_size)
        self._session: zenoh.Session | None = None
        self._entities: list[Any] = []
        self.received = 0
        self.dropped = 0
        self.undecodable = 0

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
        self._entities.append(session.declare_subscriber(f"{KEY_PREFIX}/{v}/*", self._on_sample))
        self._entities.append(
            session.liveliness().declare_subscriber(
                f"{KEY_PREFIX}/{v}", self._on_liveliness, history=True
            )
        )
        return self

    def __enter__(self) -> MonitorClient:
        return self.open()

    def __exit__(self, *_exc: object) -> None:
        self.close()

    def close(self) -> None:
        session, self._session = self._session, None
        self._entities.clear()
        if session is not None:
            _quiet_close(session)

    def query_latest(self, vehicle_id: str | None = None, timeout_s: float = 2.0) -> None:
        """Ask the cars (or one) for their latest messages; replies arrive later as events.

        Non-blocking. The monitor asks once when it opens and again when a car
        appears, so a monitor joining late sees each car's state at once.
        """
        session = self._session
        if session is None:
            return
        chunk = self._vehicle_chunk if vehicle_id is None else validate_vehicle_id(vehicle_id)
        try:
            session.get(f"{KEY_PREFIX}/{chunk}/*", self._on_reply, timeout=timeout_s)
        except Exception as exc:
            log.warning("monitor: query for latest values failed: %s", _zenoh_error_text(exc))

    def _on_reply(self, reply: zenoh.Reply) -> None:
        sample = reply.ok
        if sample is not None:
            self._on_sample(sample, late_join=True)

    def get(self, timeout_s: float | None = None) -> TelemetryEvent | None:
        try:
            return self._queue.get(timeout=timeout_s)
        except queue.Empty:
            return None

    def send_goal(self, vehicle_id: str, x_m: float, y_m: float) -> None:
        """Ask a car to drive to a new goal (it obeys only if its config and ACL allow)."""
        session = self._session
        if session is None:
            raise UserError("monitor session is not open")
        validate_vehicle_id(vehicle_id)
        body = {"schema": GOAL_SCHEMA, "x_m": float(x_m), "y_m": float(y_m)}
        session.put(goal_key(vehicle_id), encode(body), encoding=zenoh.Encoding.APPLICATION_JSON)

    def peers(self) -> int:
        session = self._session
        if session is None:
            return 0
        info = session.info
        return len(info.peers_zid()) + len(info.routers_zid())

    def _push(self, event: TelemetryEvent) -> None:
        try:
            self._queue.put_nowait(event)
        except queue.Full:
            self.dropped += 1

    def _on_sample(self, sample: zenoh.Sample, late_join: bool = False) -> None:
        key = str(sample.key_expr)
        parsed = parse_key(key)
        if parsed is None:
            return
        vehicle_id, kind = parsed
        try:
            message = json.loads(sample.payload.to_bytes())
            if not isinstance(message, dict):
                raise ValueError("not an object")
        except ValueError:
            self.undecodable += 1
            return
        self.received += 1
        self._push(TelemetryEvent(kind, vehicle_id, key, message, self._clock(), late_join))

    def _on_liveliness(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        parts = key.split("/")
        if len(parts) != 2 or parts[0] != KEY_PREFIX:
            return
        kind = "alive" if sample.kind == zenoh.SampleKind.PUT else "gone"
        self._push(TelemetryEvent(kind, parts[1], key, None, self._clock()))
