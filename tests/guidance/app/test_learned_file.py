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
from guidance.core.estimator import EstimatorConfig, PoseEstimator, car_model
from guidance.core.learned import LearnedParams

REPO = Path(__file__).resolve().parents[3]
GOOD = LearnedParams("car1", 1000.0, 2500.0, -0.011, 0.003, 0.0002, 0.0001, 38.0, 3.0)


def test_saved_and_read_back(tmp_path: Path) -> None:
    path = tmp_path / "learned.json"
    assert load_learned(path, "car1") == (None, None)
    save_learned(path, GOOD)
    assert load_learned(path, "car1") == (GOOD, None)
    est = PoseEstimator(car_model(EstimatorConfig(), calibrated=False), 0.0, 0.0, 0.0)
    used, note = start_from_learned(est, path, "car1", 1000.0 + 86400.0)
    assert used is not None and "starting from learned parameters (2.5 km, 1.0 days old)" in note
    assert est.x[3] == pytest.approx(-0.011)


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
    est = PoseEstimator(car_model(EstimatorConfig(), calibrated=False), 0.0, 0.0, 0.0)
    used, _ = start_from_learned(est, path, "car1", 0.0)
    assert used is None and est.x[3] == 0.0  # the priors, untouched


def test_a_sigkill_while_saving_leaves_the_old_file_or_the_new_one(tmp_path: Path) -> None:
    path = tmp_path / "learned.json"
    code = (
        "import sys, itertools\n"
        "from pathlib import Path\n"
        "from guidance.app.learned_file import save_learned\n"
        "from guidance.core.learned import LearnedParams\n"
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
    est = PoseEstimator(car_model(EstimatorConfig(), calibrated=False), 0.0, 0.0, 0.0)
    used, note = start_from_learned(est, path, "car1", 0.0)
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
