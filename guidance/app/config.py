"""The car's TOML configuration, validated at start (docs/app.md, "Configuration").

``load_config(path)`` reads the file with ``tomllib`` and returns an ``AppConfig``; any bad
value raises ``UserError`` with one line that names the key (``[goal] lat_deg must be within
[-90, 90], not 123.0``). Unknown tables and keys are errors too: a typo must not silently
fall back to a default in a moving car.

Start and goal are latitude/longitude (converted to the local east-north frame around the
start with pymap3d) or local metres. Devices are chosen by name in the configuration only
(HOUSE_STYLE): ``BACKENDS`` maps ``[odometry] backend = "can"`` to the driver class and its
config dataclass, imported on first use, so this module knows no hardware.
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import math
import tomllib
import types
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from guidance import files
from guidance.app.backends import BACKENDS, import_backend
from guidance.app.landmarks import LandmarkSettings, parse_landmarks_table
from guidance.app.settings import (
    HEALTH_RULES,
    CheckpointSettings,
    LoopSettings,
    NavigationSettings,
    SceneSettings,
    VehicleSettings,
    VoiceSettings,
    read_scene,
)
from guidance.app.tables import _check_document, _Table
from guidance.config_tables import field_default, from_table, key_name
from guidance.core.geo import Origin
from guidance.core.health import HealthConfig
from guidance.core.localize.car_model import car_model
from guidance.core.localize.estimator import EstimatorConfig
from guidance.core.pipeline import PipelineConfig
from guidance.core.plan.chance import ChanceSettings
from guidance.core.plan.navigator import Landmark
from guidance.errors import UserError
from guidance.recording.config import RecordingConfig
from guidance.telemetry.config import Ros2Config, TelemetryConfig
from guidance.telemetry.keys import validate_vehicle_id

DEFAULT_RATES_HZ = {"odometry": 20.0, "compass": 5.0, "camera": 10.0}
TABLES = (
    "vehicle",
    "start",
    "goal",
    "navigation",
    "estimator",
    "odometry",
    "compass",
    "camera",
    "scene",
    "voice",
    "health",
    "chance",
    "loop",
    "checkpoint",
    "telemetry",
    "ros2",
    "recording",
    "landmarks",
    "sim",
)


@dataclass(frozen=True, slots=True)
class DeviceConfig:
    """One device: its backend name, the driver's own config object and the expected rate."""

    kind: str
    backend: str
    config: Any
    expected_rate_hz: float | None

    def build(self, **kwargs: Any) -> Any:
        """Construct the driver (imports it now)."""
        cls_path, _ = BACKENDS[self.kind][self.backend]
        return import_backend(cls_path)(self.config, **kwargs)


@dataclass(frozen=True, slots=True)
class AppConfig:
    """The validated configuration of one run."""

    path: str
    vehicle_id: str
    pipeline: PipelineConfig
    origin_lat_lon_deg: tuple[float, float] | None
    odometry: DeviceConfig | None
    compass: DeviceConfig | None
    camera: DeviceConfig | None
    scene: SceneSettings
    voice: VoiceSettings
    telemetry: TelemetryConfig
    recording: RecordingConfig
    checkpoint: CheckpointSettings
    loop: LoopSettings = field(default_factory=LoopSettings)
    sim: Mapping[str, Any] = field(default_factory=dict)
    """The ``[sim]`` table, read by ``guidance sim`` only."""
    landmark_db: LandmarkSettings | None = None
    """``[landmarks] database``: landmark updates from the camera (guidance/app/landmarks.py)."""
    ros2: Ros2Config = field(default_factory=Ros2Config)
    """``[ros2]``: the estimate as ROS 2 messages over Zenoh (off by default)."""


def _device(
    kind: str,
    data: object,
    base_dir: Path | None,
    *,
    default_backend: str,
    default_enabled: bool = True,
) -> DeviceConfig | None:
    """A device table: ``backend``, ``enabled``, ``expected_rate_hz``, then the driver's keys
    (its config dataclass, read by ``from_table``)."""
    t = _Table(kind, data)
    if not t.boolean("enabled", default_enabled):
        t.used.update(t.data)
        return None
    backend = t.string("backend", default_backend, tuple(BACKENDS[kind]))
    rate = t.number("expected_rate_hz", DEFAULT_RATES_HZ[kind], positive=True)
    _, cfg_path = BACKENDS[kind][backend]
    cfg_cls = import_backend(cfg_path)
    fields = {f.name for f in dataclasses.fields(cfg_cls)}
    app_keys = {"enabled", "backend", "expected_rate_hz"} | _APP_DEVICE_KEYS.get(kind, set())
    own = {k: v for k, v in t.data.items() if k not in app_keys}
    for key in own:
        if key not in fields:
            raise UserError(
                f"[{kind}] unknown key {key!r} for backend {backend!r}; "
                f"known: {', '.join(sorted(fields | app_keys))}"
            )
    return DeviceConfig(kind, backend, from_table(cfg_cls, own, kind, base_dir), rate)


