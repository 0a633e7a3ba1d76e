"""What the pipeline takes and gives: which health record each input feeds, ``PipelineConfig``
(built from the TOML config by ``guidance.app.config``, or by the simulator) and the second
stage's part of it (``planner_config``); the ``Input`` union and ``Outputs`` (what one input
caused), defined in ``guidance.core.stages``, are named here too."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields

from guidance.config_tables import plain, rule
from guidance.core.health import HealthConfig
from guidance.core.localize.estimator_config import EstimatorConfig
from guidance.core.messages import (
    Approach,
    CancelReport,
    CompassHeading,
    GoalUpdate,
    HeadingFix,
    IntersectionScene,
    LandmarkFix,
    TurnCompleted,
    WheelOdometry,
    YawRate,
)
from guidance.core.plan.chance import ChanceSettings
from guidance.core.plan.config import PlannerConfig
from guidance.core.plan.navigator import Landmark, NavigatorConfig
from guidance.core.plan.turns import TurnDetectorConfig
from guidance.core.speech import Units
from guidance.core.stages import Input as Input  # the pipeline's, defined beside the stages
from guidance.core.stages import Outputs as Outputs

INPUT_KINDS: dict[type, str] = {
    WheelOdometry: "odometry",
    YawRate: "gyro",
    CompassHeading: "compass",
    HeadingFix: "compass",
    LandmarkFix: "landmark",
    IntersectionScene: "scene",
    TurnCompleted: "scene",
    CancelReport: "scene",
    GoalUpdate: "goal",
    Approach: "scene",
}
"""Which health record an input type feeds."""


COORDINATE = rule(lo=-1e8, hi=1e8)
"""Local metres: a point farther than 100,000 km is damage, not a place."""
MIN_STATE_PERIOD_S = 1e-3
MAX_STATE_PERIOD_S = 60.0
"""The state is published between 1000 times a second and once a minute."""
_NAVIGATION_M = rule(positive=True, table="navigation")


@dataclass(frozen=True, slots=True)
class PipelineConfig:
    """Everything the core needs; built from the TOML config (``guidance.app.config``) or the
    sim. Each field's rule is written here once: the config file (``table``/``key``: where it
    offers the field), the session record and the checkpoint's identity read it alike."""

    estimator: EstimatorConfig
    navigator: NavigatorConfig
    start_xy_m: tuple[float, float] = field(metadata=COORDINATE)
    goal_xy_m: tuple[float, float] | None = field(default=None, metadata=COORDINATE)
    """None: no goal (``[goal]`` left out: a raw-log replay, a bench). The car still estimates,
    publishes and warns; it makes no decision, no chance and no arrival until a ``GoalUpdate``."""
    start_heading_rad: float | None = field(default=None, metadata=rule(lo=-7.0, hi=7.0))
    """None: taken from the first compass reading."""
    landmarks: tuple[Landmark, ...] = field(default=(), metadata=rule(max_items=100_000))
    declination_deg: float = field(default=0.0, metadata=rule(lo=-180.0, hi=180.0, table="compass"))
    mounting_offset_deg: float = field(
        default=0.0, metadata=rule(lo=-180.0, hi=180.0, table="compass")
    )
    compass_deviation_deg: tuple[float, ...] = field(
        default=(),
        metadata=rule(lo=-90.0, hi=90.0, max_items=5, table="compass", key="deviation_deg"),
    )
    """The compass deviation card A..E (``guidance calibrate``); empty: not calibrated."""
    compass_unusable_after_s: float = field(
        default=20.0, metadata=rule(lo=0.1, hi=1e6, table="compass", key="unusable_after_s")
    )
    """A compass whose readings are mostly rejected for this long is reported unusable."""
    units: Units = field(default=Units.METRIC, metadata=rule(table="navigation"))
    state_period_s: float = field(
        default=0.1, metadata=rule(lo=MIN_STATE_PERIOD_S, hi=MAX_STATE_PERIOD_S)
    )
    """Seconds between state publications (``[loop] state_rate_hz``)."""
    expected_rates_hz: Mapping[str, float | None] = field(
        default_factory=dict, metadata=rule(positive=True, hi=1e4)
    )
    """Each input's expected rate, Hz (the device tables say; ``None`` or absent: no
    expectation, so it is never reported silent)."""
    health: HealthConfig = field(default_factory=HealthConfig)
    turn_detector: TurnDetectorConfig = field(default_factory=TurnDetectorConfig)
    straight_after_m: float = field(default=25.0, metadata=_NAVIGATION_M)
    """A decision with no turn reported this far past the intersection was 'straight on'."""
    uncertain_warn_m: float = field(default=50.0, metadata=_NAVIGATION_M)
    """Say "position uncertain" when the major axis grows past this."""
    stop_at_arrival: bool = field(default=False, metadata=rule(table="navigation"))
    """Arrival ends guidance (a simulated trip); otherwise the car waits for a new goal. Being
    lost ends it too, unless the car can find itself again (``relocalise``)."""
    relocalise: bool = False
    """The car has a camera and a landmark database, whose whole-database search runs while
    it is lost: being lost does not end a simulated trip; a place found resets the position
    (``LandmarkFix.relocalised``) and guidance replans from there."""
    start_unknown: bool = False
    """``[start]`` gives no position ("start anywhere"): the car starts lost, says so, searches
    the whole landmark database (``relocalise`` is required) and guides nobody until a place
    is found; ``start_xy_m`` is then only where the estimate waits, ``UNKNOWN_START_SIGMA_M``
    wide."""
    resume_gap_inflation: bool = True
    """After an odometry silence, inflate the position by the distance possibly driven."""
    chance: ChanceSettings = field(default_factory=ChanceSettings)
    """The live chance of reaching the goal (``guidance.core.plan.chance``)."""

    def describe(self) -> dict[str, object]:
        """Plain data for the recording's session record and the checkpoint's trip identity:
        every field (``config_tables.plain``), so ``from_table(PipelineConfig, ...)`` rebuilds
        exactly this car (``guidance.tools.replay_session``)."""
        out: dict[str, object] = plain(self)
        return out


def planner_config(config: PipelineConfig) -> PlannerConfig:
    """The car's settings for the second stage, taken here once: each ``PlannerConfig`` field
    of the same name, and the two numbers of the estimator's it judges the estimate by."""
    own = {f.name for f in fields(PlannerConfig)} - {"lost_major_axis_m", "compass_two_sigma_deg"}
    return PlannerConfig(
        **{name: getattr(config, name) for name in own},
        lost_major_axis_m=config.estimator.lost_major_axis_m,
        compass_two_sigma_deg=config.estimator.compass_two_sigma_deg,
    )
