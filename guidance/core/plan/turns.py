"""Turn detection (pure): completed turns from the estimated heading.

``TurnDetector`` watches the estimated heading against distance travelled and reports each
completed turn, so the navigator records what the driver actually did even when nobody types
it (docs/app.md, "Roadway scene").
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

from guidance.config_tables import rule
from guidance.core.messages import TurnCompleted
from guidance.core.model import wrap_angle
from guidance.core.snapshot_check import integer, number

# --------------------------------------------------------------------------- turn detection


@dataclass(frozen=True, slots=True)
class TurnDetectorConfig:
    min_turn_rad: float = field(default=math.radians(45.0), metadata=rule(positive=True))
    """A heading change at least this large is a turn (an exit, not a lane change or a bend)."""
    window_m: float = field(default=40.0, metadata=rule(positive=True))
    """The change is measured over at most this much travel (a corner takes 10-25 m)."""
    settle_m: float = field(default=8.0, metadata=rule(positive=True))
    """The turn is complete once the heading has been steady over this much travel..."""
    settle_tol_rad: float = field(default=math.radians(8.0), metadata=rule(positive=True))
    """...within this tolerance."""


class TurnDetector:
    """Completed turns from the estimated heading against distance travelled (pure, no clock).

    ``update`` takes the estimate after each odometry step. Headings are unwrapped, so a
    U-turn is reported as about +-pi. After a report the window restarts, so one corner gives
    one report.
    """

    def __init__(self, config: TurnDetectorConfig | None = None) -> None:
        self.config = config or TurnDetectorConfig()
        self._samples: deque[tuple[float, float]] = deque()  # (odometer m, unwrapped heading)
        self._last_raw: float | None = None
        self._unwrapped = 0.0
        self.turns = 0

    def reset(self) -> None:
        self._samples.clear()
        self._last_raw = None

    def update(self, t_s: float, heading_rad: float, odometer_m: float) -> TurnCompleted | None:
        if self._last_raw is None:
            self._unwrapped = heading_rad
        else:
            self._unwrapped += wrap_angle(heading_rad - self._last_raw)
        self._last_raw = heading_rad
        cfg = self.config
        s = self._samples
        if s and odometer_m - s[-1][0] < 0.5:  # sample every half metre of travel
            return None
        s.append((odometer_m, self._unwrapped))
        while len(s) > 2 and odometer_m - s[1][0] >= cfg.window_m:
            s.popleft()
        change = self._unwrapped - s[0][1]
        if abs(change) < cfg.min_turn_rad:
            return None
        # Steady over the last settle_m?
        lo = hi = self._unwrapped
        steady_from = None
        for odo, h in reversed(s):
            lo, hi = min(lo, h), max(hi, h)
            if hi - lo > cfg.settle_tol_rad:
                break
            steady_from = odo
        if steady_from is None or odometer_m - steady_from < cfg.settle_m:
            return None
        self.turns += 1
        s.clear()
        s.append((odometer_m, self._unwrapped))
        return TurnCompleted(t_s, change, source="detected")

    def snapshot(self) -> dict[str, object]:
        return {
            "samples": [list(p) for p in self._samples],
            "last_raw": self._last_raw,
            "unwrapped": self._unwrapped,
            "turns": self.turns,
        }

    def restore(self, snap: dict[str, object]) -> None:
        samples = snap.get("samples", [])
        assert isinstance(samples, list)
        self._samples = deque((float(a), float(b)) for a, b in samples)
        last = snap.get("last_raw")
        self._last_raw = None if last is None else number(last, "turns.last_raw")
        self._unwrapped = number(snap.get("unwrapped", 0.0), "turns.unwrapped")
        self.turns = integer(snap.get("turns", 0), "turns.turns")
