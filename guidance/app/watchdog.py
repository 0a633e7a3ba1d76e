"""systemd notifications from the app: READY=1, STATUS=..., WATCHDOG=1 while the loop is on time.

systemd/guidance.service runs the app as ``Type=notify`` with ``WatchdogSec=``:
systemd restarts it when ``READY=1`` never comes or when ``WATCHDOG=1`` pings
stop for longer than ``WatchdogSec``. The real-time loop calls ``tick(lag_s)``
every iteration; a ping goes out at most every half watchdog period (the
rate sd_watchdog_enabled(3) recommends) and only while the loop is on time,
so a loop that keeps lagging is restarted rather than kept alive.

Outside systemd (``NOTIFY_SOCKET`` unset) every method is a no-op. Messages
go through the ``sdnotify`` package; a send failure is logged once, and so is
the recovery, and never raised into the loop.
"""

from __future__ import annotations

import logging
import math
import os
import time
from collections.abc import Callable

import sdnotify

log = logging.getLogger(__name__)

DEFAULT_MAX_LAG_S = 0.5
"""A loop iteration later than this behind its deadline withholds the watchdog ping."""


def watchdog_interval_s(environ: dict[str, str] | None = None) -> float | None:
    """The watchdog period systemd set for this process (``WATCHDOG_USEC``), or None.

    Like sd_watchdog_enabled(3): ignored when ``WATCHDOG_PID`` names another process.
    """
    env = os.environ if environ is None else environ
    pid = env.get("WATCHDOG_PID")
    if pid and pid.strip() != str(os.getpid()):
        return None
    try:
        usec = int(env.get("WATCHDOG_USEC", ""))
    except ValueError:
        return None
    return usec / 1e6 if usec > 0 else None


class SystemdNotifier:
    """Tells systemd the app is ready, alive (from the loop) and what it is doing.

    ``clock`` is wall-clock monotonic time: the watchdog guards real time even
    when the simulation runs accelerated.
    """

    def __init__(
        self,
        *,
        max_lag_s: float = DEFAULT_MAX_LAG_S,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.max_lag_s = max_lag_s
        self._clock = clock
        self._last_ping_s = -math.inf
        self._late = False
        self._send_failed = False
        self._last_status: str | None = None
        self.interval_s: float | None = None
        self.dropped = 0
        """Messages that could not be sent (socket gone, or its queue full)."""
        self._notifier: sdnotify.SystemdNotifier | None = None
        address = os.environ.get("NOTIFY_SOCKET")
        if not address:
            return
        try:
            self._notifier = sdnotify.SystemdNotifier(debug=True)
        except Exception as e:
            log.warning("cannot reach systemd at NOTIFY_SOCKET=%s (%s); not notifying", address, e)
            return
        sock = getattr(self._notifier, "socket", None)
        if sock is not None:
            # A datagram socket blocks its sender while the receiver's queue is full (systemd
            # busy, or a test that stopped reading): that would stall the event loop, which
            # calls us. Non-blocking, such a message fails, is counted and logged once.
            sock.setblocking(False)
        self.interval_s = watchdog_interval_s()

    @property
    def enabled(self) -> bool:
        """True when running under systemd with a notify socket."""
        return self._notifier is not None

    @property
    def watchdog_enabled(self) -> bool:
        return self._notifier is not None and self.interval_s is not None

    def ready(self, status: str | None = None) -> None:
        """READY=1 (optionally with a STATUS): devices are open, the loop is starting."""
        self._send("READY=1" if status is None else f"READY=1\nSTATUS={_one_line(status)}")
        if status is not None:
            self._last_status = _one_line(status)

    def status(self, text: str) -> None:
        """STATUS=... shown by ``systemctl status``; sent only when it changes."""
        line = _one_line(text)
        if line != self._last_status:
            self._last_status = line
            self._send(f"STATUS={line}")

    def stopping(self) -> None:
        """STOPPING=1: a clean shutdown has begun (no watchdog restart during it)."""
        self._send("STOPPING=1")

    def tick(self, lag_s: float) -> bool:
        """Call once per loop iteration with its lateness; True when a ping was sent.

        Pings at most every half watchdog period, and only when ``lag_s`` is
        within ``max_lag_s``. Lateness is logged once when it starts and once
        when it ends.
        """
        interval_s = self.interval_s
        if self._notifier is None or interval_s is None:
            return False
        late = not (lag_s <= self.max_lag_s)  # NaN counts as late
        if late != self._late:
            self._late = late
            if late:
                log.warning(
                    "loop %.3f s late (limit %.3f s): withholding watchdog pings",
                    lag_s,
                    self.max_lag_s,
                )
            else:
                log.info("loop on time again: watchdog pings resumed")
        if late:
            return False
        now = self._clock()
        if now - self._last_ping_s < interval_s / 2:
            return False
        self._last_ping_s = now
        return self._send("WATCHDOG=1")

    def _send(self, message: str) -> bool:
        if self._notifier is None:
            return False
        try:
            self._notifier.notify(message)
        except Exception as e:
            self.dropped += 1
            if not self._send_failed:
                self._send_failed = True
                log.warning("sd_notify failed (%s); will keep trying", e)
            return False
        if self._send_failed:
            self._send_failed = False
            log.info("sd_notify works again")
        return True


def _one_line(text: str) -> str:
    """One ASCII line: sdnotify encodes Latin-1 and systemd expects UTF-8; ASCII is both."""
    return " ".join(text.split()).encode("ascii", "replace").decode("ascii")
