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
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from guidance import files
from guidance.app.backends import BACKENDS, import_backend
from guidance.app.landmarks import LandmarkSettings, parse_landmarks_table
from guidance.app.settings import (
    CheckpointSettings,
    DeviceSettings,
    EstimatorSettings,
    LandmarkPlace,
    LoopSettings,
    Place,
    SceneSettings,
    StartSettings,
    VehicleSettings,
    VoiceSettings,
    read_scene,
)
from guidance.app.tables import check_document
from guidance.config_tables import Rule, field_default, file_keys, from_table, names_where
from guidance.core.geo import LatLon, Origin
from guidance.core.health import HealthConfig
from guidance.core.localize.car_model import PROFILE_TRACK_TURN_SIGMA, car_model
from guidance.core.localize.estimator import EstimatorConfig
from guidance.core.localize.gyro import GyroConfig
from guidance.core.pipeline import PipelineConfig
from guidance.core.plan.chance import ChanceSettings
from guidance.core.plan.navigator import Landmark, NavigatorConfig
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
    """A device table: ``DeviceSettings`` (``backend``, ``enabled``, ``expected_rate_hz``),
    then the driver's keys (its config dataclass, read by ``from_table``). A disabled device's
    other keys are not read."""
    if not isinstance(data, Mapping):
        raise UserError(f"[{kind}] must be a table")
    common = {k: v for k, v in data.items() if k in _DEVICE_KEYS}
    base = DeviceSettings(default_enabled, default_backend, DEFAULT_RATES_HZ[kind])
    enabled = {k: v for k, v in common.items() if k == "enabled"}
    if not from_table(DeviceSettings, enabled, kind, base=base).enabled:
        return None
    backends = {"backend": Rule(choices=tuple(BACKENDS[kind]))}
    dev = from_table(DeviceSettings, common, kind, base=base, rules=backends)
    _, cfg_path = BACKENDS[kind][dev.backend]
    cfg_cls = import_backend(cfg_path)
    fields = {f.name for f in dataclasses.fields(cfg_cls)}
    app_keys = _DEVICE_KEYS | _APP_DEVICE_KEYS.get(kind, set())
    own = {k: v for k, v in data.items() if k not in app_keys}
    for key in own:
        if key not in fields:
            raise UserError(
                f"[{kind}] unknown key {key!r} for backend {dev.backend!r}; "
                f"known: {', '.join(sorted(fields | app_keys))}"
            )
    cfg = from_table(cfg_cls, own, kind, base_dir)
    return DeviceConfig(kind, dev.backend, cfg, dev.expected_rate_hz)


_DEVICE_KEYS = set(file_keys(DeviceSettings))
_COMPASS_KEYS = set(file_keys(PipelineConfig, "compass"))
"""``[compass]``'s keys for the pipeline (``PipelineConfig``'s fields the rule puts there)."""
_APP_DEVICE_KEYS = {"compass": {*_COMPASS_KEYS, "date"}}


def _place(data: object, where: str, origin: LatLon | None, cls: type[Place] = Place) -> Any:
    """A ``[start]``/``[goal]``/``[[landmarks]]`` table and its local (x, y): from latitude
    and longitude around ``origin`` (none yet: the place is the origin), or local metres."""
    p = from_table(cls, data, where)
    if p.geodetic and p.local:
        raise UserError(f"[{where}] give lat_deg/lon_deg or x_m/y_m, not both")
    if where == "goal" and not (p.geodetic or p.local):
        raise UserError("[goal] needs lat_deg/lon_deg or x_m/y_m")
    if not p.geodetic:
        return p, (p.x_m or 0.0, p.y_m or 0.0)
    lat, lon = p.lat_deg, p.lon_deg
    if lat is None or lon is None:
        raise UserError(f"[{where}] {'lat_deg' if lat is None else 'lon_deg'} is required")
    return p, (0.0, 0.0) if origin is None else Origin.of(origin).to_local(lat, lon)


@dataclass(frozen=True, slots=True)
class _Trip:
    start: StartSettings
    start_xy: tuple[float, float]
    goal_xy: tuple[float, float] | None
    """None: no ``[goal]`` (allowed where ``require_goal`` is false)."""
    origin: LatLon | None
    """The local frame's WGS-84 origin: the start's latitude and longitude (start anywhere:
    the goal's)."""
    unknown: bool
    """Start anywhere: the car starts unplaced, waiting at the goal for its first landmark."""


