"""What the second stage needs (``PlannerConfig``), as ``LocalizerConfig`` is the first's.

The car's settings are one ``PipelineConfig`` (the config file, the session record and the
checkpoint's identity read it, with each field's rule written there once);
``guidance.core.pipeline_config.planner_config`` takes the planner's part of it, in one place.
Nothing here knows the filter: the two numbers of the estimator's the planner judges the
estimate by (when it is lost, how good the compass is for the chance) are copied in as numbers.
"""

from __future__ import annotations

from dataclasses import dataclass

from guidance.core.messages import Landmark
from guidance.core.plan.chance import ChanceSettings
from guidance.core.plan.navigator import NavigatorConfig
from guidance.core.plan.turns import TurnDetectorConfig
from guidance.core.speech import Units


@dataclass(frozen=True, slots=True)
class PlannerConfig:
    """The navigator, the goal and the landmarks, the turn detector, what is said and when.
    No defaults: every value is the car's (``PipelineConfig``, where each field's meaning,
    default and rule are written once; ``planner_config`` copies them by name)."""

    navigator: NavigatorConfig
    start_xy_m: tuple[float, float]
    goal_xy_m: tuple[float, float] | None
    """None: no goal (yet). The planner still publishes the state and says the uncertainty
    and the loss, but makes no decision, no chance and no arrival until a ``GoalUpdate``."""
    landmarks: tuple[Landmark, ...]
    lost_major_axis_m: float
    """The estimator's: lost past this 2-sigma major axis."""
    compass_two_sigma_deg: float | None
    """The estimator's compass noise (None: no compass): the chance table's compass slice."""
    units: Units
    state_period_s: float
    turn_detector: TurnDetectorConfig
    straight_after_m: float
    uncertain_warn_m: float
    stop_at_arrival: bool
    relocalise: bool
    start_unknown: bool
    chance: ChanceSettings
