"""Zenoh session lifecycle: config, open, quiet close at exit, remote goal parsing."""

from __future__ import annotations

import json
import logging
import math
import threading
import time
import weakref
from collections.abc import Collection, Sequence
from pathlib import Path
from typing import Protocol

import zenoh

from guidance.errors import UserError
from guidance.telemetry.config import TlsConfig
from guidance.telemetry.example_passwords import warn_example_passwords
from guidance.telemetry.keys import GOAL_SCHEMA
from guidance.telemetry.redact import _zenoh_error_text

log = logging.getLogger(__name__)


SHARED_MEMORY = False
"""zenoh's shared-memory transport, for sessions built without a config file."""


def session_config(
    *,
    mode: str,
    listen: Sequence[str] = (),
    connect: Sequence[str] = (),
    multicast_scouting: bool = False,
    zenoh_config: str = "",
    tls: TlsConfig | None = None,
) -> zenoh.Config:
    """A zenoh config: optional JSON5 file first, then mode, endpoints, scouting and TLS.

    Without a file, zenoh's shared memory is off (``SHARED_MEMORY``): the car's messages are
    small and cross the network, and with it on every session holds shared-memory file
    descriptors: one process could open only 351 sessions and a router accept about 600 (a
    fleet of 1,000 cars through one router needs it off; docs/telemetry.md). A file decides
    for itself."""
    try:
        if zenoh_config:
            if not Path(zenoh_config).is_file():
                raise UserError(f"zenoh config file not found: {zenoh_config}")
            conf = zenoh.Config.from_file(zenoh_config)
            warn_example_passwords(zenoh_config)
        else:
            conf = zenoh.Config()
            conf.insert_json5("transport/shared_memory/enabled", json.dumps(SHARED_MEMORY))
        conf.insert_json5("mode", json.dumps(mode))
        conf.insert_json5("listen/endpoints", json.dumps(list(listen) if mode != "client" else []))
        conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
        conf.insert_json5("scouting/multicast/enabled", json.dumps(multicast_scouting))
        if tls is not None:
            conf.insert_json5("transport/link/tls", json.dumps(tls.as_zenoh()))
    except zenoh.ZError as exc:
        raise UserError(f"bad zenoh configuration: {_zenoh_error_text(exc)}") from None
    return conf


def open_session(conf: zenoh.Config) -> zenoh.Session:
    """Open a zenoh session; zenoh's failure becomes a one-line ``UserError``."""
    try:
        return zenoh.open(conf)
    except zenoh.ZError as exc:
        raise UserError(f"cannot open zenoh session: {_zenoh_error_text(exc)}") from None


def tcp_reachable(endpoint: str, timeout_s: float = 0.5) -> bool:
    """Whether something accepts TCP connections at a ``tcp/HOST:PORT`` endpoint (False for
    any other kind of endpoint): tells a router that refused a zenoh session (full, or its
    access control) from no router at all."""
    import socket

    if not endpoint.startswith("tcp/"):
        return False
    host, _, port = endpoint[4:].rpartition(":")
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=timeout_s):
            return True
    except (OSError, ValueError):
        return False


def no_router_took(connect: Sequence[str], error: str) -> str:
    """A client whose session did not open, said plainly: which listed routers answer TCP but
    refused the session (a router at its ``max_sessions``, or refusing by access control) and
    which did not answer at all."""
    refused = [ep for ep in connect if tcp_reachable(ep)]
    silent = [ep for ep in connect if ep not in refused]
    parts = []
    if refused:
        parts.append(
            f"{', '.join(refused)} answered but refused the session (full at its max_sessions, "
            "or its access control)"
        )
    if silent:
        parts.append(f"{', '.join(silent)} did not answer")
    return f"no router took this car: {'; '.join(parts)} ({error})"


REMOTE_GOAL_NEEDS = (
    "[telemetry] allow_remote_goal = true needs zenoh access control: a zenoh_config with "
    'access_control enabled and default_permission "deny" (config/zenoh/car-usrpwd-acl.json5 '
    "or car-mtls-acl.json5); without it any process that reaches the car could set its goal"
)


def remote_goal_problem(zenoh_config: str) -> str | None:
    """Why remote goals must not be enabled with this zenoh config file (one line), or None
    when it enables zenoh's access control with a default of deny (docs/telemetry.md)."""
    if not zenoh_config:
        return f"{REMOTE_GOAL_NEEDS} (no zenoh_config is set)"
    try:
        conf = zenoh.Config.from_file(zenoh_config)
        enabled = json.loads(conf.get_json("access_control/enabled"))
        default = json.loads(conf.get_json("access_control/default_permission"))
    except (zenoh.ZError, ValueError) as exc:
        return f"{REMOTE_GOAL_NEEDS} ({zenoh_config}: {_zenoh_error_text(exc)})"
    if enabled is not True:
        return f"{REMOTE_GOAL_NEEDS} ({zenoh_config} does not enable access_control)"
    if default != "deny":
        return f"{REMOTE_GOAL_NEEDS} ({zenoh_config}: default_permission is {default!r})"
    return None