def _trip(data: Mapping[str, Any], require_goal: bool) -> _Trip:
    """``[start]`` and ``[goal]``. A ``[start]`` with no position (``unknown = true``, or none
    and a goal on the globe, whose place is then the frame's origin) starts the car unplaced."""
    start, start_xy = _place(data.get("start", {}), "start", None, StartSettings)
    placed = start.geodetic or start.local
    if start.unknown and placed:
        raise UserError("[start] unknown = true and a position: give one or the other")
    origin, unknown = _lat_lon(start), start.unknown
    if "goal" not in data and require_goal:
        raise UserError("[goal] is required (lat_deg/lon_deg or x_m/y_m)")
    goal_xy: tuple[float, float] | None = None
    if "goal" in data:
        goal, goal_xy = _place(data["goal"], "goal", origin)
        if not placed and origin is None and goal.geodetic:
            origin, unknown = _lat_lon(goal), True  # start anywhere: the frame is the goal's
    waits = goal_xy if unknown and goal_xy is not None else start_xy  # start anywhere: at the goal
    return _Trip(start, waits, goal_xy, origin, unknown)


def _lat_lon(p: Place) -> LatLon | None:
    return None if p.lat_deg is None or p.lon_deg is None else (p.lat_deg, p.lon_deg)


def _relocalise(
    trip: _Trip, camera: DeviceConfig | None, landmark_db: LandmarkSettings | None
) -> bool:
    """A car with a camera and a landmark database finds itself again when lost; a car that
    starts unplaced must."""
    relocalise = camera is not None and landmark_db is not None
    if trip.unknown and not relocalise:
        raise UserError(
            "[start] gives no position, so the car must find itself: that needs a camera "
            "([camera] enabled = true) and a landmark database ([landmarks] database = ...)"
        )
    return relocalise


def _estimator(
    data: object,
    track_m: float,
    *,
    compass: bool,
    calibrated: bool,
    yaw_source: str = "wheels",
    track_given: bool = True,
) -> EstimatorConfig:
    """``[estimator]``: ``EstimatorConfig``'s offered fields by their rules, ``model`` (car or
    paper) and ``compass_two_sigma_deg = false`` (no compass). The car model's defaults come
    first (``car_model``), then the table's car keys and ``initial_position_sigma_m``; its
    ``wheel_quantum_m`` and ``wheel_slip_frac`` apply to the paper model only (the car model
    has neither: speeds on CAN are not counts). A car key needs ``model = "car"``."""
    if not isinstance(data, Mapping):
        raise UserError("[estimator] must be a table")
    table = {k: v for k, v in data.items() if k != "model"}
    picked = {k: v for k, v in data.items() if k == "model"}
    model = from_table(EstimatorSettings, picked, "estimator", others=tuple(table)).model
    if table.get("compass_two_sigma_deg") is False:
        table["compass_two_sigma_deg"] = None
    given = from_table(EstimatorConfig, table, "estimator", others=("model",))
    user = {k: getattr(given, k) for k in table}
    car = set(names_where(EstimatorConfig, group="car"))
    for key in sorted(car & set(user)) if model != "car" else ():
        raise UserError(f'[estimator] {key} needs model = "car"')
    sigma = user.pop("compass_two_sigma_deg", given.compass_two_sigma_deg)
    sigma = sigma if compass else None
    paper = {k: v for k, v in user.items() if k not in car}
    base = replace(EstimatorConfig(), **paper, track_m=track_m, compass_two_sigma_deg=sigma)
    if model != "car":
        if yaw_source != "wheels":
            raise UserError(
                f'[vehicle] yaw_source = "{yaw_source}" needs [estimator] model = "car"'
            )
        return base
    overrides = {k: v for k, v in user.items() if k in car or k == "initial_position_sigma_m"}
    if not track_given:  # a profile's track, not the car's own (docs/estimation.md)
        overrides.setdefault("turn_scale_sigma", PROFILE_TRACK_TURN_SIGMA)
    est = car_model(base, calibrated=calibrated, **overrides)
    if yaw_source == "wheels":
        return est
    return replace(est, gyro=GyroConfig(with_wheels=yaw_source == "both"))


GYRO_RATE_HZ = 10.0
"""The rate the gyro's health expects at least (``[vehicle] yaw_source`` "gyro" or "both"):
a stability control runs its yaw loop at 50-100 Hz and sends the rate as often (the RAV4's
``KINEMATICS`` at 83 Hz); silent after max(1 s, 5 periods) like every input."""


def _with_yaw_rate(vehicle: VehicleSettings, odometry: DeviceConfig | None) -> DeviceConfig | None:
    """The CAN odometry of a gyro car also delivers the yaw rate (``CanOdometryConfig.yaw_rate``,
    refused at start when the profile names no yaw-rate signal)."""
    if vehicle.yaw_source == "wheels" or odometry is None or odometry.backend != "can":
        return odometry
    return replace(odometry, config=replace(odometry.config, yaw_rate=True))


