"""The car's TOML configuration: the shipped examples load, and every bad value names its key."""

from __future__ import annotations

import dataclasses
import json
import math
import os
import tomllib
from pathlib import Path
from typing import Any

import pytest

from guidance.app.config import load_config, parse_config
from guidance.core.plan.navigator import Method
from guidance.errors import UserError
from guidance.tools.cli import main

REPO = Path(__file__).resolve().parents[3]
TAHOE = REPO / "config" / "tahoe.toml"
SIM = REPO / "config" / "sim.toml"


def _tahoe() -> dict[str, Any]:
    return tomllib.loads(TAHOE.read_text())


def test_tahoe_config_loads_with_geodetic_start_and_goal() -> None:
    cfg = load_config(TAHOE)
    p = cfg.pipeline
    assert cfg.vehicle_id == "tahoe1"
    assert cfg.telemetry.vehicle_id == "tahoe1"
    assert cfg.recording.vehicle_id == "tahoe1"
    assert p.navigator.method is Method.HYBRID
    assert p.start_xy_m == (0.0, 0.0)
    # 42.4440 N -76.5019 -> 42.4534 N -76.4735: about 2.33 km east, 1.04 km north.
    gx, gy = p.goal_xy_m
    assert gx == pytest.approx(2334, abs=15)
    assert gy == pytest.approx(1044, abs=15)
    assert p.start_heading_rad is None  # from the first compass reading
    assert -14.0 < p.declination_deg < -9.0  # WMM, Ithaca: about 11 degrees west
    assert cfg.odometry is not None and cfg.odometry.backend == "can"
    assert cfg.odometry.config.interface == "socketcan"
    assert cfg.odometry.config.channel == "can0"
    assert cfg.odometry.config.profile == "gm_global_a"
    assert cfg.compass is not None and cfg.compass.config.port == "/dev/ttyUSB0"
    assert cfg.camera is None
    assert p.expected_rates_hz == {"odometry": 20.0, "compass": 5.0}
    assert cfg.checkpoint.path == "/var/lib/guidance/checkpoint.json"


def test_sim_config_loads_without_a_goal() -> None:
    cfg = load_config(SIM, require_goal=False)
    assert cfg.sim["seed"] == 7
    assert cfg.odometry is not None and cfg.odometry.config.interface == "virtual"
    assert cfg.odometry.config.clock == "frame"
    assert Path(cfg.recording.directory).is_absolute()  # relative to the file's folder


@pytest.mark.parametrize("start", [{"x_m": 0.0, "y_m": 0.0}, {"x_m": 300.0, "y_m": -40.0},
                                   {"lat_deg": 42.444, "lon_deg": -76.5019}])  # fmt: skip
def test_no_goal_is_no_goal_and_guidance_run_still_needs_one(start: dict[str, float]) -> None:
    """Without ``[goal]`` (a raw-log replay) the car has no goal: not one at the frame's origin
    (before: (0, 0), a real goal 300 m from a start given in local metres)."""
    doc = {"start": {**start, "heading_deg": 0.0}, "compass": {"declination_deg": 0.0},
           "telemetry": {"enabled": False}, "recording": {"enabled": False}}  # fmt: skip
    cfg = parse_config(doc, require_goal=False)
    assert cfg.pipeline.goal_xy_m is None
    with pytest.raises(UserError, match=r"\[goal\] is required"):
        parse_config(doc)


def test_local_metres_and_explicit_declination() -> None:
    cfg = parse_config(
        {
            "start": {"x_m": 0.0, "y_m": 0.0, "heading_deg": 0.0},
            "goal": {"x_m": 1500, "y_m": -200},
            "compass": {"declination_deg": 3.5, "port": "/dev/ttyACM0"},
            "estimator": {"compass_two_sigma_deg": 10},
            "telemetry": {"enabled": False},
            "recording": {"enabled": False},
            "landmarks": [{"id": 3, "x_m": 100.0, "y_m": 5.0, "name": "church"}],
        }
    )
    p = cfg.pipeline
    assert p.goal_xy_m == (1500.0, -200.0)
    assert p.declination_deg == 3.5
    assert p.start_heading_rad == pytest.approx(math.pi / 2)  # north
    assert p.estimator.compass_two_sigma_deg == 10.0
    assert p.landmarks[0].name == "church"


