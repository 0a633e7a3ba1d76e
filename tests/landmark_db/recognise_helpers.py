"""What the recogniser tests share (test_recognise, test_worker, test_search): a gentle camera
and an estimate at a place."""

from __future__ import annotations

from guidance.core.messages import Ellipse, EstimateState
from hal_sim.sim_camera import SimCameraConfig

COV = ((15.0**2, 0.0), (0.0, 15.0**2))
EASY = SimCameraConfig(
    perspective=0.08, occlusion=(0.0, 0.1), blur_sigma_px=(0.0, 0.8), motion_blur_px=(0.0, 1.0)
)
"""A gentle camera: these tests check the pipeline's logic, not its detection rate."""


def state_at(x: float, y: float, cov: tuple = COV, t: float = 0.0) -> EstimateState:
    """An estimate at (x, y) with position covariance ``cov`` (heading east, 0.1 rad)."""
    c = ((cov[0][0], cov[0][1], 0.0), (cov[1][0], cov[1][1], 0.0), (0.0, 0.0, 0.01))
    return EstimateState(t, x, y, 0.0, c, Ellipse(30.0, 30.0, 0.0, 60.0), False, True)
