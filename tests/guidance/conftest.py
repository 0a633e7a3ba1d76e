"""Fixtures shared by the guidance tests (the app's and the pure pipeline's)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest

from guidance.core.estimator import EstimatorConfig
from guidance.core.navigator import Method, NavigatorConfig
from guidance.core.pipeline import Pipeline, PipelineConfig


@pytest.fixture
def make_pipeline() -> Callable[..., Pipeline]:
    """``make_pipeline(**overrides)``: a pipeline heading east from the origin to (1000, 400)
    straight to the goal, with a 20-degree compass and odometry expected at 20 Hz; keywords
    replace any ``PipelineConfig`` field."""

    def make(**kw: Any) -> Pipeline:
        base: dict[str, Any] = {
            "estimator": EstimatorConfig(compass_two_sigma_deg=20.0),
            "navigator": NavigatorConfig(method=Method.STRAIGHT_TO_GOAL),
            "start_xy_m": (0.0, 0.0),
            "goal_xy_m": (1000.0, 400.0),
            "start_heading_rad": 0.0,
            "expected_rates_hz": {"odometry": 20.0},
        }
        base.update(kw)
        return Pipeline(PipelineConfig(**base))

    return make
