"""Foxglove-native recordings and geodetic positions (issue 16, items 1 and 2).

A fresh simulated drive is recorded; every message on a Foxglove topic is validated against
the JSON Schema stored in the file, that schema is the one generated from Foxglove's published
protobuf definitions (foxglove-schemas-protobuf), and each message also parses strictly into
the official protobuf class. The same recording still replays exactly.
"""

from __future__ import annotations

import json
import math
from collections import defaultdict
from pathlib import Path
from typing import Any

import jsonschema
import numpy as np
import pymap3d
import pytest
from google.protobuf import json_format
from mcap.reader import make_reader

from guidance.core.messages import Ellipse, EstimateState
from guidance.core.pipeline import Pipeline
from guidance.outputs.messages import heading_deg_true, state_message
from guidance.outputs.schemas import SCHEMAS
from guidance.recording.config import RecordingConfig
from guidance.recording.foxglove import SCHEMA_OF_TOPIC, TRACK_PIECE, ellipse_points
from guidance.recording.foxglove_schemas import json_schema, to_protobuf
from guidance.recording.reader import Reader
from guidance.recording.writer import Recorder
from guidance.telemetry.config import TelemetryConfig
from guidance.tools.replay import (
    compare_with_recording,
    mcap_inputs,
    pipeline_config_from_session,
    recorded_outputs,
    replay,
)
from hal_sim.drive import SIM_ORIGIN_LAT_LON, DriveOptions, run_drive

ORIGIN = (42.444, -76.5019)


