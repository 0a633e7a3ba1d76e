"""End-to-end simulated drives: world -> CAN frames on a virtual bus -> CanOdometry, NMEA on a
pty -> SerialCompass, city-graph scene -> Pipeline (estimator + navigator) -> prompts."""

from __future__ import annotations

import json
import os
import shutil
import time
import wave
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager
from dataclasses import replace
from pathlib import Path

import pytest

from guidance.tools.cli import main
from hal_sim.drive import DriveOptions, run_drive

FAST = DriveOptions(seed=7, voice="none", telemetry=False, record=False, png=False)


@pytest.fixture(autouse=True)
def no_leaks(leak_check: Callable[..., AbstractContextManager[None]]) -> Iterator[None]:
    """A drive must close its bus, its pty and every thread it started."""
    with leak_check(grace_s=3.0):
        yield


def test_seed_7_reaches_the_goal_through_the_real_drivers(tmp_path: Path) -> None:
    lines: list[str] = []
    opts = DriveOptions(
        seed=7, voice="none", telemetry=False, record=True, png=True, out=str(tmp_path)
    )
    r = run_drive(opts, lines.append)
    assert r.outcome == "arrived"
    assert 1.0 < r.driven_km < 5.0
    assert r.final_error_m < 30.0  # within the arrival radius of the truth
    # Odometry really went through CAN: two GM frames (0x348, 0x34A) per 0.1 s step...
    steps = round(r.sim_s / 0.1)
    assert r.frames_sent == 2 * steps
    # ...and the compass through the pty at about 6 Hz.
    assert r.compass_lines == pytest.approx(6 * r.sim_s, rel=0.05)
    assert r.decisions >= 3
    assert r.prompts == len(r.prompt_log) == len(lines)
    assert lines[-1].endswith("You have arrived at your destination")
    assert any("turn" in line for line in lines)
    assert not r.health_warnings
    png = Path(r.png or "")
    assert png.is_file() and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert png.stat().st_size > 20_000
    assert r.recording and Path(r.recording[0]).is_file()


def test_the_same_seed_gives_the_same_drive() -> None:
    a = run_drive(FAST)
    b = run_drive(FAST)
    assert a.prompt_log == b.prompt_log
    assert a.final_error_m == b.final_error_m
    assert a.driven_km == b.driven_km


def test_silent_can_is_flagged_spoken_and_survived() -> None:
    """Two seconds without wheel-speed frames: odometry goes dead, the driver is warned, the
    estimate is inflated for the distance missed (the speed before the gap times the gap plus
    what the car could have gained: about 26 m), and the drive still reaches its goal. (Five
    seconds at town speed widen it by about 90 m: honestly lost, tests/guidance/core.)"""
    r = run_drive(replace(FAST, can_silent=(30.0, 2.0)))
    warnings = [w for w in r.health_warnings if "odometry" in w]
    assert warnings and "silent" in warnings[0]
    t_warn = float(warnings[0].split()[0])
    assert 30.9 <= t_warn <= 32.0  # dead after 1 s (min timeout), evaluated every step
    lost = "Wheel speed signal lost. Position is getting less certain."
    spoken = [(t, text) for t, text in r.prompt_log if "heel speed" in text or "odometry" in text]
    assert [text for _, text in spoken] == [lost]  # once, one sentence whoever noticed first
    assert r.outcome == "arrived"
    assert r.sim_s > 35.0


def test_garbled_compass_is_flagged_and_survived() -> None:
    r = run_drive(replace(FAST, compass_garbage=(20.0, 6.0)))
    warnings = [w for w in r.health_warnings if "compass" in w]
    assert warnings, r.health_warnings
    said = [text for _, text in r.prompt_log if text.startswith("Compass")]
    assert len(said) == 1 and said[0].endswith("Heading is getting less certain."), said
    assert r.outcome == "arrived"


def test_without_a_compass_the_car_gets_lost_and_says_so() -> None:
    r = run_drive(replace(FAST, compass_deg=None, density_per_km2=0.0))
    assert r.outcome == "lost"
    assert r.prompt_log[-1][1].startswith("Position lost")
    assert r.driven_km < 2.0


def test_cli_json_is_the_last_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rc = main(
        [
            "sim",
            "--seed",
            "7",
            "--no-voice",
            "--no-telemetry",
            "--no-record",
            "--json",
            "--out",
            str(tmp_path),
        ]
    )
    assert rc == 0
    out = capsys.readouterr().out.strip().splitlines()
    summary = json.loads(out[-1])
    for key in ("outcome", "driven_km", "final_error_m", "prompts", "landmark_updates", "png"):
        assert key in summary
    assert summary["outcome"] == "arrived"
    assert Path(summary["png"]).is_file()
    assert any(line.startswith("[") and " s] " in line for line in out)  # prompts with times
    assert any(line.startswith("ARRIVED") for line in out)


def test_cli_rejects_bad_options(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["sim", "--detection-rate", "1.5", "--no-voice", "--no-telemetry"]) == 2
    assert "--detection-rate must be a finite number >= 0 and <= 1" in capsys.readouterr().err


@pytest.mark.skipif(shutil.which("espeak-ng") is None, reason="espeak-ng not installed")
def test_voice_to_records_the_prompts(tmp_path: Path) -> None:
    wav = tmp_path / "prompts.wav"
    r = run_drive(replace(FAST, voice_to=str(wav)))
    assert r.outcome == "arrived"
    with wave.open(str(wav)) as w:
        seconds = w.getnframes() / w.getframerate()
    assert seconds > r.prompts * 0.8  # about a second or more per prompt


