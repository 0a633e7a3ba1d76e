"""``[vehicle] yaw_source`` (issue 38): the car model with the gyro's two states, or a clear
refusal."""

from __future__ import annotations

from pathlib import Path

import pytest

from guidance.app.config import load_config
from guidance.core.localize import gyro
from guidance.errors import UserError

REPO = Path(__file__).resolve().parents[3]
BERLIN = REPO / "config" / "realdrives" / "smartloc_berlin.toml"


def _car(tmp_path: Path, line: str, model: str = "") -> Path:
    text = BERLIN.read_text().replace("[vehicle]\n", f"[vehicle]\n{line}\n", 1)
    if model:
        text = text.replace("[estimator]\n", f'[estimator]\nmodel = "{model}"\n', 1)
    path = tmp_path / "car.toml"
    path.write_text(text)
    return path


def test_a_gyro_car_gets_the_gyro_states(tmp_path: Path) -> None:
    est = load_config(_car(tmp_path, 'yaw_source = "gyro"'), require_goal=False).pipeline.estimator
    assert est.gyro == gyro.GyroConfig() and est.n_state == gyro.N_STATE_GYRO
    wheels = load_config(BERLIN, require_goal=False).pipeline.estimator
    assert wheels.gyro is None and wheels.n_state == gyro.N_STATE_GYRO - 2
    both = load_config(_car(tmp_path, 'yaw_source = "both"'), require_goal=False)
    assert both.pipeline.estimator.gyro == gyro.GyroConfig(with_wheels=True)
    assert both.pipeline.expected_rates_hz["gyro"] > 0  # its health is judged like the wheels'


@pytest.mark.parametrize(
    ("line", "model", "why"),
    [
        ('yaw_source = "compass"', "", r"yaw_source"),
        ('yaw_source = "both"', "paper", r'needs \[estimator\] model = "car"'),
        ('yaw_source = "gyro"', "paper", r'needs \[estimator\] model = "car"'),
    ],
)
def test_what_is_not_a_yaw_source_is_refused(
    tmp_path: Path, line: str, model: str, why: str
) -> None:
    with pytest.raises(UserError, match=why):
        load_config(_car(tmp_path, line, model), require_goal=False)