_APP_DEVICE_KEYS = {
    "compass": {
        "mounting_offset_deg",
        "declination_deg",
        "date",
        "deviation_deg",
        "unusable_after_s",
    }
}


def _point(
    t: _Table, origin: tuple[float, float] | None
) -> tuple[tuple[float, float], tuple[float, float] | None]:
    """Local (x, y) of a [start]/[goal] table and its (lat, lon) when given."""
    has_geo = t.has("lat_deg") or t.has("lon_deg")
    has_xy = t.has("x_m") or t.has("y_m")
    if has_geo and has_xy:
        raise UserError(f"[{t.name}] give lat_deg/lon_deg or x_m/y_m, not both")
    if has_geo:
        lat = t.req_number("lat_deg", lo=-90.0, hi=90.0)
        lon = t.req_number("lon_deg", lo=-180.0, hi=180.0)
        if origin is None:
            return (0.0, 0.0), (lat, lon)
        return Origin.of(origin).to_local(lat, lon), (lat, lon)
    x = t.number("x_m", 0.0)
    y = t.number("y_m", 0.0)
    assert x is not None and y is not None
    if t.name == "goal" and not has_xy:
        raise UserError("[goal] needs lat_deg/lon_deg or x_m/y_m")
    return (x, y), None


CAR_KEYS = (
    "wheel_walk_var_m2_per_m",
    "scale_sigma",
    "diff_sigma",
    "diff_walk_var_per_m",
    "camber_diff_sigma",
    "camber_length_m",
    "turn_scale_sigma",
    "compass_bias_sigma_deg",
    "compass_bias_walk_deg2_per_s",
    "compass_bias_turn_deg2_per_rad",
    "heading_second_order",
)
"""The car model's settings in ``[estimator]`` (docs/estimation.md)."""


def _deviation(value: object) -> tuple[float, ...]:
    """``[compass] deviation_deg = [A, B, C, D, E]`` (``guidance calibrate`` writes it)."""
    if value is None:
        return ()
    from guidance.core.localize.compass_cal import CompassCalibration

    if not isinstance(value, list) or len(value) != 5:
        raise UserError("[compass] deviation_deg must be a list of 5 numbers [A, B, C, D, E]")
    keys = ("a_deg", "b_deg", "c_deg", "d_deg", "e_deg")
    try:
        cal = CompassCalibration.from_mapping(dict(zip(keys, value, strict=True)))
    except (TypeError, ValueError) as exc:
        raise UserError(f"[compass] deviation_deg: {exc}") from None
    return (cal.a_deg, cal.b_deg, cal.c_deg, cal.d_deg, cal.e_deg)


def profile_track_m(profile: str) -> float:
    """The rear track width of a CAN vehicle profile (named, imported on first use)."""
    if profile == "auto":  # known only once the car's frames arrive (drivers.can_identify)
        raise UserError(
            '[odometry] profile = "auto": set [vehicle] track_m (the rear track, metres): '
            "the profile, and its track, are known only once the bus is heard"
        )
    get_profile = import_backend("drivers.profiles:get_profile")
    return float(get_profile(profile).track_width_m)


def _date(value: object, where: str) -> dt.date:
    if value is None:
        return dt.datetime.now(dt.UTC).date()
    if isinstance(value, dt.date):
        return value
    if isinstance(value, str):
        try:
            return dt.date.fromisoformat(value)
        except ValueError:
            pass
    raise UserError(f"{where} must be a date (2026-05-01), not {value!r}")


# ----------------------------------------------------------------------------- loading


