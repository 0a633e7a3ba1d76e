"""Crash recovery (issue 7): atomic checkpoints, and a simulated drive killed with SIGKILL at 20
random points that still reaches its goal after each restart."""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from guidance.app.checkpoint import Checkpointer, load_checkpoint, write_atomic

REPO = Path(__file__).resolve().parents[3]


def test_atomic_write_replaces_whole_files(tmp_path: Path) -> None:
    path = tmp_path / "sub" / "ck.json"
    write_atomic(path, b'{"a": 1}')
    write_atomic(path, b'{"a": 2}')
    assert json.loads(path.read_bytes()) == {"a": 2}
    assert [p.name for p in path.parent.iterdir()] == ["ck.json"]  # no temporary left behind


def test_missing_damaged_and_foreign_checkpoints(tmp_path: Path) -> None:
    """None, and a bad file is moved aside (tests/reliability/test_checkpoint_trust.py)."""
    assert load_checkpoint(tmp_path / "none.json") is None
    bad = tmp_path / "bad.json"
    bad.write_text('{"schema": "guidance.checkpoint/2", "t_s": ')
    assert load_checkpoint(bad) is None
    assert not bad.exists()
    bad.write_text('{"schema": "something/else"}')
    assert load_checkpoint(bad) is None
    assert len(list(tmp_path.glob("bad.json.rejected-*"))) == 2


def test_interval_is_on_the_message_clock(tmp_path: Path) -> None:
    ck = Checkpointer(tmp_path / "ck.json", interval_s=5.0)
    written = [
        t
        for t in (0.0, 1.0, 4.9, 5.0, 7.0, 10.0, 10.1)
        if ck.maybe_save(t, {"x": t, "pipeline": {}})
    ]
    assert written == [0.0, 5.0, 10.0]
    doc = load_checkpoint(tmp_path / "ck.json")
    assert doc is not None and doc["x"] == 10.0 and doc["t_s"] == 10.0


def test_a_failing_disk_is_reported_not_raised(tmp_path: Path) -> None:
    target = tmp_path / "ro"
    target.mkdir()
    target.chmod(0o500)
    try:
        if os.access(target, os.W_OK):  # root ignores the mode
            pytest.skip("running as root: cannot make a read-only folder")
        ck = Checkpointer(target / "ck.json")
        assert ck.save(1.0, {"x": 1}) is False
        assert ck.errors == 1
    finally:
        target.chmod(0o700)


def test_resume_loads_asks_the_policy_restores_and_sets_a_refused_state_aside(
    tmp_path: Path,
) -> None:
    """The mechanics the car and the simulated drive share (``resume_from_checkpoint``)."""
    from guidance.app.checkpoint import INVALID, NO_CHECKPOINT, resume_from_checkpoint

    path = tmp_path / "ck.json"
    restored: list[dict[str, Any]] = []
    assert resume_from_checkpoint(path, restored.append).outcome == NO_CHECKPOINT
    Checkpointer(path).save(1.0, {"pipeline": {"x": [1.0]}})
    later = resume_from_checkpoint(path, restored.append, policy=lambda doc: "too old")
    assert later.outcome == "too old" and not later.resumed
    assert not restored and path.exists()  # the policy's refusal keeps the file
    assert resume_from_checkpoint(path, restored.append).resumed
    assert restored[0]["pipeline"] == {"x": [1.0]}

    def refuse(doc: dict[str, Any]) -> None:
        raise ValueError("x[0] is not finite")

    done = resume_from_checkpoint(path, refuse)
    assert (done.outcome, done.why, done.resumed) == (INVALID, "x[0] is not finite", False)
    assert not path.exists() and len(list(tmp_path.glob("ck.json.rejected-*"))) == 1


def test_the_car_and_the_simulator_resume_through_the_shared_mechanics() -> None:
    """ARCHITECTURE-2: loading a checkpoint and moving a bad one aside are written once, in
    ``guidance/app/checkpoint.py``; the car (``build.resume_car``) and the simulated drive
    (``SimDrive._resume``) give only their policy and their state to ``resume_from_checkpoint``."""
    import ast

    own = REPO / "guidance" / "app" / "checkpoint.py"
    bad = []
    for folder in ("guidance", "hal_sim"):
        for path in sorted((REPO / folder).rglob("*.py")):
            if path == own:
                continue
            for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
                name = getattr(node, "id", None) or getattr(node, "attr", None)
                if name in ("load_checkpoint", "set_aside"):
                    bad.append(f"{path.relative_to(REPO)}:{getattr(node, 'lineno', 0)} {name}")
    assert not bad, "resume with checkpoint.resume_from_checkpoint:\n" + "\n".join(bad)


