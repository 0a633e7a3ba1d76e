"""A checked checkpoint (issue 14, item 3): real files, the real Pipeline and Checkpointer.

A checkpoint names the vehicle, the trip and the software version; a clean stop marks it
finished; a damaged, invalid or foreign one is moved aside, logged and ignored, and every value
of the state is checked before anything is restored. A write on a full disk leaves no temp file.
"""

from __future__ import annotations

import copy
import json
import logging
import math
import subprocess
import sys
import textwrap
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from reliability_helpers import REPO

from guidance.app.build import start_checkpoints
from guidance.app.checkpoint import Checkpointer, load_checkpoint, trip_identity
from guidance.core.localize.estimator import EstimatorConfig
from guidance.core.messages import HeadingFix, WheelOdometry
from guidance.core.pipeline import Pipeline, PipelineConfig
from guidance.core.plan.navigator import Method, NavigatorConfig

GOAL = (800.0, 300.0)


def _pipeline(goal: tuple[float, float] | None = GOAL) -> Pipeline:
    return Pipeline(
        PipelineConfig(
            estimator=EstimatorConfig(compass_two_sigma_deg=20.0),
            navigator=NavigatorConfig(method=Method.STRAIGHT_TO_GOAL),
            start_xy_m=(0.0, 0.0),
            goal_xy_m=goal,
            start_heading_rad=0.0,
        )
    )


def _driven(goal: tuple[float, float] | None = GOAL) -> Pipeline:
    """A pipeline that has driven 100 m east, so a resumed state differs from a fresh one."""
    p = _pipeline(goal)
    for i in range(1, 101):
        p.feed(WheelOdometry(i * 0.1, 1.0, 1.0))
        if i % 10 == 0:
            p.feed(HeadingFix(i * 0.1, 0.0))
    assert p.localizer.estimator.x[0] > 90.0
    return p


def _write(path: Path, pipeline: Pipeline, vehicle: str = "car-1", **kw: Any) -> Checkpointer:
    ck = Checkpointer(path, 5.0, trip_identity(vehicle, pipeline.config.describe()))
    assert ck.save(10.0, {"pipeline": pipeline.snapshot(), "extra": {}}, **kw)
    return ck


def _start(
    path: Path, goal: tuple[float, float] | None = GOAL, vehicle: str = "car-1"
) -> Pipeline:
    p = _pipeline(goal)
    ck = start_checkpoints(
        p, str(path), interval_s=5.0, max_age_s=600.0, vehicle_id=vehicle, resume=True
    )
    assert ck is not None
    return p


def _aside(path: Path) -> list[str]:
    return sorted(q.name for q in path.parent.iterdir() if ".rejected-" in q.name)


def test_the_same_vehicle_and_trip_resumes(tmp_path: Path) -> None:
    ck = tmp_path / "ck.json"
    _write(ck, _driven())
    p = _start(ck)
    assert p.localizer.estimator.x[0] > 90.0  # resumed where it was
    doc = json.loads(ck.read_bytes())
    assert doc["identity"]["vehicle_id"] == "car-1"
    assert doc["identity"]["software_version"]
    assert set(doc["identity"]["trip"]) == {"goal_xy_m", "start_xy_m", "config_digest"}


@pytest.mark.parametrize(
    ("vehicle", "goal", "why"),
    [
        ("car-2", GOAL, "from vehicle 'car-1'"),
        ("car-1", (-500.0, 900.0), "the goal changed"),
        ("car-1", None, "the goal changed"),  # a car with no goal now
    ],
)
def test_another_vehicle_or_a_changed_goal_starts_afresh_and_the_file_is_moved_aside(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, vehicle: str, goal: Any, why: str
) -> None:
    ck = tmp_path / "ck.json"
    _write(ck, _driven())
    with caplog.at_level(logging.WARNING):
        p = _start(ck, goal=goal, vehicle=vehicle)
    assert p.localizer.estimator.x[0] == 0.0  # afresh
    assert p.navigator.goal == goal  # the configured goal, not the checkpoint's
    assert not ck.exists() and len(_aside(ck)) == 1
    assert why in caplog.text and "moved aside" in caplog.text


def test_a_car_without_a_goal_resumes_its_own_checkpoint(tmp_path: Path) -> None:
    ck = tmp_path / "ck.json"
    _write(ck, _driven(goal=None))
    assert json.loads(ck.read_bytes())["identity"]["trip"]["goal_xy_m"] is None
    p = _start(ck, goal=None)
    assert p.localizer.estimator.x[0] > 90.0 and p.navigator.goal is None


def test_a_clean_stop_is_not_resumed(tmp_path: Path) -> None:
    ck = tmp_path / "ck.json"
    _write(ck, _driven(), finished=True)
    assert load_checkpoint(ck, trip_identity("car-1", _pipeline().config.describe())) is None
    p = _start(ck)
    assert p.localizer.estimator.x[0] == 0.0
    assert ck.exists() and not _aside(ck)  # nothing wrong with it: just finished


