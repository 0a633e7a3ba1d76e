"""The learned-parameters file (guidance/app/learned_file.py): atomic, checked, refused with one
line when damaged or tampered, and the car then starts from its priors."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from guidance.app.learned_file import load_learned, save_learned, start_from_learned
from guidance.core.localize.car_model import car_model
from guidance.core.localize.estimator import EstimatorConfig, PoseEstimator
from guidance.core.localize.learned import LearnedParams
from guidance.core.localize.localizer import Localizer, LocalizerConfig

REPO = Path(__file__).resolve().parents[3]
GOOD = LearnedParams("car1", 1000.0, 2500.0, -0.011, 0.003, 0.0002, 0.0001, 38.0, 3.0)


def _car() -> Localizer:
    """A fresh car-model first stage (no compass card), as the car starts."""
    cfg = car_model(EstimatorConfig(), calibrated=False)
    return Localizer(LocalizerConfig(cfg, start_xy_m=(0.0, 0.0), start_heading_rad=0.0))


def _scale(loc: Localizer) -> float:
    """The wheel scale the first stage starts from (its learned values, read back)."""
    now = loc.learned("car1", 0.0, 0.0)
    assert now is not None
    return now.scale


def test_saved_and_read_back(tmp_path: Path) -> None:
    path = tmp_path / "learned.json"
    assert load_learned(path, "car1") == (None, None)
    save_learned(path, GOOD)
    assert load_learned(path, "car1") == (GOOD, None)
    loc = _car()
    used, note = start_from_learned(loc, path, "car1", 1000.0 + 86400.0)
    assert used is not None and "starting from learned parameters (2.5 km, 1.0 days old)" in note
    assert _scale(loc) == pytest.approx(-0.011)


@pytest.mark.parametrize(
    "damage",
    ["not json {", "[1, 2]", "bad scale", "another car", "truncated", "nan sigma"],
)
def test_a_damaged_or_tampered_file_is_refused_with_one_line(tmp_path: Path, damage: str) -> None:
    path = tmp_path / "learned.json"
    doc = GOOD.to_dict()
    text = {
        "not json {": "not json {",
        "[1, 2]": "[1, 2]",
        "bad scale": json.dumps({**doc, "scale": 0.4}),
        "another car": json.dumps({**doc, "vehicle_id": "car2"}),
        "truncated": json.dumps(doc)[:40],
        "nan sigma": json.dumps({**doc, "scale_sigma": float("nan")}),
    }[damage]
    path.write_text(text)
    params, why = load_learned(path, "car1")
    assert params is None and why is not None and "\n" not in why
    assert "starting from the priors" in why
    loc = _car()
    used, _ = start_from_learned(loc, path, "car1", 0.0)
    assert used is None and _scale(loc) == 0.0  # the priors, untouched


def test_a_sigkill_while_saving_leaves_the_old_file_or_the_new_one(tmp_path: Path) -> None:
    path = tmp_path / "learned.json"
    code = (
        "import sys, itertools\n"
        "from pathlib import Path\n"
        "from guidance.app.learned_file import save_learned\n"
        "from guidance.core.localize.learned import LearnedParams\n"
        "p = Path(sys.argv[1])\n"
        "for k in itertools.count():\n"
        "    save_learned(p, LearnedParams('car1', float(k), 1.0, 0.01, 0.003, 0.0, 1e-4))\n"
    )
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    for delay in (0.005, 0.013, 0.021, 0.037):
        path.unlink(missing_ok=True)
        proc = subprocess.Popen([sys.executable, "-c", code, str(path)], env=env)
        deadline = time.monotonic() + 60.0
        while not path.exists() and time.monotonic() < deadline:  # saving, again and again
            time.sleep(0.001)
        time.sleep(delay)
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        params, why = load_learned(path, "car1")
        assert why is None and params is not None  # a whole file, never half of one


@pytest.mark.parametrize(
    "key",
    ["saved_unix_s", "distance_m", "scale", "scale_sigma", "diff", "diff_sigma",
     "compass_bias_deg", "compass_bias_sigma_deg", "turn_scale", "turn_scale_sigma"],
)  # fmt: skip
@pytest.mark.parametrize("huge", [10**400, -(10**400)])
def test_a_number_too_large_for_a_float_is_refused_with_one_line(
    tmp_path: Path, key: str, huge: int
) -> None:
    """Issue 40 (high): a 400-digit integer in any numeric field made ``guidance run`` exit
    "internal error: OverflowError" at every start (a systemd restart loop)."""
    path = tmp_path / "learned.json"
    doc = {**GOOD.to_dict(), "turn_scale": 0.001, "turn_scale_sigma": 0.01}
    path.write_text(json.dumps({**doc, key: huge}))
    params, why = load_learned(path, "car1")
    assert params is None and why is not None and "\n" not in why and key in why
    used, note = start_from_learned(_car(), path, "car1", 0.0)
    assert used is None and "starting from the priors" in note


def test_the_lock_is_exclusive_across_processes_and_dies_with_its_holder(tmp_path: Path) -> None:
    """Issue 40 (high): the car holds ``<file>.lock`` while it drives; a second taker is refused
    with the holder's pid; a SIGKILLed holder leaves nothing locked."""
    from guidance.app.learned_file import LearnedBusy, LearnedLock

    path = tmp_path / "learned.json"
    code = (
        "import sys, time\n"
        "from pathlib import Path\n"
        "from guidance.app.learned_file import LearnedLock\n"
        "lock = LearnedLock.take(Path(sys.argv[1]))\n"
        "print('held', flush=True)\n"
        "time.sleep(60)\n"
    )
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen(
        [sys.executable, "-c", code, str(path)], env=env, stdout=subprocess.PIPE, text=True
    )
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == "held"
        with pytest.raises(LearnedBusy, match=rf"in use by a running car \(pid {proc.pid}\)"):
            LearnedLock.take(path)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    with LearnedLock.take(path) as lock:  # free again: the kernel dropped the dead one's lock
        with pytest.raises(LearnedBusy):
            LearnedLock.take(path)  # exclusive within one process too
        assert lock.path == path
    LearnedLock.take(path).release()