def _sim_cmd(ck: Path, out: Path) -> list[str]:
    return [
        sys.executable,
        "-m",
        "guidance.tools.cli",
        "sim",
        "--seed",
        "7",
        "--no-voice",
        "--no-telemetry",
        "--no-png",
        "--json",
        "--checkpoint",
        str(ck),
        "--out",
        str(out),
    ]


def _checkpoint_t(ck: Path) -> float:
    try:
        return float(json.loads(ck.read_bytes())["t_s"])
    except (OSError, ValueError, KeyError):
        return -1.0


@pytest.mark.slow
def test_kill_9_at_20_random_points_still_reaches_the_goal(tmp_path: Path) -> None:
    """Each run is SIGKILLed once the drive passes a random simulated time (plus a random
    0-150 ms, so kills also land mid-write); the next run resumes from the checkpoint. The
    uninterrupted drive takes about 150 simulated seconds."""
    # Compile and cache the numba world and filter first (a fresh cache after an edit of a
    # compiled module can take a minute on a busy machine; kills must land in the drive).
    from hal_sim.drive import DriveOptions, run_drive

    run_drive(
        DriveOptions(
            goal_min_m=300.0,
            goal_max_m=500.0,
            voice="none",
            telemetry=False,
            record=False,
            png=False,
            out=str(tmp_path / "warm"),
        )
    )
    kills = int(os.environ.get("GUIDANCE_CRASH_KILLS", "20"))
    rng = random.Random(20261125)
    targets = sorted(rng.uniform(3.0, 140.0) for _ in range(kills))
    ck = tmp_path / "ck.json"
    out = tmp_path / "out"
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    killed = 0
    progress: list[float] = []
    for i, target in enumerate(targets):
        log = tmp_path / f"run{i:02d}.err"
        with log.open("wb") as err:
            proc = subprocess.Popen(
                _sim_cmd(ck, out), cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=err
            )
        deadline = time.monotonic() + 120.0
        while proc.poll() is None and _checkpoint_t(ck) < target:
            if time.monotonic() > deadline:
                proc.kill()
                proc.wait()
                raise AssertionError(f"run {i} made no progress: {log.read_text()[-2000:]}")
            time.sleep(0.01)
        time.sleep(rng.uniform(0.0, 0.15))
        if proc.poll() is None:
            proc.send_signal(signal.SIGKILL)
            killed += 1
        proc.wait()
        assert proc.stdout is not None
        proc.stdout.close()
        progress.append(_checkpoint_t(ck))
    assert killed >= kills - 2  # the last targets may fall after the drive ended
    assert progress == sorted(progress)  # never went back in time
    final = subprocess.run(
        _sim_cmd(ck, out), cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120
    )
    assert final.returncode == 0, final.stderr
    summary = json.loads(final.stdout.strip().splitlines()[-1])
    assert summary["outcome"] == "arrived"
    assert summary["resumed_at_s"] is not None
    assert summary["final_error_m"] < 30.0
    # Every recording (one per run) is readable up to its last complete chunk.
    from guidance.recording.reader import Reader

    files = sorted((out / "recordings").glob("*.mcap"))
    assert files  # runs killed during start-up have not opened one yet
    for f in files:
        first = next(iter(Reader(f, log_time_order=False)), None)
        assert first is None or first.topic == "/session"


def test_an_atomic_write_never_replaces_what_is_not_a_regular_file(tmp_path: Path) -> None:
    """Issue 40: a FIFO (or a folder) at ``[checkpoint] path`` or the learned file's path is
    refused by the reader at start (``guidance.files``) and is not replaced by the first save
    either: not the product's to delete. A link is replaced as before (the link, not its
    target)."""
    fifo = tmp_path / "ck.json"
    os.mkfifo(fifo)
    folder = tmp_path / "learned.json"
    folder.mkdir()
    for path in (fifo, folder):
        with pytest.raises(OSError, match="not a regular file"):
            write_atomic(path, b"{}")
    assert fifo.is_fifo() and folder.is_dir()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ck.json", "learned.json"]
    link = tmp_path / "link.json"
    link.symlink_to("target.json")
    write_atomic(link, b"{}")
    assert link.read_bytes() == b"{}" and not link.is_symlink()
