"""Announcement timing (pure): when to say a turn prompt, scaled by speed."""

from __future__ import annotations

import math
from collections.abc import Collection
from dataclasses import dataclass
from typing import Literal

# --------------------------------------------------------------------- prompt timing

Announcement = Literal["early", "before"]

# Organic Maps, routing/turns_notification_manager.cpp and turns_sound_settings.cpp
# (vehicle, metric): the first notification comes 30 s ahead, clamped to
# 200..2000 m, plus the distance covered while it is spoken; the second when
# the car is within 8 s of the turn, clamped to 35..150 m. No first notification
# when the turn is already within 170 m. OsmAnd's AnnounceTimeDistances agrees:
# "turn in" 22 s ahead (275 m at 45 km/h), "turn now" about 7 s or 45 m ahead.
EARLY_TIME_S = 30.0
EARLY_MIN_M = 200.0
EARLY_MAX_M = 2000.0
BEFORE_TIME_S = 8.0
BEFORE_MIN_M = 35.0
BEFORE_MAX_M = 150.0
EARLY_TOO_CLOSE_M = 170.0


@dataclass(frozen=True, slots=True)
class AnnouncementDistances:
    """Distances to the intersection (m) inside which each announcement is due."""

    early_m: float
    before_m: float
    too_close_for_early_m: float = EARLY_TOO_CLOSE_M


def _clamp(x: float, lo: float, hi: float) -> float:
    return min(max(x, lo), hi)


def _check_speed(speed_mps: float) -> float:
    if not math.isfinite(speed_mps):
        raise ValueError(f"speed must be finite, got {speed_mps}")
    return max(0.0, speed_mps)


def announcement_distances_m(speed_mps: float) -> AnnouncementDistances:
    """Where the early ("In 300 metres, turn left") and just-before ("Turn left") prompts start.

    Both scale with speed so the driver gets about the same time to act; a
    negative speed counts as standstill.
    """
    v = _check_speed(speed_mps)
    before_m = _clamp(BEFORE_TIME_S * v, BEFORE_MIN_M, BEFORE_MAX_M)
    early_m = _clamp(EARLY_TIME_S * v, EARLY_MIN_M, EARLY_MAX_M) + before_m
    return AnnouncementDistances(early_m=early_m, before_m=before_m)


def due_announcements(
    distance_to_intersection_m: float,
    speed_mps: float,
    already_announced: Collection[str],
) -> tuple[Announcement, ...]:
    """Which announcements for the next intersection are due now: (), ("early",) or ("before",).

    The caller adds what it announced to ``already_announced`` and resets it
    after the intersection. "before" supersedes a pending "early" (no double
    prompt), and "early" is skipped when the intersection is already within
    ``EARLY_TOO_CLOSE_M``, as in Organic Maps.
    """
    if not math.isfinite(distance_to_intersection_m):
        raise ValueError(f"distance must be finite, got {distance_to_intersection_m}")
    d = max(0.0, distance_to_intersection_m)
    if "before" in already_announced:
        return ()
    dist = announcement_distances_m(speed_mps)
    if d <= dist.before_m:
        return ("before",)
    if "early" not in already_announced and dist.too_close_for_early_m < d <= dist.early_m:
        return ("early",)
    return ()
