"""What the two stages of the core hand each other (``../shared/ARCHITECTURE-3.md`` section 5):
the first (``core/localize``) returns a ``LocalizeStep`` for each input, the second
(``core/plan``) reads it. Values only: the planner never sees the filter."""

from __future__ import annotations

from dataclasses import dataclass, field

from guidance.core.messages import EstimateState

LOST_HYSTERESIS = 0.8
"""Lost once the 2-sigma major axis passes ``lost_major_axis_m``; found again only once it is
back below this fraction of it (the planner says each once; a relocalisation resets while the
axis is above it)."""
RELOCALISED = "relocalised"
"""The reason of an accepted landmark fix that reset the position (a whole-database find while
lost: ``localize.covariance_edits.relocalised``, applied by the estimator)."""


@dataclass(frozen=True, slots=True)
class Move:
    """The estimate moved: an odometry step (``odometry``), or carried on through a gap at the
    last speed (a compass reading in a CAN silence). The planner steps the road ahead with it."""

    t_s: float
    estimate: EstimateState
    odometry: bool
    gap_from_s: float | None = None
    """The odometry resumed after a silence that began then (dead-reckoned through): the
    places ahead may no longer be placed (``Guide.after_gap``)."""


@dataclass(slots=True)
class LocalizeStep:
    """What one input did to the estimate."""

    moves: list[Move] = field(default_factory=list)
    """Every estimate the input produced, in order (an odometry input held back after a gap
    can bring two steps; a compass reading in a silence, the dead reckoning up to it)."""
    estimate: EstimateState | None = None
    """The estimate after the input (``Localizer.handle`` always sets it)."""
    accepted: bool | None = None
    """The filter's verdict on a sensor input; None: not a sensor input (the planner's)."""
    reason: str | None = None
    heading_found: bool = False
    """The first compass reading gave the heading (the heading history before says nothing)."""
    relocalised: bool = False
    """An accepted landmark fix reset the position (a whole-database find while lost)."""
    compass_unusable: bool = False
    """The filter has rejected most of the compass's readings lately (``CompassJudge``)."""
