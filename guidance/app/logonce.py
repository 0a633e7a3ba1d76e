"""The drivers' logging rule for the app too: log once when something starts failing (with its
traceback), count the repeats, and log once when it works again (ARCHITECTURE.md section 2).
A failure that repeats on every message or tick must not flood the journal of a car.
"""

from __future__ import annotations

import logging
from collections import Counter


class LogOnce:
    """Per-``what`` failure state: ``failed(what)`` inside an ``except``, ``ok(what)`` after a
    success; ``counts`` holds the failures of each."""

    def __init__(self, logger: logging.Logger) -> None:
        self._log = logger
        self._failing: set[str] = set()
        self.counts: Counter[str] = Counter()

    def failed(self, what: str) -> None:
        """Call from an ``except`` block: the first failure is logged with its traceback."""
        self.counts[what] += 1
        if what not in self._failing:
            self._failing.add(what)
            self._log.exception("%s failed; continuing (logged once until it works again)", what)

    def ok(self, what: str) -> None:
        if what in self._failing:
            self._failing.discard(what)
            self._log.warning("%s works again after %d failures", what, self.counts[what])