def _mutations() -> dict[str, Any]:
    """Name -> a function that spoils a snapshot (the attacks of issue 14, item 3)."""
    nan = float("nan")

    def setp(path: str, value: Any) -> Any:
        def f(s: dict[str, Any]) -> None:
            *head, last = path.split(".")
            d = s
            for k in head:
                d = d[int(k)] if isinstance(d, list) else d[k]
            if isinstance(d, list):
                d[int(last)] = value
            else:
                d[last] = value

        return f

    return {
        "nan x": setp("x.0", nan),
        "inf heading": setp("x.2", float("inf")),
        "nan covariance": setp("P.0.0", nan),
        "negative covariance": setp("P.0.0", -4.0),
        "asymmetric covariance": setp("P.0.1", 50.0),
        "10,000 km jump": setp("x.0", 1e7),
        "nan goal": setp("navigator.goal.0", nan),
        "text number": setp("odometer_m", "12"),
        "speed 1e300": setp("speed_mps", 1e300),
        "wrong shape x": setp("x", [1.0, 2.0]),
        "wrong shape P": setp("P", [[1.0, 0.0], [0.0, 1.0]]),
        "100k-entry memory": setp("navigator.mem_xy", [[0.0, 0.0]] * 100_000),
        "memory rows disagree": setp("navigator.mem_headings", [[0.0] * 8]),
        "mode 7": setp("navigator.mode", 7),
        "counts text": setp("counts", {"a": "many"}),
        "bool as number": setp("decisions", True),
        "turn samples a table": setp("turns.samples", {"a": 1}),
        "guide garbage": setp("guide", {"ahead": [{"decision": {"t_s": 1}, "exits_rad": [0]}]}),
        "guide exits NaN": setp("guide", {"ahead": [{"exits_rad": [math.nan]}]}),
        "guide 9 ahead": setp("guide", {"ahead": [{"exits_rad": [0.0]}] * 9}),
        "guide history rows": setp("guide.history", [[0.0, 1.0]]),
        "pipeline a list": lambda s: s.clear(),
    }


@pytest.mark.parametrize("name", list(_mutations()))
def test_an_invalid_state_is_moved_aside_and_later_writes_work(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, name: str
) -> None:
    ck = tmp_path / "ck.json"
    good = _driven()
    _write(ck, good)
    doc = json.loads(ck.read_bytes())
    snap = copy.deepcopy(doc["pipeline"])
    _mutations()[name](snap)
    doc["pipeline"] = snap
    ck.write_text(json.dumps(doc))  # json writes NaN as NaN, which json.loads accepts
    with caplog.at_level(logging.WARNING):
        p = _start(ck)
    est = p.localizer.estimator
    assert est.x[0] == 0.0 and np.all(np.isfinite(est.P))  # afresh, untouched
    assert p.navigator.goal == GOAL
    assert len(_aside(ck)) == 1, caplog.text
    assert "moved aside" in caplog.text
    # Crash recovery still works: the next write succeeds and is resumed.
    _write(ck, p)
    assert load_checkpoint(ck, trip_identity("car-1", p.config.describe())) is not None


@pytest.mark.parametrize(
    "content",
    [b"", b"{", b"\x00\xff" * 100, b'{"schema": "guidance.checkpoint/1"}', b"[1, 2]", b"[" * 50000],
)
def test_a_damaged_or_empty_checkpoint_never_stops_a_start(tmp_path: Path, content: bytes) -> None:
    ck = tmp_path / "ck.json"
    ck.write_bytes(content)
    p = _start(ck)
    assert p.localizer.estimator.x[0] == 0.0
    assert not ck.exists() and len(_aside(ck)) == 1  # ages out: the next start is clean
    _start(ck)
    assert len(_aside(ck)) == 1


def test_an_unreadable_wall_time_is_too_old_not_a_crash(tmp_path: Path) -> None:
    ck = tmp_path / "ck.json"
    _write(ck, _driven())
    doc = json.loads(ck.read_bytes())
    doc["wall_time_unix_s"] = "yesterday"
    ck.write_text(json.dumps(doc))
    assert _start(ck).localizer.estimator.x[0] == 0.0


def test_a_write_on_a_full_disk_leaves_no_temp_file(tmp_path: Path) -> None:
    """A real file-size limit (RLIMIT_FSIZE) in a child process: the write fails with EFBIG
    half-way, is reported (False, counted), and the folder holds no temporary file."""
    folder = tmp_path / "ck"
    script = textwrap.dedent(
        f"""
        import resource, signal, sys
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        from guidance.app.checkpoint import Checkpointer
        resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))
        ck = Checkpointer({str(folder / "ck.json")!r})
        ok = [ck.save(float(i), {{"blob": "x" * 20000}}) for i in range(3)]
        print(ok, ck.errors)
        """
    )
    out = subprocess.run(
        [sys.executable, "-c", script], cwd=REPO, capture_output=True, text=True, timeout=60
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["[False,", "False,", "False]", "3"]
    assert [p.name for p in folder.iterdir()] == []


def test_the_simulator_refuses_its_own_damaged_checkpoint_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture
) -> None:
    """A sim checkpoint whose state is invalid (NaN pose): one clear line, moved aside, and
    the run starts afresh (issue 40: a NaN is not JSON the strict parser takes, so the file is
    damaged like any other and set aside as ``guidance run`` does)."""
    import json

    from guidance.tools.cli import main

    ck = tmp_path / "ck.json"
    args = ["sim", "--seed", "11", "--no-voice", "--no-record", "--no-png", "--no-telemetry",
            "--out", str(tmp_path), "--checkpoint", str(ck)]  # fmt: skip
    assert main(args) == 0
    doc = json.loads(ck.read_text())
    doc["pipeline"]["x"][0] = float("nan")
    ck.write_text(json.dumps(doc))
    capsys.readouterr()
    with caplog.at_level("WARNING", logger="guidance.app.checkpoint"):
        assert main(args) == 0  # afresh
    err = capsys.readouterr().err
    assert "internal error" not in err
    said = [r.getMessage() for r in caplog.records if "ck.json" in r.getMessage()]
    assert len(said) == 1 and "damaged" in said[0] and "NaN is not a finite number" in said[0]
    assert list(tmp_path.glob("ck.json.rejected-*"))