def test_no_compass_needs_a_start_heading() -> None:
    doc = _tahoe()
    doc["compass"] = {"enabled": False}
    with pytest.raises(UserError, match=r"\[start\] heading_deg is required"):
        parse_config(doc)
    doc["start"]["heading_deg"] = 270.0
    cfg = parse_config(doc)
    assert cfg.compass is None
    assert cfg.pipeline.estimator.compass_two_sigma_deg is None
    assert cfg.pipeline.start_heading_rad == pytest.approx(math.radians(90 - 270))


BAD = [
    (("goal", "lat_deg"), 123.0, r"\[goal\] lat_deg must be within \[-90.0, 90.0\]"),
    (("goal", "lon_deg"), "east", r"\[goal\] lon_deg must be a number"),
    (("start", "heading_deg"), 400, r"\[start\] heading_deg must be within"),
    (("navigation", "method"), "fastest", r"\[navigation\] method must be one of"),
    (("navigation", "units"), "furlongs", r"\[navigation\] units must be one of"),
    (("navigation", "arrival_radius_m"), -5, r"\[navigation\] arrival_radius_m must be > 0"),
    (("navigation", "stop_at_arrival"), "yes", r"\[navigation\] stop_at_arrival must be true"),
    (("estimator", "compass_two_sigma_deg"), 0, r"\[estimator\] compass_two_sigma_deg must be"),
    (("estimator", "wheel_slip"), 0.1, r"\[estimator\] unknown key\(s\): wheel_slip"),
    (("vehicle", "id"), "my car!", r"\[vehicle\] id"),
    (("vehicle", "track_m"), math.inf, r"\[vehicle\] track_m must be finite"),
    (("odometry", "bitrate"), -1, r"\[odometry\] bitrate must be a positive integer"),
    (("odometry", "bitrate"), "fast", r"\[odometry\] bitrate must be an integer, not 'fast'"),
    (("odometry", "profile"), "ford_t", r"\[odometry\] .*ford_t"),
    (("odometry", "chanel"), "can1", r"\[odometry\] unknown key 'chanel'"),
    (("odometry", "backend"), "lin", r"\[odometry\] backend must be one of can"),
    (("odometry", "clock"), "sundial", r"\[odometry\] clock must be"),
    (("odometry", "expected_rate_hz"), 0, r"\[odometry\] expected_rate_hz must be > 0"),
    (("compass", "baudrate"), 0, r"\[compass\] baudrate must be a positive integer"),
    (("compass", "port"), 7, r"\[compass\] port must be a string, not 7"),
    (("compass", "mounting_offset_deg"), 200, r"\[compass\] mounting_offset_deg must be within"),
    (("compass", "date"), "yesterday", r"\[compass\] date must be a date"),
    (("camera", "source"), [1], r"\[camera\]"),
    (("voice", "backend"), "shout", r"\[voice\] backend must be one of"),
    (("loop", "tick_hz"), 0, r"\[loop\] tick_hz must be > 0"),
    (("checkpoint", "interval_s"), -1, r"\[checkpoint\] interval_s must be > 0"),
    (("telemetry", "mode"), "broadcast", r"\[telemetry\] mode must be one of peer, client, not"),
    (("telemetry", "listn"), [], r"\[telemetry\] unknown key\(s\): listn \(known: "),
    (("recording", "compression"), "zip", r"\[recording\] compression"),
    (("health", "max_reject_fraction"), 2, r"\[health\] max_reject_fraction must be within"),
]