# -- issue 40, defect 3 and the lows: physical floors, a save time in the future, resume ----------
@pytest.mark.parametrize(
    ("key", "value"),
    [
        ("scale_sigma", 1e-6),  # 100 m known to 0.1 mm: the hand edit of the issue
        ("diff_sigma", 1e-8),
        ("compass_bias_sigma_deg", 1e-6),
        ("turn_scale_sigma", 1e-6),
    ],
)
def test_a_sigma_below_what_any_drive_can_teach_is_refused(
    tmp_path: Path, key: str, value: float
) -> None:
    """Defect 3: the old bounds let a file claim sigmas about 1,000 times below anything a
    drive reaches (``guidance.core.localize.state_limits.MIN_*``, with their reasons)."""
    path = tmp_path / "learned.json"
    doc = GOOD.to_dict() | {"compass_bias_deg": 2.0, "compass_bias_sigma_deg": 3.0}
    doc |= {"turn_scale": 0.01, "turn_scale_sigma": 0.002}
    path.write_text(json.dumps(doc))
    assert load_learned(path, "car1")[0] is not None  # the same file with honest sigmas
    path.write_text(json.dumps(doc | {key: value}))
    params, why = load_learned(path, "car1")
    assert params is None and why is not None and key in why and "outside" in why


def test_the_car_never_saves_a_sigma_below_the_floor_so_it_never_refuses_its_own_file(
    tmp_path: Path,
) -> None:
    from guidance.core import model
    from guidance.core.localize import state_limits

    est = PoseEstimator(car_model(EstimatorConfig(), calibrated=False), 0.0, 0.0, 0.0)
    P = est.P
    for i in (model.STATE_SCALE, model.STATE_DIFF, model.STATE_BIAS, model.STATE_TURN):
        P[i, :] = 0.0
        P[:, i] = 0.0
        P[i, i] = 1e-20  # a filter that believes it knows everything
    est.set_state(est.x, P)
    params = LearnedParams.from_estimator(est, "car1", 1000.0, 10.0)
    assert params is not None
    assert params.scale_sigma == state_limits.MIN_SCALE_SIGMA
    assert params.diff_sigma == state_limits.MIN_DIFF_SIGMA
    assert params.turn_scale_sigma == state_limits.MIN_TURN_SIGMA
    path = tmp_path / "learned.json"
    save_learned(path, params)
    assert load_learned(path, "car1") == (params, None)


def test_a_save_time_in_the_future_is_refused_by_the_car_not_by_a_replay(tmp_path: Path) -> None:
    """Defect 3: a file saved ten days after the car's clock would never be widened (its age
    taken as zero); the car refuses it, a replay (its clock is the log's) takes it."""
    path = tmp_path / "learned.json"
    now = time.time()
    save_learned(path, LearnedParams("car1", now + 10 * 86400.0, 2500.0, -0.011, 0.003, 0.0, 1e-4))
    loc = _car()
    used, note = start_from_learned(loc, path, "car1", now)
    assert used is None and "saved 10.0 days after this clock" in note and _scale(loc) == 0.0
    used, _ = start_from_learned(loc, path, "car1", now, wall_clock=False)
    assert used is not None and _scale(loc) == pytest.approx(-0.011)
    save_learned(path, LearnedParams("car1", now + 3600.0, 2500.0, -0.011, 0.003, 0.0, 1e-4))
    assert start_from_learned(_car(), path, "car1", now)[0] is not None  # a clock an hour off


def test_a_resumed_trip_keeps_the_file_s_distance_and_removes_stale_temps(tmp_path: Path) -> None:
    """Lows: after a crash-resume the learned file's distance counter restarted at the trip's
    odometer (12,000 km became 2.4 m), and temp files a SIGKILL left were not removed."""
    from guidance.app.learned_file import counter_after_resume

    path = tmp_path / "learned.json"
    save_learned(path, LearnedParams("car1", 1000.0, 12_000_000.0, -0.011, 0.003, 0.0, 1e-4))
    stale = tmp_path / ".learned.json.999999999.tmp"  # a pid that is not running
    stale.write_text("{")
    before = counter_after_resume(path, "car1", odometer_m=2400.0)
    assert before is not None and before.distance_m == 12_000_000.0 - 2400.0
    assert not stale.exists()
    assert counter_after_resume(tmp_path / "none.json", "car1", 10.0) is None
