"""Checkpoint and learned-parameter states (issue 23, items 6, 13, 14): real files, the real
Pipeline, Checkpointer and ``start_checkpoints`` / ``start_from_learned`` the car runs.

* the car model's learned states (wheel scale, left/right difference, compass bias) are held
  to their physical range when read, by one definition (``guidance.core.localize.state_limits``);
* the checker and the estimator agree on what a valid state is: a car-model car without a
  compass (bias variance 0 by design) is resumed, not refused as "not positive-definite";
* a temporary file a SIGKILL left mid-write is removed at the next start.
"""

from __future__ import annotations

import copy
import json
import logging
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from reliability_helpers import REPO

from guidance.app.build import start_checkpoints
from guidance.app.checkpoint import Checkpointer, trip_identity
from guidance.app.learned_file import load_learned, start_from_learned
from guidance.core import model
from guidance.core.localize import state_limits
from guidance.core.localize.car_model import car_model
from guidance.core.localize.estimator import EstimatorConfig
from guidance.core.localize.learned import LearnedParams
from guidance.core.messages import HeadingFix, WheelOdometry
from guidance.core.pipeline import Pipeline, PipelineConfig
from guidance.core.plan.navigator import Method, NavigatorConfig

GOAL = (800.0, 300.0)


def _pipeline(compass: bool = True) -> Pipeline:
    est = car_model(EstimatorConfig(compass_two_sigma_deg=20.0 if compass else None),
                    calibrated=False)  # fmt: skip
    return Pipeline(
        PipelineConfig(
            estimator=est,
            navigator=NavigatorConfig(method=Method.STRAIGHT_TO_GOAL),
            start_xy_m=(0.0, 0.0),
            goal_xy_m=GOAL,
            start_heading_rad=0.0,
        )
    )


def _drive(p: Pipeline, steps: int = 100) -> Pipeline:
    for i in range(1, steps + 1):
        p.feed(WheelOdometry(i * 0.1, 1.0, 1.0))
        if i % 10 == 0 and p.localizer.estimator.config.compass_two_sigma_deg is not None:
            p.feed(HeadingFix(i * 0.1, 0.0))
    return p


def _write(path: Path, p: Pipeline) -> dict[str, Any]:
    ck = Checkpointer(path, 5.0, trip_identity("car-1", p.config.describe()))
    assert ck.save(10.0, {"pipeline": p.snapshot(), "extra": {}})
    return dict(json.loads(path.read_bytes()))


def _start(path: Path, compass: bool = True) -> tuple[Pipeline, Checkpointer]:
    p = _pipeline(compass)
    ck = start_checkpoints(
        p, str(path), interval_s=5.0, max_age_s=600.0, vehicle_id="car-1", resume=True
    )
    assert ck is not None
    return p, ck


def _aside(path: Path) -> list[str]:
    return sorted(q.name for q in path.parent.iterdir() if ".rejected-" in q.name)


# -- item 6: learned states bounded when read ---------------------------------------------------

HOSTILE_STATES = {
    "scale 1e6 (100 m read as 100,000 km)": (3, 1e6),
    "scale -1 (the estimate frozen)": (3, -1.0),
    "scale 0.5": (3, 0.5),
    "left/right 0.5": (4, 0.5),
    "left/right -1e3": (4, -1e3),
    "compass bias 1e6 rad": (5, 1e6),
    "compass bias 4 rad": (5, 4.0),
    "turn scale 0.5": (6, 0.5),
    "turn scale -1 (every turn undone)": (6, -1.0),
}


@pytest.mark.parametrize("name", list(HOSTILE_STATES))
def test_a_learned_state_outside_its_physical_range_is_not_resumed(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, name: str
) -> None:
    ck = tmp_path / "ck.json"
    doc = _write(ck, _drive(_pipeline()))
    i, value = HOSTILE_STATES[name]
    doc["pipeline"]["x"][i] = value
    ck.write_text(json.dumps(doc))
    with caplog.at_level(logging.WARNING):
        p, writer = _start(ck)
    assert not writer.resumed and len(_aside(ck)) == 1, caplog.text
    assert f"x[{i}]" in caplog.text and "outside" in caplog.text
    x0 = _pipeline().localizer.estimator.x
    assert np.array_equal(p.localizer.estimator.x, x0)  # the priors: nothing of it restored
    _drive(p, 50)  # and the estimate moves as it should: 50 m, not 50,000 km or frozen
    assert 45.0 < p.localizer.estimator.x[0] < 55.0


def test_a_learned_sigma_beyond_its_bound_is_not_resumed(tmp_path: Path) -> None:
    ck = tmp_path / "ck.json"
    doc = _write(ck, _drive(_pipeline()))
    doc["pipeline"]["P"][3][3] = 4.0  # a 1-sigma of 200 % on the wheel scale
    ck.write_text(json.dumps(doc))
    _, writer = _start(ck)
    assert not writer.resumed and len(_aside(ck)) == 1


@pytest.mark.parametrize("scale", [0.099, 0.101, -0.099, -0.101])
def test_the_checkpoint_and_the_learned_file_hold_the_scale_to_the_same_range(
    tmp_path: Path, scale: float
) -> None:
    inside = abs(scale) <= state_limits.MAX_ABS_SCALE
    ck = tmp_path / "ck.json"
    doc = _write(ck, _drive(_pipeline()))
    doc["pipeline"]["x"][3] = scale
    ck.write_text(json.dumps(doc))
    _, writer = _start(ck)
    assert writer.resumed == inside
    learned = tmp_path / "learned.json"
    params = LearnedParams("car-1", 1000.0, 100.0, 0.0, 0.003, 0.0, 0.0001, 10.0, 3.0)
    learned.write_text(json.dumps({**params.to_dict(), "scale": scale}))
    got, why = load_learned(learned, "car-1")
    assert (got is not None) == inside, why


