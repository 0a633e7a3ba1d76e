"""Announcements (pure): when to say a turn prompt, scaled by speed; whether the heading is
good enough to name it; whether the car arrives before an intersection."""

from __future__ import annotations

import math
from collections.abc import Collection
from dataclasses import dataclass
from typing import Literal

import numpy as np

from guidance.core.model import wrap_angle
from guidance.core.plan.navigator import Decision

ARRIVE_MARGIN_M = 15.0
"""The goal's own intersection is not announced when the car will be told it has arrived at
least this far before it (a spoken distance's tolerance: the oracle's 15 m)."""
WORD_SIGMAS = 3.0
"""A manoeuvre is named only when every turn within this many heading sigmas of the estimate
gets the same name (``speech.manoeuvre_within``): for a Gaussian heading error the name is
then wrong about once in 370 announcements, where 2 sigmas would be once in 22. Exits typed
relative to the car (the co-driver's) and approach roads taken from the scene's exits are
exact and never coarsened."""


def arrives_before(
    goal: tuple[float, float],
    radius_m: float,
    start: tuple[float, float],
    heading_rad: float,
    ahead_m: float,
) -> bool:
    """A road from ``start`` along ``heading_rad`` enters the arrival circle (``radius_m``
    round ``goal``) at least ``ARRIVE_MARGIN_M`` before the intersection ``ahead_m`` along it."""
    dx, dy = goal[0] - start[0], goal[1] - start[1]
    ux, uy = math.cos(heading_rad), math.sin(heading_rad)
    along = dx * ux + dy * uy
    off2 = max(0.0, dx * dx + dy * dy - along * along)
    if off2 > radius_m * radius_m:
        return False  # the road never comes within the radius
    enter = along - math.sqrt(radius_m * radius_m - off2)
    return enter <= max(0.0, ahead_m) - ARRIVE_MARGIN_M


def heading_sd(P: np.ndarray) -> float:
    """The estimate's heading 1-sigma (rad) from its covariance: the words' uncertainty."""
    return math.sqrt(max(0.0, float(P[2, 2])))


def heading_cannot_tell(d: Decision, heading_sd_rad: float) -> bool:
    """The heading is too uncertain to say which exit the car took: within ``WORD_SIGMAS`` of
    it lies the advised exit's boundary with a neighbour (half the angle between them). The
    driver is then taken to have done as told, unless a co-driver reports otherwise: a lost
    car's drifted heading must not drop the intersections reported behind the advised one."""
    h = d.options[d.exit_index].heading_rad
    gaps = [abs(wrap_angle(o.heading_rad - h)) for o in d.options if o.index != d.exit_index]
    return bool(gaps) and WORD_SIGMAS * heading_sd_rad > 0.5 * min(gaps)


def heads_along(heading_rad: float, road_rad: float, heading_sd_rad: float, tol_rad: float) -> bool:
    """A car heading ``heading_rad`` is on a road along ``road_rad``: within the turn
    detector's tolerance ``tol_rad`` or ``WORD_SIGMAS`` of its heading's uncertainty (more
    than that is a turn, not the noise)."""
    return abs(wrap_angle(heading_rad - road_rad)) <= max(tol_rad, WORD_SIGMAS * heading_sd_rad)


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


NOTICE_S = 2.5
"""A driver's perception-reaction time (AASHTO's 2.5 s for stopping sight distance): a first
instruction for an intersection closer than this at the car's speed comes too late to act on
(the car is already in the turn it chose; a decision first made there, e.g. right after a
position found, is held unsaid)."""
NOTICE_MIN_M = 15.0
"""Nor closer than this at any speed: a turn begins about two town-corner radii (7 m: the
corner of ``localize.odometry_gap.GAP_YAW_RATE_RADPS``) before the intersection's centre,
where the car is already placed for the exit it chose."""


def too_late(distance_m: float, speed_mps: float) -> bool:
    """A first instruction at ``distance_m`` ahead and ``speed_mps`` cannot be acted on."""
    return distance_m < max(NOTICE_MIN_M, NOTICE_S * max(0.0, speed_mps))


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
