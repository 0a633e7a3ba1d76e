"""What the two stages of the core hand each other (``../shared/ARCHITECTURE-3.md`` section 5):
the first (``core/localize``) returns a ``LocalizeStep`` for each input, the second
(``core/plan``) reads it and returns ``Outputs``. Values only: the planner never sees the
filter. The ``Input`` union and ``Outputs`` are the pipeline's too (``pipeline_config``
re-exports them); they are defined here, beside the stages, so that ``core/plan`` loads
nothing of ``core/localize`` (``tests/test_layers.py``)."""

from __future__ import annotations

from dataclasses import dataclass, field

from guidance.core.codec import InputMessage
from guidance.core.messages import (
    Decision,
    DeviceStatus,
    EstimateState,
    ExitTaken,
    HealthChange,
    LandmarkFix,
    Prompt,
    TurnCompleted,
)

Input = InputMessage | DeviceStatus
"""Everything the pipeline is fed: the recorded inputs (``codec.InputMessage``) and the drivers'
status flips."""

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


@dataclass(slots=True)
class Outputs:
    """What one input (or tick) caused."""

    accepted: bool = True
    reason: str | None = None
    decisions: list[Decision] = field(default_factory=list)
    prompts: list[Prompt] = field(default_factory=list)
    landmark_updates: list[LandmarkFix] = field(default_factory=list)
    landmark_rejections: list[tuple[LandmarkFix, str]] = field(default_factory=list)
    turns: list[TurnCompleted] = field(default_factory=list)
    exits_taken: list[ExitTaken] = field(default_factory=list)
    health: list[HealthChange] = field(default_factory=list)
    state: EstimateState | None = None
    """The estimate, when a state publication is due (``state_period_s`` of message time)."""
    chance: float | None = None
    """With ``state``: the chance of reaching the goal from here (``guidance.core.plan.chance``;
    None: no goal, or no chance table)."""
    arrived: bool = False
    lost: bool = False