def _foxglove_messages(path: Path) -> tuple[dict[str, Any], dict[str, list[dict[str, Any]]]]:
    """Schemas (by name, as stored) and messages (by topic) of the file's Foxglove channels."""
    schemas: dict[str, Any] = {}
    messages: dict[str, list[dict[str, Any]]] = defaultdict(list)
    with path.open("rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            if schema is None or not schema.name.startswith("foxglove."):
                continue
            assert schema.encoding == "jsonschema" and channel.message_encoding == "json"
            schemas[schema.name] = json.loads(schema.data)
            messages[channel.topic].append(json.loads(message.data))
    return schemas, messages


@pytest.fixture(scope="module")
def drive(tmp_path_factory: pytest.TempPathFactory) -> Any:
    out = tmp_path_factory.mktemp("fox")
    return run_drive(DriveOptions(seed=11, goal_min_m=350, goal_max_m=600, voice="none",
                                  telemetry=False, png=False, out=str(out)))  # fmt: skip


def test_simulated_recording_validates_against_the_official_foxglove_schemas(drive: Any) -> None:
    path = Path(drive.recording[0])
    schemas, messages = _foxglove_messages(path)
    expected_topics = set(SCHEMA_OF_TOPIC) - {"/camera/thumbnail"}  # no camera in this drive
    assert expected_topics <= set(messages), set(messages)
    total = 0
    for topic, msgs in messages.items():
        name = SCHEMA_OF_TOPIC[topic]
        # the stored schema is the one generated from Foxglove's published definitions
        assert schemas[name] == json_schema(name)
        validator = jsonschema.Draft7Validator(schemas[name])
        for m in msgs:
            errors = [e.message for e in validator.iter_errors(m)]
            assert errors == [], (topic, errors[:3])
            to_protobuf(name, m)  # strict: unknown fields or wrong types raise
            total += 1
    assert total > 1000


def test_foxglove_views_carry_the_estimate_truth_prompts_and_scene(drive: Any) -> None:
    path = Path(drive.recording[0])
    _, fox = _foxglove_messages(path)
    states = [m.data for m in Reader(path, topics=["/state"], log_time_order=False)]
    prompts = [m.data for m in Reader(path, topics=["/prompt"], log_time_order=False)]
    # one LocationFix and one pose per state, same numbers
    assert len(fox["/foxglove/location"]) == len(states) == len(fox["/foxglove/pose"])
    for s, fix, pose in zip(states, fox["/foxglove/location"], fox["/foxglove/pose"], strict=True):
        e, n, _u = pymap3d.geodetic2enu(fix["latitude"], fix["longitude"], 0.0,
                                        *SIM_ORIGIN_LAT_LON, 0.0)  # fmt: skip
        assert (e, n) == (pytest.approx(s["x_m"], abs=1e-3), pytest.approx(s["y_m"], abs=1e-3))
        cov = fix["position_covariance"]
        assert fix["position_covariance_type"] == 3
        assert [cov[0], cov[1], cov[3], cov[4]] == [
            s["covariance"][0][0],
            s["covariance"][0][1],
            s["covariance"][1][0],
            s["covariance"][1][1],
        ]
        q = pose["pose"]["orientation"]
        assert 2.0 * math.atan2(q["z"], q["w"]) == pytest.approx(s["heading_rad"], abs=1e-9)
        assert pose["pose"]["position"]["x"] == pytest.approx(s["x_m"], abs=1e-3)
    # prompts as Log lines, in order
    assert [m["message"] for m in fox["/foxglove/log"]] == [p["text"] for p in prompts]
    # the true pose is on its own topics, at most 10 Hz, close to the estimate at the end
    truth = fox["/truth/pose"]
    assert len(truth) == len(fox["/truth/location"]) > 10
    assert [m.topic for m in Reader(path, topics=["/truth"])][:1] == ["/truth"]
    last = truth[-1]["pose"]["position"]
    assert math.hypot(last["x"] - states[-1]["x_m"], last["y"] - states[-1]["y_m"]) < 100.0
    # the scene: estimate with an ellipse, goal, track pieces, true track, landmarks
    ids: set[str] = set()
    for update in fox["/foxglove/scene"]:
        for ent in update["entities"]:
            ids.add(ent["id"].split("/")[0])
            assert ent["frame_id"] == "map"
            if ent["id"].startswith(("truth", "track")):  # pieces, never the whole path again
                assert all(len(line["points"]) <= TRACK_PIECE + 1 for line in ent["lines"])
    assert {"estimate", "goal", "track", "truth", "landmarks"} <= ids
    est = next(ent for u in fox["/foxglove/scene"] for ent in u["entities"]
               if ent["id"] == "estimate")  # fmt: skip
    assert est["lines"][0]["type"] == 1 and len(est["lines"][0]["points"]) >= 24


def test_the_foxglove_recording_still_replays_exactly(drive: Any) -> None:
    path = Path(drive.recording[0])
    session, inputs = mcap_inputs(path)
    res = replay(Pipeline(pipeline_config_from_session(session)), inputs)
    assert compare_with_recording(res, recorded_outputs(path)) == []


def test_the_validation_bites_on_a_broken_message() -> None:
    schema = json_schema("foxglove.LocationFix")
    good = {
        "timestamp": {"sec": 1, "nsec": 5},
        "frame_id": "estimate",
        "latitude": 42.0,
        "longitude": -76.0,
        "altitude": 0.0,
        "position_covariance": [0.0] * 9,
        "position_covariance_type": 3,
        "color": {"r": 1.0, "g": 0.0, "b": 0.0, "a": 1.0},
        "metadata": [],
    }
    jsonschema.validate(good, schema)
    to_protobuf("foxglove.LocationFix", good)
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate({**good, "latitude": "42"}, schema)
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate({k: v for k, v in good.items() if k != "longitude"}, schema)
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate({**good, "position_covariance_type": 7}, schema)
    with pytest.raises(json_format.ParseError):
        to_protobuf("foxglove.LocationFix", {**good, "lat": 42.0})
    scene = json_schema("foxglove.SceneUpdate")
    with pytest.raises(jsonschema.ValidationError):  # a nested message through its $ref
        jsonschema.validate({"deletions": [], "entities": [{"id": 3}]}, scene)


def test_ellipse_outline_is_the_two_sigma_contour_of_the_covariance() -> None:
    from guidance.core.model import CHI2_2D_2SIGMA, ellipse_axes

    cov = np.array([[120.0, 35.0], [35.0, 60.0]])
    a, b, o = ellipse_axes(cov[0, 0], cov[0, 1], cov[1, 1], CHI2_2D_2SIGMA)
    inv = np.linalg.inv(cov)
    for p in ellipse_points(5.0, -3.0, a, b, o):
        d = np.array([p["x"] - 5.0, p["y"] + 3.0])
        assert float(d @ inv @ d) == pytest.approx(4.0, rel=1e-3)


@pytest.mark.parametrize(
    ("heading_rad", "compass"),
    [(0.0, 90.0), (math.pi / 2, 0.0), (math.pi, 270.0), (-math.pi / 2, 180.0), (0.1, 84.27)],
)
def test_compass_heading_is_clockwise_from_true_north(heading_rad: float, compass: float) -> None:
    assert heading_deg_true(heading_rad) == pytest.approx(compass, abs=0.01)


def test_state_without_an_origin_has_null_positions_and_validates() -> None:
    cov = ((4.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 0.01))
    st = EstimateState(1.0, 3.0, 4.0, 0.0, cov, Ellipse(4.0, 2.0, 0.0, 8.0), False, True)
    msg = state_message(st, vehicle_id="c", goal=(1.0, 2.0))
    assert (msg["lat_deg"], msg["lon_deg"], msg["origin"]) == (None, None, None)
    assert (msg["goal"]["lat_deg"], msg["heading_deg_true"]) == (None, 90.0)
    jsonschema.validate(msg, SCHEMAS["state"])
    geo = state_message(st, vehicle_id="c", goal=(1.0, 2.0), origin_lat_lon_deg=ORIGIN)
    jsonschema.validate(geo, SCHEMAS["state"])
    assert geo["lat_deg"] > ORIGIN[0] and geo["lon_deg"] > ORIGIN[1]  # north-east of it


def test_the_configured_start_is_the_origin_of_telemetry_and_recording(tmp_path: Path) -> None:
    from guidance.app.config import load_config

    toml = tmp_path / "car.toml"
    toml.write_text(
        '[vehicle]\nid = "car1"\n[start]\nlat_deg = 42.444\nlon_deg = -76.5019\nheading_deg = 90\n'
        "[goal]\nlat_deg = 42.45\nlon_deg = -76.5\n"
    )
    cfg = load_config(toml)
    assert cfg.origin_lat_lon_deg == ORIGIN
    assert cfg.telemetry.origin_lat_lon_deg == ORIGIN == cfg.recording.origin_lat_lon_deg
    # not a key of its own in the TOML tables
    from guidance.errors import UserError

    with pytest.raises(UserError, match="unknown key"):
        TelemetryConfig.from_mapping({"origin_lat_lon_deg": [1.0, 2.0]})
    with pytest.raises(UserError, match="unknown key"):
        RecordingConfig.from_mapping({"origin_lat_lon_deg": [1.0, 2.0]})
    with pytest.raises(UserError, match="latitude"):
        TelemetryConfig(origin_lat_lon_deg=(95.0, 0.0))


def test_record_truth_is_rate_limited(tmp_path: Path) -> None:
    with Recorder(RecordingConfig(directory=str(tmp_path), origin_lat_lon_deg=ORIGIN)) as rec:
        kept = [rec.record_truth(i * 0.02, float(i), 0.0, 0.0) for i in range(50)]
    assert sum(kept) == 10  # 1 s at 50 Hz, at most one per 0.1 s
    topics = [m.topic for m in Reader(tmp_path)]
    assert topics.count("/truth") == topics.count("/truth/location") == 10
