"""Input health on the message clock (SPEC section 6; openpilot's SubMaster alive/valid), the
drivers' statuses and their flips (``DeviceStatus``). The record itself, for inputs and
components alike, is ``guidance.core.messages.Health``.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field

from guidance.config_tables import rule
from guidance.core import speech
from guidance.core.messages import DeviceStatus, Health, HealthChange, Say, Speech

# ----------------------------------------------------------------------------- health


RATE_WINDOW_S = 2.0
"""Input rates are measured over this much message time."""

VALIDITY_WINDOW = 20
"""A driver judges its last 20 units of data (``drivers.health.HealthTracker``): a fast verdict,
so a 0.8 s storm of bad CAN frames is flagged within a fifth of a second. The pipeline judges
what each source read since it last looked (``App`` reads ``stats()`` once a second)."""
MAX_REJECTED_FRACTION = 0.5
"""More rejected than this makes an input invalid: the drivers' limit and the default of
``[health] max_reject_fraction``, the pipeline's."""


def garbled(read: int, rejected: int, max_fraction: float = MAX_REJECTED_FRACTION) -> str:
    """The one validity judge for garbled input: why ``read`` units of data, ``rejected`` of
    them by the parser, are not usable ("garbled: 60% rejected") when more than
    ``max_fraction`` of them were rejected, else "". Both places that look at an input's
    rejections ask it: the driver over its last ``VALIDITY_WINDOW`` units, the pipeline over the
    counts since it last looked (``HealthMonitor.update_counts``, ``[health]``'s limit); each
    decides how many units are enough to judge."""
    frac = rejected / read if read > 0 else 0.0
    return f"garbled: {frac:.0%} rejected" if frac > max_fraction else ""


@dataclass(frozen=True, slots=True)
class HealthConfig:
    silence_periods: float = field(default=5.0, metadata=rule(positive=True))
    """An input is dead after this many expected periods without a message..."""
    min_timeout_s: float = field(default=1.0, metadata=rule(positive=True))
    """...but never sooner than this."""
    max_reject_fraction: float = field(
        default=MAX_REJECTED_FRACTION, metadata=rule(lo=0.0, hi=1.0)
    )
    """Invalid when more than this fraction of what a source read was rejected recently
    (``garbled``)."""
    min_reads_for_validity: int = field(default=5, metadata=rule(lo=1, hi=1_000_000, read=False))
    """Reads before a source's rejections are judged (not offered in ``[health]``)."""


class HealthMonitor:
    """Alive / valid / rate of each input, evaluated on the message clock (pure)."""

    def __init__(
        self, expected_rates_hz: Mapping[str, float | None], config: HealthConfig | None = None
    ) -> None:
        self.config = config or HealthConfig()
        self.expected = dict(expected_rates_hz)
        self._last: dict[str, float | None] = dict.fromkeys(self.expected)
        self._times: dict[str, deque[float]] = {k: deque() for k in self.expected}
        self._status: dict[str, Health] = {}
        self._counts: dict[str, tuple[int, int]] = {}
        self._valid: dict[str, tuple[bool, str]] = {}
        self._judged: dict[tuple[str, str], tuple[bool, str]] = {}
        self._device: dict[str, Health] = {}
        self._start: float | None = None

    def observe(self, name: str, t_s: float) -> None:
        if name not in self.expected:
            return
        if self._start is None:
            self._start = t_s
        self._last[name] = t_s
        q = self._times[name]
        q.append(t_s)
        while q and q[0] < t_s - RATE_WINDOW_S:
            q.popleft()

    def update_counts(self, name: str, read: int, rejected: int) -> None:
        """Cumulative counts from the source (``stats()``): validity from what was read since
        the last counts (``garbled``, when at least ``min_reads_for_validity`` were)."""
        if name not in self.expected:
            return
        prev_read, prev_rej = self._counts.get(name, (0, 0))
        self._counts[name] = (read, rejected)
        d_read, d_rej = read - prev_read, rejected - prev_rej
        if d_read < self.config.min_reads_for_validity:
            return
        why = garbled(d_read, d_rej, self.config.max_reject_fraction)
        self._valid[name] = (not why, why)

    def report(self, status: DeviceStatus) -> bool:
        """A driver's status flip; returns True when the input just went bad by the driver's
        own account (its warning sentence is then what the driver hears)."""
        name, h = status.input, status.health
        if name not in self.expected:
            return False
        was_bad = self.device_status(name) in BAD_STATUSES
        self._device[name] = h
        return h.status in BAD_STATUSES and not was_bad

    def device_status(self, name: str) -> str:
        """The last status the input's driver reported ("ok" when it never did)."""
        device = self._device.get(name)
        return "ok" if device is None else device.status

    def judge(self, name: str, ok: bool, why: str = "", aspect: str = "data") -> None:
        """The consumer's verdict on an input (e.g. a compass the filter keeps rejecting, or
        inputs stamped before the estimate): invalid with ``why`` until judged ok again. Each
        ``aspect`` is judged on its own; the input is valid when every aspect is."""
        if name in self.expected:
            self._judged[(name, aspect)] = (ok, "" if ok else why)

    def timeout_s(self, name: str) -> float:
        rate = self.expected.get(name)
        if not rate:
            return math.inf
        return max(self.config.min_timeout_s, self.config.silence_periods / rate)

    def status(self, name: str, t_s: float) -> Health:
        last = self._last.get(name)
        rate = self.expected.get(name)
        q = self._times.get(name, deque())
        window = min(RATE_WINDOW_S, t_s - self._start) if self._start is not None else 0.0
        measured = len(q) / window if window > 0.5 else 0.0
        age = None if last is None else max(0.0, t_s - last)
        starting = False
        if rate is None:  # event-driven input (scene, landmarks): always alive
            alive, detail = True, ""
        elif last is None:
            started = self._start is not None and t_s - self._start > self.timeout_s(name)
            alive, detail = not started, ("silent since start" if started else "")
            starting = not started
        else:
            alive = age is not None and age <= self.timeout_s(name)
            detail = "" if alive else f"silent for {age:.1f} s"
        valid, why = self._valid.get(name, (True, ""))
        if not valid:
            detail = f"{detail}; {why}" if detail else why
        device = self._device.get(name)
        device_bad = device is not None and device.status in ("disconnected", "invalid")
        if device is not None and device_bad:  # the driver knows better than the clock
            alive = alive and device.status != "disconnected"
            valid = False
            what = f"{device.status}: {device.detail}" if device.detail else device.status
            detail = f"{detail}; {what}" if detail else what
        for (judged_name, _aspect), (judged, why) in self._judged.items():
            if judged_name == name and not judged:
                valid = False
                detail = f"{detail}; {why}" if detail else why
        if device is not None and device_bad:
            status = device.status
        else:
            status = "silent" if not alive else "invalid" if not valid else "ok"
            if status == "ok" and starting:
                status = "starting"  # in its grace period: nothing received yet
        bad = status in BAD_STATUSES  # the sentence the driver hears, for the health message
        warning = speech.words(Say(Speech.SENSOR, input=name, status=status)) if bad else ""
        counts = self._counts.get(name)
        counters = {} if counts is None else {"read": counts[0], "rejected": counts[1]}
        return Health(
            name,
            status,
            alive,
            valid,
            age,
            detail,
            warning,
            counters=counters,
            rate_hz=measured,
            expected_rate_hz=rate,
        )

    def evaluate(self, t_s: float) -> list[HealthChange]:
        """Statuses whose alive/valid flags flipped since the last evaluation."""
        if self._start is None:  # the clock starts at the first message or tick
            self._start = t_s
        changes = []
        for name in self.expected:
            st = self.status(name, t_s)
            old = self._status.get(name)
            self._status[name] = st
            if old is None:
                if not (st.alive and st.valid):
                    changes.append(HealthChange(t_s, st))
            elif (old.alive, old.valid) != (st.alive, st.valid):
                changes.append(HealthChange(t_s, st))
        return changes

    def statuses(self, t_s: float) -> dict[str, Health]:
        return {name: self.status(name, t_s) for name in self.expected}