def goal_sender(sample: zenoh.Sample) -> str:
    """Who sent a goal, as far as zenoh says: the sending session's id when the sample
    carries source info (``guidance monitor --send-goal`` sets it; the sender states it, the
    access control decided it may put), else that zenoh does not name the sender."""
    try:
        info = sample.source_info
        if info is not None:
            return f"zenoh session {info.source_id.zid}"
    except Exception as exc:  # an unstable zenoh API: never the reason a goal is lost
        log.debug("telemetry: no source info on a goal: %s", exc)
    return "a sender zenoh does not name (no source info)"


def parse_goal(payload: bytes, max_range_m: float) -> tuple[float, float]:
    """Validate a goal command: a JSON object with finite ``x_m``, ``y_m`` within range."""
    if len(payload) > 4096:
        raise ValueError("payload larger than 4 KiB")
    try:
        obj = json.loads(payload)
    except (UnicodeDecodeError, json.JSONDecodeError):
        raise ValueError("not JSON") from None
    if not isinstance(obj, dict):
        raise ValueError("not a JSON object")
    tag = obj.get("schema", GOAL_SCHEMA)
    if tag != GOAL_SCHEMA:
        raise ValueError(f"schema {tag!r} is not {GOAL_SCHEMA}")
    try:
        x, y = obj["x_m"], obj["y_m"]
    except KeyError:
        raise ValueError("x_m and y_m are required") from None
    if not all(isinstance(v, int | float) and not isinstance(v, bool) for v in (x, y)):
        raise ValueError("x_m and y_m must be numbers")
    x, y = float(x), float(y)
    if not (math.isfinite(x) and math.isfinite(y)):
        raise ValueError("x_m and y_m must be finite")
    if math.hypot(x, y) > max_range_m:
        dist = math.hypot(x, y)
        raise ValueError(f"goal {dist:.0f} m from the start exceeds {max_range_m:.0f} m")
    return x, y


CALLBACK_THREAD_MARK = "pyo3-closure"
"""zenoh-python runs each Python callback (a queryable's, a subscriber's) on a daemon thread
of its own, named after its target: 'Thread-N (pyo3-closure)'."""
CALLBACK_JOIN_S = 1.0
"""How long closing a session waits for its callback threads (they end within a millisecond)."""


def callback_threads(before: Collection[threading.Thread]) -> list[threading.Thread]:
    """zenoh's callback threads started since ``before`` (a ``threading.enumerate()``)."""
    return [t for t in threading.enumerate() if t not in before and CALLBACK_THREAD_MARK in t.name]


def _quiet_close(
    session: zenoh.Session,
    threads: Sequence[threading.Thread] = (),
    timeout_s: float = CALLBACK_JOIN_S,
) -> None:
    """Close ``session``, then wait for its callback ``threads`` to end (issue 23, item 8).

    Closing the session ends them, but each needs the GIL once more to return from zenoh's
    Rust code. A process that finalizes before then kills such a daemon thread with
    ``pthread_exit`` inside a pyo3 trampoline, whose ``catch_unwind`` swallows the forced
    unwind: glibc aborts with "FATAL: exception not rethrown" (SIGABRT after a clean stop)."""
    try:
        session.close()
    except Exception as exc:
        log.debug("closing zenoh session: %s", exc)
    deadline = time.monotonic() + timeout_s
    for t in threads:
        if t is not threading.current_thread():
            t.join(max(0.0, deadline - time.monotonic()))
            if t.is_alive():
                log.debug("zenoh callback thread %s still running after close", t.name)


class Closable(Protocol):
    """What holds a zenoh session open (``Telemetry``, ``MonitorClient``): closed at exit.
    A protocol, so this module imports neither of them (no import circle)."""

    def close(self) -> None: ...


_OPEN: weakref.WeakSet[Closable] = weakref.WeakSet()
_EXIT_HOOK = threading.Lock()
_exit_hook_installed = False


def _close_all_at_exit() -> None:
    for obj in list(_OPEN):
        obj.close()


def _close_at_exit(obj: Closable) -> None:
    """Close forgotten sessions before interpreter shutdown.

    A zenoh session with Python callbacks still declared makes the interpreter
    hang at exit (zenoh-python 1.10, measured here); ``atexit`` runs too late,
    so the hook goes where ``concurrent.futures`` puts its own: before threads
    are joined.
    """
    global _exit_hook_installed
    _OPEN.add(obj)
    with _EXIT_HOOK:
        if _exit_hook_installed:
            return
        register = getattr(threading, "_register_atexit", None)
        if register is not None:
            try:
                register(_close_all_at_exit)
            except RuntimeError:  # already shutting down
                return
        _exit_hook_installed = True