def test_a_learned_file_that_is_dev_zero_or_deeply_nested_is_refused_in_bounded_time(
    tmp_path: Path,
) -> None:
    deep = tmp_path / "deep.json"
    deep.write_text("[" * 100_000 + "]" * 100_000)
    zero = tmp_path / "zero.json"
    zero.symlink_to("/dev/zero")
    code = textwrap.dedent(
        f"""
        import resource, sys
        from pathlib import Path
        resource.setrlimit(resource.RLIMIT_AS, (1 << 31, 1 << 31))
        from guidance.app.learned_file import load_learned
        for name in ("deep.json", "zero.json"):
            params, why = load_learned(Path({str(tmp_path)!r}) / name, "car-1")
            assert params is None and "starting from the priors" in why, why
            print(why)
        """
    )
    res = subprocess.run(
        [sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=60
    )
    assert res.returncode == 0, res.stderr[-2000:]
    assert len(res.stdout.splitlines()) == 2 and "Traceback" not in res.stderr


# -- item 13: the checker and the estimator agree ---------------------------------------------


def test_a_car_without_a_compass_that_crashes_before_its_first_odometry_is_resumed(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    ck = tmp_path / "ck.json"
    before = _pipeline(compass=False)
    est = before.localizer.estimator
    assert est.n == model.N_STATE_CAR and est.P[5, 5] == 0.0  # by design
    assert est.state_problem() is None
    _write(ck, before)
    with caplog.at_level(logging.WARNING):
        p, writer = _start(ck, compass=False)
    assert writer.resumed and not _aside(ck), caplog.text
    assert "not positive-definite" not in caplog.text
    assert np.array_equal(p.localizer.estimator.P, before.localizer.estimator.P)


def test_every_state_the_estimator_reaches_is_one_the_checker_resumes(tmp_path: Path) -> None:
    for compass in (False, True):
        p = _pipeline(compass)
        for steps in (0, 1, 5, 40):
            _drive(p, steps)
            assert p.localizer.estimator.state_problem() is None
            ck = tmp_path / f"ck-{compass}-{steps}.json"
            _write(ck, p)
            _, writer = _start(ck, compass)
            assert writer.resumed, (compass, steps)


def test_a_zero_variance_where_the_prior_is_not_zero_is_still_refused(tmp_path: Path) -> None:
    ck = tmp_path / "ck.json"
    doc = _write(ck, _pipeline(compass=True))
    snap = copy.deepcopy(doc["pipeline"])
    for j in range(6):  # the bias of a car with a compass is never certain
        snap["P"][5][j] = snap["P"][j][5] = 0.0
    doc["pipeline"] = snap
    ck.write_text(json.dumps(doc))
    _, writer = _start(ck, compass=True)
    assert not writer.resumed and len(_aside(ck)) == 1


# -- item 14: a temporary file left by SIGKILL --------------------------------------------------


def _killed_mid_write(ck: Path) -> Path:
    """A real process SIGKILLed while ``write_atomic`` writes ``ck``: its temporary file."""
    code = textwrap.dedent(
        f"""
        from pathlib import Path
        from guidance.app.checkpoint import write_atomic
        data = b"x" * (256 << 20)
        while True:
            write_atomic(Path({str(ck)!r}), data)
        """
    )
    for _ in range(5):
        proc = subprocess.Popen([sys.executable, "-c", code], cwd=REPO)
        tmp = ck.with_name(f".{ck.name}.{proc.pid}.tmp")
        deadline = time.monotonic() + 30.0
        while not tmp.exists() and time.monotonic() < deadline:
            time.sleep(0.001)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        if tmp.exists():
            return tmp
    pytest.fail("never caught the process mid-write")


def test_a_temp_file_left_by_sigkill_is_removed_at_the_next_start(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    ck = tmp_path / "ck.json"
    stale = _killed_mid_write(ck)
    ck.unlink(missing_ok=True)
    sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        busy = ck.with_name(f".{ck.name}.{sleeper.pid}.tmp")  # a live writer's, fresh: kept
        busy.write_bytes(b"{}")
        old = ck.with_name(f".{ck.name}.{sleeper.pid}.tmp.x")  # not write_atomic's: kept
        old.write_bytes(b"{}")
        aged = ck.with_name(f".{ck.name}.{os.getppid()}.tmp")  # alive but an hour old
        aged.write_bytes(b"{}")
        hour_ago = time.time() - 3600
        os.utime(aged, (hour_ago, hour_ago))
        with caplog.at_level(logging.WARNING):
            _start(ck)
        left = sorted(q.name for q in tmp_path.iterdir())
        assert stale.name not in left and aged.name not in left
        assert busy.name in left and old.name in left
        assert "left by an interrupted write" in caplog.text
    finally:
        sleeper.kill()
        sleeper.wait()


def test_a_temp_file_of_the_learned_parameters_is_removed_at_the_next_start(
    tmp_path: Path,
) -> None:
    from guidance.core.localize.localizer import Localizer, LocalizerConfig

    learned = tmp_path / "learned.json"
    stale = _killed_mid_write(learned)
    learned.unlink(missing_ok=True)
    car = LocalizerConfig(car_model(EstimatorConfig(), calibrated=False), start_xy_m=(0.0, 0.0))
    used, note = start_from_learned(Localizer(car), learned, "car-1", 0.0)
    assert not stale.exists() and used is None and "no learned parameters yet" in note