STATUSES = ("starting", "ok", "silent", "disconnected", "invalid", "ended", "stopped")
"""'starting': started, nothing yet and not overdue; 'silent': no data for ``stale_after_s``;
'disconnected': the device cannot be opened or was lost; 'invalid': data arrives but too much of
it is rejected; 'ended': a recorded source (file) reached its end; 'stopped': not running."""
BAD_STATUSES = frozenset({"silent", "disconnected", "invalid"})

UNUSABLE = "unusable"
"""Marks a status detail that says the consumer cannot use the input's data."""


class CompassJudge:
    """Is the compass usable? The fraction of its readings the filter rejected, over a window
    of message time (issue 12: a real, uncalibrated compass was rejected 99-100 % of the time
    while its health stayed alive and valid).

    Unusable when more than ``on_fraction`` of the readings of the last ``window_s`` were
    rejected (and the window is full); usable again when fewer than ``off_fraction`` were.
    The reason names the dominant rejection: ``interference`` (the NIS detector), ``gated`` (the
    chi-square gate), or ``uncalibrated`` when the car has no compass calibration at all.
    """

    def __init__(
        self,
        window_s: float = 20.0,
        *,
        calibrated: bool = False,
        on_fraction: float = 0.8,
        off_fraction: float = 0.5,
    ) -> None:
        self.window_s = window_s
        self.calibrated = calibrated
        self.on_fraction = on_fraction
        self.off_fraction = off_fraction
        self._log: deque[tuple[float, bool, str]] = deque()
        self.unusable = False
        self.reason = ""

    def add(self, t_s: float, accepted: bool, reason: str | None) -> None:
        self._log.append((t_s, accepted, reason or ""))
        while self._log and self._log[0][0] < t_s - self.window_s:
            self._log.popleft()

    def verdict(self, t_s: float) -> tuple[bool, str]:
        """(usable, why) after the readings so far."""
        log_ = self._log
        if len(log_) < 5 or t_s - log_[0][0] < 0.9 * self.window_s:
            return (not self.unusable, self._why())
        rejected = [r for _, ok, r in log_ if not ok]
        frac = len(rejected) / len(log_)
        if not self.unusable and frac > self.on_fraction:
            self.unusable = True
            top = max(set(rejected), key=rejected.count)
            if not self.calibrated:
                self.reason = "uncalibrated"
            elif top == "magnetic_interference":
                self.reason = "interference"
            else:
                self.reason = "gated"
        elif self.unusable and frac < self.off_fraction:
            self.unusable = False
            self.reason = ""
        return (not self.unusable, self._why())

    def _why(self) -> str:
        return f"{UNUSABLE}: {self.reason}" if self.unusable else ""