@pytest.mark.parametrize(("where", "value", "message"), BAD, ids=[".".join(b[0]) for b in BAD])
def test_bad_value_names_its_key(where: tuple[str, str], value: object, message: str) -> None:
    doc = _tahoe()
    table, key = where
    doc.setdefault(table, {})[key] = value
    if table == "camera":
        doc["camera"]["enabled"] = True
    with pytest.raises(UserError, match=message) as info:
        parse_config(doc)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"goal": None}, r"\[goal\] is required"),
        ({"gaol": {"x_m": 1}}, r"unknown table\(s\): \[gaol\]"),
        ({"goal": {"lat_deg": 42.0}}, r"\[goal\] lon_deg is required"),
        ({"goal": {"lat_deg": 42.0, "lon_deg": -76.0, "x_m": 3.0}}, r"not both"),
        ({"start": {"x_m": 0.0}}, r"\[compass\] declination_deg is required"),
        (
            {"landmarks": [{"id": 1, "x_m": 0, "y_m": 0}, {"id": 1, "x_m": 5, "y_m": 0}]},
            r"\[landmarks.1\] id",
        ),
        ({"voice": {"backend": "wav"}}, r"\[voice\] wav_path is required"),
    ],
)
def test_bad_structure_is_explained(change: dict[str, Any], message: str) -> None:
    doc = _tahoe()
    for table, value in change.items():
        if value is None:
            doc.pop(table)
        else:
            doc[table] = value
    with pytest.raises(UserError, match=message):
        parse_config(doc)