def load_config(
    path: str | Path, *, require_goal: bool = True, default_date: dt.date | None = None
) -> AppConfig:
    """Read and validate a TOML configuration file."""
    p = Path(path)
    text = files.read_bytes(p, "config")
    try:
        data = tomllib.loads(text.decode("utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise UserError(f"{p}: not valid TOML: {exc}") from None
    try:
        return parse_config(
            data,
            base_dir=p.resolve().parent,
            path=str(p),
            require_goal=require_goal,
            default_date=default_date,
        )
    except UserError as exc:  # one format: the file, then [table] key and what was expected
        raise UserError(f"{p}: {exc}") from None


def parse_config(
    data: Mapping[str, Any],
    *,
    base_dir: Path | None = None,
    path: str = "<config>",
    require_goal: bool = True,
    default_date: dt.date | None = None,
) -> AppConfig:
    """Validate a parsed TOML document (a dict) into an ``AppConfig``.

    ``require_goal=False`` (the simulator, which draws its own goal) allows no ``[goal]``.
    """
    _check_document(data)
    unknown = sorted(set(data) - set(TABLES))
    if unknown:
        raise UserError(f"unknown table(s): {', '.join(f'[{key_name(u)}]' for u in unknown)}")

    vehicle = from_table(VehicleSettings, data.get("vehicle", {}), "vehicle")
    vehicle_id, track = vehicle.id, vehicle.track_m
    try:
        validate_vehicle_id(vehicle_id)
    except UserError as exc:
        raise UserError(f"[vehicle] id: {exc}") from None

    start = _Table("start", data.get("start", {}))
    (sx, sy), origin = _point(start, None)
    start_heading = start.number("heading_deg", None, lo=0.0, hi=360.0)
    """True heading, degrees clockwise from north (None: from the first compass reading)."""
    start.done()

    if "goal" not in data and require_goal:
        raise UserError("[goal] is required (lat_deg/lon_deg or x_m/y_m)")
    gx = gy = 0.0
    if "goal" in data:
        goal_t = _Table("goal", data["goal"])
        (gx, gy), _ = _point(goal_t, origin)
        goal_t.done()

    nav = from_table(NavigationSettings, data.get("navigation", {}), "navigation")

    est = _Table("estimator", data.get("estimator", {}))
    compass_sigma: float | None
    default_sigma = field_default(EstimatorConfig, "compass_two_sigma_deg")
    if est.get("compass_two_sigma_deg", default_sigma) is False:
        compass_sigma = None
    else:
        compass_sigma = est.number("compass_two_sigma_deg", default_sigma, positive=True)
    noise_model = est.string("model", "car", ("car", "paper"))
    est_kwargs: dict[str, Any] = {"compass_two_sigma_deg": compass_sigma}
    for key in (
        "wheel_quantum_m",
        "wheel_slip_frac",
        "lost_major_axis_m",
        "initial_position_sigma_m",
        "initial_heading_sigma_deg",
        "max_wheel_step_m",
    ):
        if est.has(key):
            est_kwargs[key] = est.number(key, positive=True)
    car_overrides: dict[str, float] = {}
    if noise_model == "car" and "initial_position_sigma_m" in est_kwargs:
        car_overrides["initial_position_sigma_m"] = est_kwargs["initial_position_sigma_m"]
    for key in CAR_KEYS:
        if est.has(key):
            if noise_model != "car":
                raise UserError(f'[estimator] {key} needs model = "car"')
            car_overrides[key] = est.number(key, lo=0.0) or 0.0
    est.done()

    odometry = _device("odometry", data.get("odometry", {}), base_dir, default_backend="can")
    compass_table = data.get("compass", {})
    compass = _device("compass", compass_table, base_dir, default_backend="nmea_serial")
    if compass is None:
        compass_sigma = None
        est_kwargs["compass_two_sigma_deg"] = None
    ct = _Table("compass", compass_table)
    mounting = ct.number("mounting_offset_deg", 0.0, lo=-180.0, hi=180.0) or 0.0
    declination = ct.number("declination_deg", None, lo=-180.0, hi=180.0)
    deviation = _deviation(ct.get("deviation_deg"))
    unusable_default = field_default(PipelineConfig, "compass_unusable_after_s")
    unusable_after = ct.number("unusable_after_s", unusable_default, positive=True)
    when = (
        default_date
        if ct.get("date") is None and default_date
        else _date(ct.get("date"), "[compass] date")
    )
    if declination is None:
        if compass is not None and origin is None:
            raise UserError(
                "[compass] declination_deg is required when [start] has no lat_deg/lon_deg "
                "(the World Magnetic Model needs the place)"
            )
        if origin is not None:
            from guidance.app.magnetic import declination_deg

            declination = declination_deg(origin[0], origin[1], when)
    if (compass is None or compass_sigma is None) and start_heading is None:
        raise UserError(
            "[start] heading_deg is required when there is no compass (or "
            "compass_two_sigma_deg = false): the heading could never become known"
        )
    camera = _device("camera", data.get("camera", {}), base_dir, default_backend="opencv",
                     default_enabled=False)  # fmt: skip

    scene = read_scene(data.get("scene", {}), base_dir)

    voice = from_table(VoiceSettings, data.get("voice", {}), "voice", base_dir)
    if voice.backend == "wav" and not voice.wav_path:
        raise UserError("[voice] wav_path is required with backend = 'wav'")
    health = from_table(HealthConfig, data.get("health", {}), "health", rules=HEALTH_RULES)
    loop = from_table(LoopSettings, data.get("loop", {}), "loop")
    chance = from_table(ChanceSettings, data.get("chance", {}), "chance")
    checkpoint = from_table(CheckpointSettings, data.get("checkpoint", {}), "checkpoint", base_dir)

    # [telemetry] and [recording]: vehicle_id defaults to [vehicle] id; the origin is [start]'s.
    telemetry = from_table(
        TelemetryConfig,
        data.get("telemetry", {}),
        "telemetry",
        base_dir,
        base=TelemetryConfig(vehicle_id=vehicle_id, origin_lat_lon_deg=origin),
    )
    recording = from_table(
        RecordingConfig,
        data.get("recording", {}),
        "recording",
        base_dir,
        base=RecordingConfig(vehicle_id=vehicle_id, origin_lat_lon_deg=origin),
    )

    landmark_db = None
    if isinstance(data.get("landmarks"), Mapping):  # [landmarks]: a database and its matcher
        landmark_db = parse_landmarks_table(data["landmarks"], base_dir)
        landmarks: tuple[Landmark, ...] = ()  # read from the database when the car starts
    else:  # [[landmarks]]: positions only
        landmarks = _landmarks(data.get("landmarks", []), origin)

    rates: dict[str, float | None] = {}
    if odometry is not None:
        rates["odometry"] = odometry.expected_rate_hz
    if compass is not None:
        rates["compass"] = compass.expected_rate_hz
    if camera is not None:
        rates["camera"] = camera.expected_rate_hz
    profile_name = getattr(odometry.config, "profile", None) if odometry else None
    if track is None:  # the vehicle profile knows the car's track (issue 12)
        track = profile_track_m(profile_name) if isinstance(profile_name, str) else 1.72
    est_kwargs["track_m"] = track
    est_config = EstimatorConfig(**est_kwargs)
    if noise_model == "car":
        calibrated = bool(any(deviation) or mounting)
        est_config = car_model(est_config, calibrated=calibrated, **car_overrides)
    pipeline = PipelineConfig(
        estimator=est_config,
        navigator=nav.navigator(),
        start_xy_m=(sx, sy),
        goal_xy_m=(gx, gy),
        start_heading_rad=(None if start_heading is None else math.radians(90.0 - start_heading)),
        landmarks=landmarks,
        declination_deg=declination or 0.0,
        mounting_offset_deg=mounting,
        compass_deviation_deg=deviation,
        compass_unusable_after_s=unusable_after or unusable_default,
        units=nav.units,
        state_period_s=1.0 / loop.state_rate_hz,
        expected_rates_hz=rates,
        health=health,
        straight_after_m=nav.straight_after_m,
        uncertain_warn_m=nav.uncertain_warn_m,
        stop_at_arrival=nav.stop_at_arrival,
        chance=chance,
    )
    sim = data.get("sim", {})
    if not isinstance(sim, Mapping):
        raise UserError("[sim] must be a table")
    return AppConfig(
        path=path,
        vehicle_id=vehicle_id,
        pipeline=pipeline,
        origin_lat_lon_deg=origin,
        odometry=odometry,
        compass=compass,
        camera=camera,
        scene=scene,
        voice=voice,
        telemetry=telemetry,
        recording=recording,
        checkpoint=checkpoint,
        loop=loop,
        sim=types.MappingProxyType(dict(sim)),
        landmark_db=landmark_db,
        ros2=from_table(Ros2Config, data.get("ros2", {}), "ros2"),
    )


def _landmarks(items: object, origin: tuple[float, float] | None) -> tuple[Landmark, ...]:
    """``[[landmarks]]`` entries: id, name, and lat_deg/lon_deg or x_m/y_m."""
    if not isinstance(items, list):
        raise UserError("[[landmarks]] must be an array of tables")
    out = []
    seen: set[int] = set()
    for i, item in enumerate(items):
        t = _Table(f"landmarks.{i}", item)
        lid = t.get("id", i)
        if not isinstance(lid, int) or isinstance(lid, bool) or lid in seen:
            raise UserError(f"[landmarks.{i}] id must be a unique integer, not {lid!r}")
        seen.add(lid)
        name = t.string("name", "")
        if (t.has("lat_deg") or t.has("lon_deg")) and origin is None:
            raise UserError(f"[landmarks.{i}] lat_deg/lon_deg need [start] lat_deg/lon_deg")
        if not (t.has("lat_deg") or t.has("lon_deg")) and not (t.has("x_m") and t.has("y_m")):
            raise UserError(f"[landmarks.{i}] needs a position: lat_deg/lon_deg or x_m and y_m")
        (x, y), _ = _point(t, origin)
        t.done()
        out.append(Landmark(lid, x, y, name))
    return tuple(out)
