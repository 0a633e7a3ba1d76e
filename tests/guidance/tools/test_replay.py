"""Replay: recordings reproduce their estimates and decisions exactly; raw CAN/NMEA logs run
through the same pipeline; a committed recording regresses against committed outputs."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import can
import pytest

from guidance.core.pipeline import Pipeline
from guidance.recording.reader import Reader
from guidance.tools.cli import main
from guidance.tools.replay import (
    can_inputs,
    compare_with_recording,
    mcap_inputs,
    nmea_inputs,
    pipeline_config_from_session,
    recorded_outputs,
    replay,
)
from hal_sim.drive import DriveOptions, run_drive

REPO = Path(__file__).resolve().parents[3]
DATA = REPO / "tests" / "data" / "replay"
RECORDING = DATA / "sim_seed3_landmarks.mcap"
EXPECTED = DATA / "sim_seed3_landmarks.expected.json"
RAV4 = REPO / "tests" / "data" / "can" / "rav4_2020-02-03_bus0_wheelspeeds.log"


def _replay_mcap(path: Path) -> Any:
    session, inputs = mcap_inputs(path)
    return replay(Pipeline(pipeline_config_from_session(session)), inputs)


def _close(a: Any, b: Any, path: str = "") -> None:
    """Equal structure; floats equal to 1e-9 relative (other CPUs may round differently)."""
    if isinstance(a, float) or isinstance(b, float):
        assert a == pytest.approx(b, rel=1e-9, abs=1e-9), path
    elif isinstance(a, dict):
        assert a.keys() == b.keys(), path
        for k in a:
            _close(a[k], b[k], f"{path}.{k}")
    elif isinstance(a, list | tuple):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _close(x, y, f"{path}[{i}]")
    else:
        assert a == b, path


def test_committed_recording_reproduces_its_own_outputs_exactly() -> None:
    res = _replay_mcap(RECORDING)
    assert compare_with_recording(res, recorded_outputs(RECORDING)) == []
    assert res.landmark_updates >= 2 and len(res.decisions) >= 3
    assert res.final["arrived"]


def test_committed_recording_matches_committed_expected_outputs() -> None:
    res = _replay_mcap(RECORDING)
    _close(json.loads(json.dumps(res.expected())), json.loads(EXPECTED.read_text()))


def test_recording_lists_channels_and_schemas_for_the_mcap_reader() -> None:
    from mcap.reader import make_reader

    with RECORDING.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    topics = {ch.topic: summary.schemas[ch.schema_id].name for ch in summary.channels.values()}
    for topic in ("/session", "/odometry", "/compass", "/landmark_fix", "/scene", "/decision",
                  "/state", "/prompt", "/health"):  # fmt: skip
        assert topic in topics
    assert topics["/decision"] == "guidance.decision"
    assert Reader(RECORDING).channels()["/state"] == "guidance.state"


def test_a_fresh_simulated_drive_replays_exactly(tmp_path: Path) -> None:
    r = run_drive(DriveOptions(seed=11, goal_min_m=350, goal_max_m=600, voice="none",
                               telemetry=False, png=False, out=str(tmp_path)))  # fmt: skip
    assert r.outcome == "arrived"
    path = Path(r.recording[0])
    res = _replay_mcap(path)
    assert compare_with_recording(res, recorded_outputs(path)) == []
    assert [p for _, p in res.prompts] == [p for _, p in r.prompt_log]
    assert res.final["odometer_m"] > 400.0
    # The raw CAN frames and NMEA lines, decoded again by the drivers' decoder and parser,
    # give the very same drive.
    session, raw = mcap_inputs(path, raw=True, profile="gm_global_a")
    res_raw = replay(Pipeline(pipeline_config_from_session(session)), raw)
    assert compare_with_recording(res_raw, recorded_outputs(path)) == []
    topics = Reader(path).channels()
    assert topics["/can"] == "guidance.can_frame" and topics["/nmea"] == "guidance.nmea_line"


def test_cli_replay_of_a_recording(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["replay", str(RECORDING), "--json"]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    summary = json.loads(out[-1])
    assert summary["matches_recording"] is True
    assert summary["decisions"] >= 3
    assert "matches the recording exactly" in out[-2]


# ----------------------------------------------------------------------------- raw logs


def _candump_distance() -> float:
    from drivers.can_odometry import replay_log

    return replay_log(RAV4, "toyota").distance_m


@pytest.mark.parametrize("suffix", [".log", ".asc", ".blf"])
def test_raw_can_logs_drive_the_pipeline(tmp_path: Path, suffix: str) -> None:
    path = RAV4
    if suffix != ".log":  # the same frames written by python-can's own writers
        path = tmp_path / f"rav4{suffix}"
        with can.Logger(str(path)) as writer:
            for msg in can.LogReader(str(RAV4)):
                writer.on_message_received(msg)
    p = Pipeline(_raw_config())
    res = replay(p, can_inputs(path, "toyota"))
    assert res.inputs > 3000
    assert res.odometer_m == pytest.approx(_candump_distance(), rel=1e-3)
    assert math.isfinite(res.final["x_m"]) and math.isfinite(res.final["y_m"])


def _raw_config() -> Any:
    from guidance.tools.replay import _default_pipeline

    return _default_pipeline(0.0)


def test_stamped_nmea_merges_with_can_by_time(tmp_path: Path) -> None:
    from hal_sim.sim_compass import hdg_body, nmea_sentence

    t0 = float(next(iter(can.LogReader(str(RAV4)))).timestamp)
    lines = [f"{t0 + 0.2 * k:.3f} " + nmea_sentence(hdg_body(10.0)).decode().strip()
             for k in range(200)]  # fmt: skip
    lines.insert(5, "garbage line")
    nmea = tmp_path / "compass.txt"
    nmea.write_text("\n".join(lines) + "\n")
    headings = list(nmea_inputs(nmea, t0, 5.0))
    assert len(headings) == 200
    assert headings[1].t_s - headings[0].t_s == pytest.approx(0.2)
    assert main(["replay", str(RAV4), "--profile", "toyota", "--nmea", str(nmea), "--json"]) == 0


def test_raw_replay_without_a_compass_needs_a_heading(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["replay", str(RAV4), "--profile", "toyota"]) == 2
    assert "--start-heading-deg" in capsys.readouterr().err
