"""Compile the core's numba functions before the event loop's clock starts.

numba compiles on first call (seconds on a fresh machine; later runs load the on-disk cache in
well under a second). Done inside the running app, that first call stalls the loop: the lag
warning fires and the drivers report their inputs silent. ``warm_up`` drives a throwaway
pipeline of each noise model through every kind of input once, so every compiled function the
car uses is ready before the first real message.
"""

from __future__ import annotations

import math

import numpy as np

from guidance.core.localize.car_model import car_model
from guidance.core.localize.estimator import EstimatorConfig
from guidance.core.messages import CompassHeading, IntersectionScene, LandmarkFix, WheelOdometry
from guidance.core.plan.navigator import Landmark, NavigatorConfig


def warm_up() -> None:
    """Run one of each input through a paper-model and a car-model pipeline (pure, ~ms warm)."""
    from guidance.core.pipeline import Pipeline, PipelineConfig

    paper = EstimatorConfig()
    car = car_model(paper, calibrated=False)
    for est in (paper, car):
        p = Pipeline(
            PipelineConfig(
                estimator=est,
                navigator=NavigatorConfig(),
                start_xy_m=(0.0, 0.0),
                goal_xy_m=(500.0, 500.0),
                start_heading_rad=0.0,
                landmarks=(Landmark(1, 50.0, 0.0, "warm-up"),),
            )
        )
        p.feed(WheelOdometry(0.1, 1.0, 1.05))
        p.feed(CompassHeading(0.2, 90.0))
        p.feed(LandmarkFix(0.3, 1, 2.0, 0.0, 5.0))
        p.feed(IntersectionScene(0.4, (0.0, math.pi / 2), 30.0))
        nav, P = p.navigator, np.array(p.estimate.covariance)  # evaluate-then-commit (guide)
        nav.evaluate(0.5, (30.0, 0.0), P, (0.0, math.pi / 2), 0.0, (0.0, 0.0))
        nav.commit((30.0, 0.0), P[:2, :2], 0.0)
        p.state()