def test_cli_reports_a_bad_config_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "car.toml"
    bad.write_text(TAHOE.read_text().replace('channel = "can0"', "channel = 0"))
    assert main(["run", "--config", str(bad), "--check"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert f"{bad}: [odometry] channel must be a string, not 0" in err[0]


def test_cli_reports_toml_syntax_and_missing_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "car.toml"
    bad.write_text("[goal\nx_m = 1\n")
    assert main(["run", "--config", str(bad), "--check"]) == 2
    assert "not valid TOML" in capsys.readouterr().err
    assert main(["run", "--config", str(tmp_path / "nope.toml")]) == 2
    assert f"config file {tmp_path / 'nope.toml'}: not found" in capsys.readouterr().err


def test_a_config_that_is_no_regular_file_is_the_door_s_error_not_not_found(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 40 (noticed): ``guidance run`` checked ``is_file()`` before the file door, so a
    FIFO or a folder as the config said "config file not found". Now the door answers, for the
    run and for ``--check`` alike, at once (the FIFO has no writer: nothing waits on it)."""
    fifo = tmp_path / "car.toml"
    os.mkfifo(fifo)
    for path, why in ((fifo, "not a regular file (a FIFO)"), (tmp_path, "not a regular file")):
        for check in ([], ["--check"]):
            assert main(["run", "--config", str(path), *check]) == 2
            err = capsys.readouterr().err.strip().splitlines()
            assert len(err) == 1 and f"config file {path}: {why}" in err[0], err


def test_cli_check_accepts_the_tahoe_config(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["run", "--config", str(TAHOE), "--check"]) == 0
    assert "OK (vehicle tahoe1, method hybrid)" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("table", "value", "message"),
    [
        ("voice", {"rate_wpm": 500}, "[voice] rate_wpm must be within [80, 400], not 500"),
        ("voice", {"rate_wpm": 170.5}, "[voice] rate_wpm must be an integer, not 170.5"),
        ("loop", {"tick_hz": True}, "[loop] tick_hz must be a number, not True"),
        ("health", {"min_reads_for_validity": 3}, "[health] unknown key(s): min_reads_for_valid"),
        ("vehicle", {"track_m": -1.5}, "[vehicle] track_m must be > 0, not -1.5"),
        ("recording", {"directory": 5}, "[recording] directory must be a string, not 5"),
        ("telemetry", {"tls": {"mutual": True}}, "[telemetry.tls] root_ca_certificate is required"),
        ("telemetry", {"listen": ["tcp/a:1", 2]}, "[telemetry] listen[1] must be a string, not 2"),
        ("odometry", {"bitrate": True}, "[odometry] bitrate must be an integer, not True"),
        ("checkpoint", {"path": 1}, "[checkpoint] path must be a string, not 1"),
    ],
)
def test_one_format_table_key_and_what_was_expected(
    table: str, value: dict[str, Any], message: str
) -> None:
    doc = _tahoe()
    doc.setdefault(table, {}).update(value)
    with pytest.raises(UserError) as info:
        parse_config(doc)
    assert str(info.value).startswith(message)


def test_a_bad_file_names_itself(tmp_path: Path) -> None:
    bad = tmp_path / "car.toml"
    bad.write_text(TAHOE.read_text().replace("[voice]", "[voice]\nrate_wpm = true"))
    with pytest.raises(UserError) as info:
        load_config(bad)
    assert str(info.value) == f"{bad}: [voice] rate_wpm must be an integer, not True"


def test_paths_are_relative_to_the_config_files_folder(tmp_path: Path) -> None:
    (tmp_path / "cfg").mkdir()
    path = tmp_path / "cfg" / "car.toml"
    path.write_text(
        "[start]\nx_m = 0.0\ny_m = 0.0\nheading_deg = 90.0\n"
        "[goal]\nx_m = 100.0\ny_m = 0.0\n"
        "[compass]\nenabled = false\n"
        '[checkpoint]\npath = "state/ck.json"\n'
        '[recording]\ndirectory = "rec"\n'
        '[telemetry]\nzenoh_config = "/etc/zenoh.json5"\n'
        '[telemetry.tls]\nroot_ca_certificate = "ca.pem"\n'
    )
    cfg = load_config(path)
    folder = path.resolve().parent
    assert cfg.checkpoint.path == str(folder / "state" / "ck.json")
    assert cfg.recording.directory == str(folder / "rec")
    assert cfg.telemetry.zenoh_config == "/etc/zenoh.json5"  # absolute: as given
    assert cfg.telemetry.tls is not None
    assert cfg.telemetry.tls.root_ca_certificate == str(folder / "ca.pem")
    assert cfg.telemetry.vehicle_id == cfg.recording.vehicle_id == "car1"  # [vehicle] id


def test_the_car_models_turn_scale_prior_is_a_setting_and_is_checked() -> None:
    """``[estimator] turn_scale_sigma``: the car model's default 2 %, a car's own value, and a
    negative one refused naming its key."""
    doc = _tahoe()
    assert parse_config(doc, base_dir=REPO / "config").pipeline.estimator.turn_scale_sigma == 0.02
    doc.setdefault("estimator", {})["turn_scale_sigma"] = 0.005
    assert parse_config(doc, base_dir=REPO / "config").pipeline.estimator.turn_scale_sigma == 0.005
    doc["estimator"]["turn_scale_sigma"] = -0.01
    with pytest.raises(UserError, match=r"\[estimator\] turn_scale_sigma"):
        parse_config(doc, base_dir=REPO / "config")


def test_the_camber_process_is_a_setting_and_is_checked() -> None:
    """``[estimator] camber_diff_sigma`` / ``camber_length_m``: the car model's 0.016 % over
    250 m in place of a walk of the difference, a car's own values (the walk back, say) taken,
    a negative one refused naming its key."""
    doc = _tahoe()
    est = parse_config(doc, base_dir=REPO / "config").pipeline.estimator
    assert (est.camber_diff_sigma, est.camber_length_m, est.diff_walk_var_per_m) == (
        1.6e-4,
        250.0,
        0.0,
    )
    doc.setdefault("estimator", {}).update(camber_diff_sigma=0.0, diff_walk_var_per_m=1e-10)
    est = parse_config(doc, base_dir=REPO / "config").pipeline.estimator
    assert (est.camber_diff_sigma, est.diff_walk_var_per_m) == (0.0, 1e-10)
    doc["estimator"]["camber_length_m"] = -1.0
    with pytest.raises(UserError, match=r"\[estimator\] camber_length_m"):
        parse_config(doc, base_dir=REPO / "config")


def _offered() -> list[tuple[str, str, float]]:
    """Every numeric setting the config file offers from the core's config dataclasses, and a
    value just past each bound of its rule: (table, key, value)."""
    from guidance.config_tables import file_key, rule_of
    from guidance.core.health import HealthConfig
    from guidance.core.localize.estimator import EstimatorConfig
    from guidance.core.pipeline_config import PipelineConfig
    from guidance.core.plan.chance import ChanceSettings
    from guidance.core.plan.navigator import NavigatorConfig

    cases = []
    for cls, table in [(EstimatorConfig, "estimator"), (NavigatorConfig, "navigation"),
                       (HealthConfig, "health"), (ChanceSettings, "chance"),
                       (PipelineConfig, "")]:  # fmt: skip
        for f in dataclasses.fields(cls):
            r = rule_of(cls, f.name)
            where = r.table or table
            if not (r.read and where) or f.name == "compass_deviation_deg":
                continue  # not offered (the deviation card: its own test above)
            key = file_key(f.name, r)
            if r.lo is not None:
                cases.append((where, key, r.lo - max(1e-6, abs(r.lo) * 1e-6)))
            if r.hi is not None:
                cases.append((where, key, r.hi + max(1e-6, abs(r.hi) * 1e-6)))
            if r.positive:
                cases.append((where, key, 0.0))
    return cases


OFFERED = _offered()


@pytest.mark.parametrize(
    ("table", "key", "value"), OFFERED, ids=[f"{t}.{k}" for t, k, _ in OFFERED]
)
def test_every_rule_of_the_cores_config_holds_in_the_config_file(
    table: str, key: str, value: float
) -> None:
    """The rule written on the core's dataclass is the config file's: a value just past it is
    refused in one line naming the table, the key, the rule and the value."""
    doc = _tahoe()
    doc.setdefault(table, {})[key] = value
    with pytest.raises(UserError) as info:
        parse_config(doc, base_dir=REPO / "config")
    text = str(info.value)
    assert text.startswith(f"[{table}] {key} must be ") and repr(value) in text, text
    assert "\n" not in text


def test_fixed_settings_are_not_offered_but_are_recorded() -> None:
    """A field whose rule says ``read=False`` (the gates, the reorder window, the navigator's
    array sizes) is refused in the config file, yet the session record carries and reads it."""
    fixed = [("estimator", "compass_gate_chi2"), ("estimator", "track_m"),
             ("navigation", "max_exits"), ("health", "min_reads_for_validity")]  # fmt: skip
    for table, key in fixed:
        doc = _tahoe()
        doc.setdefault(table, {})[key] = 1
        with pytest.raises(UserError, match=rf"\[{table}\] unknown key\(s\): {key} "):
            parse_config(doc, base_dir=REPO / "config")


@pytest.mark.parametrize("path", [TAHOE, SIM, REPO / "config" / "sim-landmarks.toml"])
def test_a_config_the_file_accepts_is_one_the_session_record_replays(path: Path) -> None:
    """Both boundaries read one set of rules, so the car's configuration recorded in a session
    is read back whole (before, ``[loop] state_rate_hz`` or a device's rate could pass the
    file and be refused by the replay)."""
    from guidance.tools.replay_session import pipeline_config_from_session

    cfg = load_config(path, require_goal=False)
    record = json.loads(json.dumps({"pipeline": cfg.pipeline.describe()}))
    assert pipeline_config_from_session(record) == cfg.pipeline