def _rates(
    devices: Mapping[str, DeviceConfig | None], vehicle: VehicleSettings
) -> dict[str, float | None]:
    """The inputs the health monitor expects, at their rates: the devices, and the gyro."""
    rates = {k: d.expected_rate_hz for k, d in devices.items() if d is not None}
    if vehicle.yaw_source != "wheels" and "odometry" in rates:  # read from the same bus
        rates["gyro"] = GYRO_RATE_HZ
    return rates


def _compass(
    pipeline: PipelineConfig,
    data: object,
    compass: DeviceConfig | None,
    origin: LatLon | None,
    default_date: dt.date | None,
) -> PipelineConfig:
    """``[compass]``'s keys for the pipeline (mounting, declination, the deviation card, when
    it is unusable) by ``PipelineConfig``'s rules; the declination from the World Magnetic
    Model at the start and ``date`` when not given."""
    table = data if isinstance(data, Mapping) else {}
    mine = {k: v for k, v in table.items() if k in _COMPASS_KEYS}
    out = from_table(PipelineConfig, mine, "compass", part="compass", base=pipeline)
    if "deviation_deg" in mine:
        out = replace(out, compass_deviation_deg=_deviation(out.compass_deviation_deg))
    given = table.get("date")
    when = default_date if given is None and default_date else _date(given, "[compass] date")
    if "declination_deg" in mine:
        return out
    if compass is not None and origin is None:
        raise UserError(
            "[compass] declination_deg is required when [start] has no lat_deg/lon_deg "
            "(the World Magnetic Model needs the place)"
        )
    if origin is None:
        return out
    from guidance.app.magnetic import declination_deg

    return replace(out, declination_deg=declination_deg(origin[0], origin[1], when))


def _deviation(card: tuple[float, ...]) -> tuple[float, ...]:
    """``[compass] deviation_deg = [A, B, C, D, E]`` (``guidance calibrate`` writes it)."""
    from guidance.core.localize.compass_cal import CompassCalibration

    if len(card) != 5:
        raise UserError("[compass] deviation_deg must be a list of 5 numbers [A, B, C, D, E]")
    keys = ("a_deg", "b_deg", "c_deg", "d_deg", "e_deg")
    try:
        cal = CompassCalibration.from_mapping(dict(zip(keys, card, strict=True)))
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


def _track_m(vehicle: VehicleSettings, odometry: DeviceConfig | None) -> float:
    """``[vehicle] track_m``, else the ``[odometry] profile``'s (issue 12), else the default."""
    if vehicle.track_m is not None:
        return vehicle.track_m
    profile = getattr(odometry.config, "profile", None) if odometry else None
    return profile_track_m(profile) if isinstance(profile, str) else _DEFAULT_TRACK_M