@pytest.mark.slow
def test_simulated_camera_through_the_real_recogniser(tmp_path: Path) -> None:
    """Camera frames rendered at the true position, matched by landmark_db's recogniser off
    the loop; its fixes reach the estimator (about 20 s)."""
    opts = replace(
        FAST,
        seed=3,
        goal_min_m=350.0,
        goal_max_m=600.0,
        density_per_km2=30.0,
        camera_hz=2.0,
        out=str(tmp_path),
    )
    r = run_drive(opts)
    assert r.outcome == "arrived"
    assert r.landmark_updates >= 1
    assert any(text.startswith("Passing the ") for _, text in r.prompt_log)  # by its name


def test_a_monitor_in_another_process_follows_the_simulated_car(tmp_path: Path) -> None:
    """Issue 6: ``guidance sim`` and a monitor on loopback. State arrives at the published
    rate (10 Hz of simulated time, here paced at 2x: 20 Hz) with no sequence gaps, and the
    car's liveliness goes within seconds of a SIGKILL."""
    import signal
    import socket
    import subprocess
    import sys

    from guidance.telemetry.client import MonitorClient

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    repo = Path(__file__).resolve().parents[2]
    cfg = tmp_path / "sim.toml"
    cfg.write_text(
        (repo / "config" / "sim.toml")
        .read_text()
        .replace("tcp/127.0.0.1:7447", f"tcp/127.0.0.1:{port}")
        .replace('vehicle_id = "sim1"', 'vehicle_id = "simmon"')
        .replace("[vehicle]\n", '[vehicle]\nid = "simmon"\n')
    )
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "guidance.tools.cli",
            "sim",
            "--config",
            str(cfg),
            "--speed",
            "2",
            "--no-voice",
            "--no-record",
            "--no-png",
            "--out",
            str(tmp_path),
        ],
        cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": str(repo)},
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        with MonitorClient([f"tcp/127.0.0.1:{port}"]) as mon:
            deadline = time.monotonic() + 30.0
            seqs: list[int] = []
            t0 = None
            while time.monotonic() < deadline:
                e = mon.get(0.1)
                if e is None or e.kind != "state" or e.late_join or not e.message:
                    continue
                assert e.vehicle_id == "simmon"
                t0 = t0 or e.received_s
                seqs.append(int(e.message["seq"]))
                if e.received_s - t0 >= 3.0:
                    break
            assert t0 is not None, "no state received"
            rate_hz = (len(seqs) - 1) / (time.monotonic() - t0)
            assert seqs == list(range(seqs[0], seqs[0] + len(seqs))), "gaps in the state"
            assert 14.0 < rate_hz < 26.0
            os.kill(proc.pid, signal.SIGKILL)
            killed = time.monotonic()
            while time.monotonic() - killed < 10.0:
                e = mon.get(0.1)
                if e is not None and e.kind == "gone" and e.vehicle_id == "simmon":
                    break
            else:
                raise AssertionError("the car's liveliness did not go")
            assert time.monotonic() - killed < 5.0
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait()


def test_field_protocol_sets_new_goals_until_the_time_limit() -> None:
    times: list[float] = []
    r = run_drive(replace(FAST, seed=3, duration_s=420.0), None, None, times.append)
    assert r.outcome == "time_limit"
    assert 420.0 <= r.sim_s < 421.0
    assert r.goals_reached >= 1  # seed 3 reaches its first goal in about 170 s
    assert any("New destination" in text for _, text in r.prompt_log)
    assert times[0] == pytest.approx(0.0, abs=0.2) and len(times) == 7  # once a simulated minute
    assert r.loop_lag_ms["loop_lag_p99_ms"] is not None


def test_turn_prompts_come_early_enough_at_the_simulated_speed_and_never_twice() -> None:
    """The final announcement is at least 3 s before the intersection at the drive's speed
    (Organic Maps: about 8 s, at least 35 m); no prompt twice; "continue straight" is not said
    at one intersection after another."""
    import itertools
    import re

    from hal_sim.params import SimParams

    r = run_drive(replace(FAST, density_per_km2=5.0))  # with landmark fixes too
    v = SimParams().cruise_mps  # the fastest the simulated car drives
    turns = [(t, text) for t, text in r.prompt_log if text.startswith("In ")]
    assert len(turns) >= 3
    for _t, text in turns:
        m = re.match(r"In (\d+) metres", text)
        assert m, text
        assert int(m.group(1)) / v >= 3.0, text  # seconds left to act, at most this speed
    assert len(set(r.prompt_log)) == len(r.prompt_log)
    for i, (t, text) in enumerate(r.prompt_log):  # nor the same sentence twice in 3 s
        assert not any(u - t < 3.0 and same == text for u, same in r.prompt_log[i + 1 :])
    texts = [text for _t, text in r.prompt_log]
    for a, b in itertools.pairwise(texts):
        assert not (a == b and "straight" in a), (a, b)


def test_the_summary_names_a_wav_only_when_it_holds_speech(tmp_path: Path) -> None:
    import wave

    import numpy as np

    from hal_sim.drive import wav_has_speech

    assert not wav_has_speech(str(tmp_path / "missing.wav"))
    silent = tmp_path / "silent.wav"
    with wave.open(str(silent), "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(22050)
        w.writeframes(np.zeros(22050, dtype=np.int16).tobytes())
    assert not wav_has_speech(str(silent))
    (tmp_path / "junk.wav").write_bytes(b"RIFF....not a wav")
    assert not wav_has_speech(str(tmp_path / "junk.wav"))
    r = run_drive(replace(FAST, voice_to=str(tmp_path / "prompts.wav")))
    assert r.wav == str(tmp_path / "prompts.wav") and wav_has_speech(r.wav)