_DEFAULT_TRACK_M: float = field_default(EstimatorConfig, "track_m")


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
    check_document(data, TABLES)
    t = {name: data.get(name, {}) for name in TABLES}
    vehicle = from_table(VehicleSettings, t["vehicle"], "vehicle")
    trip = _trip(data, require_goal)
    origin = trip.origin
    nav_keys = file_keys(PipelineConfig, "navigation")
    navigator = from_table(NavigatorConfig, t["navigation"], "navigation", others=nav_keys)
    odometry = _with_yaw_rate(vehicle, _device("odometry", t["odometry"], base_dir,
                                               default_backend="can"))  # fmt: skip
    compass = _device("compass", t["compass"], base_dir, default_backend="nmea_serial")
    camera = _device("camera", t["camera"], base_dir, default_backend="opencv",
                     default_enabled=False)  # fmt: skip
    devices = {"odometry": odometry, "compass": compass, "camera": camera}
    loop = from_table(LoopSettings, t["loop"], "loop")
    landmark_db, landmarks = _landmarks(data.get("landmarks", []), origin, base_dir)
    pipeline = PipelineConfig(
        estimator=EstimatorConfig(),
        navigator=navigator,
        start_xy_m=trip.start_xy,
        goal_xy_m=trip.goal_xy,
        start_heading_rad=_heading_rad(trip.start.heading_deg),
        landmarks=landmarks,
        state_period_s=1.0 / loop.state_rate_hz,
        expected_rates_hz=_rates(devices, vehicle),
        health=from_table(HealthConfig, t["health"], "health"),
        chance=from_table(ChanceSettings, t["chance"], "chance"),
        relocalise=_relocalise(trip, camera, landmark_db),
        start_unknown=trip.unknown,
    )
    pipeline = from_table(PipelineConfig, t["navigation"], "navigation", part="navigation",
                          others=file_keys(NavigatorConfig), base=pipeline)  # fmt: skip
    pipeline = _compass(pipeline, t["compass"], compass, origin, default_date)
    calibrated = bool(any(pipeline.compass_deviation_deg) or pipeline.mounting_offset_deg)
    estimator = _estimator(t["estimator"], _track_m(vehicle, odometry), compass=compass is not None,
                           calibrated=calibrated, yaw_source=vehicle.yaw_source,
                           track_given=vehicle.track_m is not None)  # fmt: skip
    if estimator.compass_two_sigma_deg is None and trip.start.heading_deg is None:
        raise UserError(
            "[start] heading_deg is required when there is no compass (or "
            "compass_two_sigma_deg = false): the heading could never become known"
        )
    return AppConfig(
        path=path,
        vehicle_id=_vehicle_id(vehicle),
        pipeline=replace(pipeline, estimator=estimator),
        origin_lat_lon_deg=origin,
        odometry=odometry,
        compass=compass,
        camera=camera,
        scene=read_scene(t["scene"], base_dir),
        voice=from_table(VoiceSettings, t["voice"], "voice", base_dir),
        telemetry=_output(TelemetryConfig, t["telemetry"], "telemetry", base_dir, vehicle, origin),
        recording=_output(RecordingConfig, t["recording"], "recording", base_dir, vehicle, origin),
        checkpoint=from_table(CheckpointSettings, t["checkpoint"], "checkpoint", base_dir),
        loop=loop,
        sim=_sim(t["sim"]),
        landmark_db=landmark_db,
        ros2=from_table(Ros2Config, t["ros2"], "ros2"),
    )


def _heading_rad(heading_deg: float | None) -> float | None:
    """A true heading (degrees clockwise from north) as the local frame's angle."""
    return None if heading_deg is None else math.radians(90.0 - heading_deg)


def _vehicle_id(vehicle: VehicleSettings) -> str:
    try:
        validate_vehicle_id(vehicle.id)
    except UserError as exc:
        raise UserError(f"[vehicle] id: {exc}") from None
    return vehicle.id


def _output(
    cls: Any, data: object, where: str, base_dir: Path | None, vehicle: VehicleSettings,
    origin: LatLon | None,
) -> Any:  # fmt: skip
    """``[telemetry]``/``[recording]``: ``vehicle_id`` defaults to ``[vehicle] id``, the origin
    is ``[start]``'s."""
    base = cls(vehicle_id=vehicle.id, origin_lat_lon_deg=origin)
    return from_table(cls, data, where, base_dir, base=base)


def _sim(data: object) -> Mapping[str, Any]:
    """``[sim]``: read by ``guidance sim`` only (``hal_sim.drive_options``)."""
    if not isinstance(data, Mapping):
        raise UserError("[sim] must be a table")
    return types.MappingProxyType(dict(data))


def _landmarks(
    data: object, origin: LatLon | None, base_dir: Path | None
) -> tuple[LandmarkSettings | None, tuple[Landmark, ...]]:
    """``[landmarks]`` (a database and its matcher; its landmarks are read when the car
    starts) or ``[[landmarks]]`` (positions only: id, name, and lat_deg/lon_deg or x_m/y_m)."""
    if isinstance(data, Mapping):
        return parse_landmarks_table(data, base_dir), ()
    if not isinstance(data, list):
        raise UserError("[[landmarks]] must be an array of tables")
    out = []
    seen: set[int] = set()
    for i, item in enumerate(data):
        where = f"landmarks.{i}"
        if not isinstance(item, Mapping):
            raise UserError(f"[{where}] must be a table")
        lid = item.get("id", i)
        if not isinstance(lid, int) or isinstance(lid, bool) or lid in seen:
            raise UserError(f"[{where}] id must be a unique integer, not {lid!r}")
        seen.add(lid)
        geodetic = "lat_deg" in item or "lon_deg" in item
        if geodetic and origin is None:
            raise UserError(f"[{where}] lat_deg/lon_deg need [start] lat_deg/lon_deg")
        if not geodetic and not ("x_m" in item and "y_m" in item):
            raise UserError(f"[{where}] needs a position: lat_deg/lon_deg or x_m and y_m")
        p, (x, y) = _place(item, where, origin, LandmarkPlace)
        out.append(Landmark(lid, x, y, p.name))
    return None, tuple(out)
