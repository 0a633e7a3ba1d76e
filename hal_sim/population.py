"""A population of simulated cars with the errors real cars have, for the estimator's honesty.

An estimator's honesty is a property of many cars, not of one drive (issue 21). Each car here
gets persistent errors drawn as a real car's (``hal_sim.car_errors``), drives a random route
through a simulated city (the world of ``hal_sim.world``; at each intersection a random exit),
and its wheel increments and compass readings are made from the true motion with *its* errors
(``hal_sim.car_errors.CarSensors``: the simulated car's one sensor-error model), sent as the
car's devices send them and decoded by the car's own decoders (``hal_sim.car_inputs``: CAN frames
through ``WheelSpeedDecoder`` and, a gyro car's, ``YawRateDecoder``, NMEA through the compass
parser), then fed to the car's ``Localizer`` with the car model as a car nobody calibrated is
configured (``guidance.core.localize.car_model``, no deviation card). Per car: the truth inside
the 2-sigma ellipse, the NEES, the along/across split, the true error when "lost" is declared.

The cars' errors and their draws are the car model's (``hal_sim.car_errors``: ``CarErrors``,
``draw_car`` heavier-tailed than the filter's priors, ``draw_matched_car`` from them, gyro
cars' ``draw_gyro``); with ``stops``, a car stops at intersections for realistic lengths
(``hal_sim.gyro_cars``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.stats import chi2

from guidance.core.localize.car_model import car_model
from guidance.core.localize.estimator import EstimatorConfig
from guidance.core.localize.gyro import GyroConfig
from guidance.core.localize.learned import LearnedParams
from guidance.core.localize.localizer import Localizer, LocalizerConfig
from guidance.core.messages import EstimateState, LandmarkFix
from guidance.core.model import CHI2_2D_2SIGMA, mahalanobis_sq_2d, wrap_angle
from guidance.core.plan.navigator import NavigatorConfig
from hal_sim import world as world_mod
from hal_sim.car_errors import CarErrors, CarSensors
from hal_sim.car_inputs import CarInputs, DeviceWire
from hal_sim.gyro_cars import STOP_S, GyroSim, stop_for
from hal_sim.params import SimParams, estimator_config
from hal_sim.provenance import wilson_pair
from hal_sim.sim_world import SimWorld, WorldSpec

TRACK_M = 1.72
WHEEL_PROFILE = "gm_global_a"
"""The DBC a wheel car's wire speaks (``car_inputs.DeviceWire``; its track is ``TRACK_M``)."""
GYRO_PROFILE = "ford_lincoln_base_pt"
"""The DBC a gyro car's wire speaks: its yaw rate (Yaw_Data_FD1.VehYaw_W_Actl) in steps of
0.0002 rad/s (0.011 deg/s) within +-6.5 rad/s. Most profiles' stability controls report
0.005-0.01 deg/s (VW, Chrysler, Hyundai, Hyundai CAN FD), a tenth of one reading's noise
(``gyro_cars``: 0.1 deg/s); Ford's range also holds the simulated city's sharpest turns (70-102
deg/s at the fastest step of a 1.5 km drive, seeds 20000-20009), which Hyundai's ESP12
(+-41 deg/s) clips. The coarsest step any profile sends is Toyota's KINEMATICS (0.244
deg/s, no step at zero: the reading noise dithers it, and its gyro cars meet the bars);
``gm_global_a`` reads EBCMVehicleDynamic.YawRate2 (0.0625 deg/s), not YawRate (0.625 deg/s,
on which a standing reading rounds to 0 and the filter, which does not model the step, was
overconfident: drivers/profiles.py says why YawRate2 is the sensor).
``drive_car(profile=...)`` drives a gyro car on another DBC (benchmarks/honest_bars.py
--gyro-profile)."""
ODO_EVERY = 1
"""World steps per odometry message (the world's 10 Hz; the car model does not depend on it)."""
COMPASS_EVERY = 2
"""World steps per compass reading (5 Hz)."""
SAMPLE_EVERY = 10
"""World steps per consistency sample (1 s)."""


@dataclass(slots=True)
class CarResult:
    errors: CarErrors
    compass: bool
    driven_m: float = 0.0
    duration_s: float = 0.0
    """The drive's time, stops included."""
    nees: list[float] = field(default_factory=list)
    along2: list[float] = field(default_factory=list)
    across2: list[float] = field(default_factory=list)
    axis_ratio: list[float] = field(default_factory=list)
    lost_at_error_m: float | None = None
    lost_at_m: float | None = None
    """Distance driven when "lost" was first declared."""
    axis_m: list[tuple[float, float]] = field(default_factory=list)
    """(distance driven, 2-sigma major axis) at every sample."""
    final_error_m: float = 0.0
    final_major_axis_m: float = 0.0
    learned: LearnedParams | None = None

    @property
    def inside(self) -> float:
        return float(np.mean(np.asarray(self.nees) <= CHI2_2D_2SIGMA)) if self.nees else 1.0


FIX_SIGMA_M = 5.0
"""A landmark fix in the population: the truth plus this much noise (1 sigma), unbiased (the
world's own sighting model puts the car at the landmark when it comes within 20 m: a bias
along the road that would teach the scale wrongly)."""


def drive_car(
    seed: int,
    errors: CarErrors,
    *,
    compass: bool,
    distance_m: float = 1500.0,
    landmarks_per_km2: float = 0.0,
    learned: LearnedParams | None = None,
    stop_when_lost: bool = False,
    calibrated: bool = False,
    filter_overrides: dict[str, float] | None = None,
    duration_s: float | None = None,
    stops: bool = False,
    both: bool = False,
    profile: str | None = None,
) -> CarResult:
    """One car, ``distance_m`` of random route in the city of ``seed`` (module doc); with
    ``landmarks_per_km2``, fixes where the world has sightings (60 % detected); with
    ``learned``, the drive starts from what an earlier drive learned; ``stop_when_lost``
    ends it when "lost" is declared; ``calibrated``: the compass has its deviation card (the
    filter's calibrated compass prior; ``errors`` are then the card's residuals);
    ``filter_overrides``: car-model settings other than the shipped ones (a sensitivity);
    ``duration_s``: drive for this long (stops included) instead of ``distance_m``;
    ``stops``: start from a parked car and stand at intersections (``hal_sim.gyro_cars``);
    ``both``: a gyro car's filter weighs its wheels' turn too (``yaw_source = "both"``);
    ``profile``: the DBC of the car's wire (``WHEEL_PROFILE``, a gyro car's ``GYRO_PROFILE``)."""
    rng = np.random.default_rng([seed, 99])
    sim = SimParams()
    est0 = estimator_config(sim, 20.0 if compass else None)
    spec = WorldSpec(seed, 4.0, 300.0, 800.0, landmarks_per_km2, 0.6)
    world = SimWorld(spec, sim, est0, NavigatorConfig())
    est = car_model(
        EstimatorConfig(
            track_m=TRACK_M,
            compass_two_sigma_deg=None if not compass else 30.0,
            gyro=None if errors.gyro is None else GyroConfig(with_wheels=both),
        ),
        calibrated=calibrated,
        **(filter_overrides or {}),
    )
    dt = world.dt_s
    p = _localizer(est, errors, world.start_pose, dt, compass)
    if learned is not None:
        p.adopt(learned)
    res = CarResult(errors, compass)
    left = right = 0.0
    sensors = CarSensors(errors, rng, np.random.default_rng([seed, 98]), TRACK_M)
    car = _car_inputs(errors, profile)
    prev = world.truth
    gyro = None if errors.gyro is None else GyroSim(errors.gyro, np.random.default_rng([seed, 97]))
    stop_rng = np.random.default_rng([seed, 96])
    t_off = 0.0  # time stood still: the world's clock does not run while the car stands
    if stops:  # the drive starts from a parked car (the operator sets the start there)
        t_off = _stand(p, car, gyro, 0.0, float(stop_rng.uniform(*STOP_S)), dt)
    while (world.driven_m < distance_m) if duration_s is None else (world.t_s + t_off < duration_s):
        ev = world.step()
        wait = 0.0
        if ev.decide and int(world.ns[world_mod.R_C]) < 0:
            n = len(world.exits())
            world.take_exit(int(rng.integers(n)))
            wait = stop_for(stop_rng) if stops else 0.0
        t = ev.t_s + t_off
        x, y, th = world.truth
        d = math.hypot(x - prev[0], y - prev[1])
        dth = wrap_angle(th - prev[2])
        prev = (x, y, th)
        dl, dr = sensors.wheels(d, dth)
        left += dl
        right += dr
        step = world.step_count
        if gyro is not None:
            for rate in car.yaw_rate(t, gyro.reading(dth, dt)):
                p.handle(rate)
        if step % ODO_EVERY == 0:
            for odometry in car.wheels(t, left / (ODO_EVERY * dt), right / (ODO_EVERY * dt)):
                p.handle(odometry)
            left = right = 0.0
        if compass and step % COMPASS_EVERY == 0:
            heading = car.heading(t, sensors.compass(th, COMPASS_EVERY * dt))
            if heading is not None:
                p.handle(heading)
        if ev.landmark is not None:
            fx = x + float(rng.normal()) * FIX_SIGMA_M
            fy = y + float(rng.normal()) * FIX_SIGMA_M
            p.handle(LandmarkFix(t, ev.landmark, fx, fy, FIX_SIGMA_M))
        if step % SAMPLE_EVERY == 0:
            now = p.estimate()
            _sample(res, now, x, y, th)
            res.axis_m.append((world.driven_m, now.ellipse.major_axis_m))
            if res.lost_at_m is None and now.lost:
                res.lost_at_m = world.driven_m
                if stop_when_lost:
                    break
        t_off += _stand(p, car, gyro, t, wait, dt)
    res.driven_m = world.driven_m
    res.duration_s = world.t_s + t_off
    now = p.estimate()
    res.final_error_m = math.hypot(prev[0] - now.x_m, prev[1] - now.y_m)
    res.final_major_axis_m = now.ellipse.major_axis_m
    res.learned = p.learned("sim", world.t_s, world.driven_m, learned)
    return res


def _localizer(
    est: EstimatorConfig,
    errors: CarErrors,
    start_pose: tuple[float, float, float],
    dt: float,
    compass: bool,
) -> Localizer:
    """The car's estimate alone (no goal, no navigator), started where the operator puts it:
    the true start pose with the car's start errors."""
    sx, sy, th0 = start_pose
    cfg = LocalizerConfig(
        estimator=est,
        start_xy_m=(sx + errors.start_dx_m, sy + errors.start_dy_m),
        start_heading_rad=th0 + math.radians(errors.start_heading_deg),
        expected_rates_hz={
            "odometry": 1.0 / (dt * ODO_EVERY),
            **({"compass": 1.0 / (dt * COMPASS_EVERY)} if compass else {}),
        },
    )
    return Localizer(cfg)


def _car_inputs(errors: CarErrors, profile: str | None) -> CarInputs:
    """What the car's own decoders make of its sensors' wire (a gyro car's yaw rate too), on
    ``profile``'s DBC (default ``WHEEL_PROFILE``, a gyro car's ``GYRO_PROFILE``)."""
    gyro_car = errors.gyro is not None
    wire = DeviceWire(0.0, profile=profile or (GYRO_PROFILE if gyro_car else WHEEL_PROFILE))
    return CarInputs(wire, yaw_rate=gyro_car)


def _stand(
    p: Localizer, car: CarInputs, gyro: GyroSim | None, t0: float, seconds: float, dt: float
) -> float:
    """The car stands still from ``t0`` for ``seconds``: its wheels read zero, its gyro its
    bias and noise. Returns the time stood (whole steps)."""
    n = round(seconds / dt)
    for k in range(1, n + 1):
        if gyro is not None:
            for rate in car.yaw_rate(t0 + k * dt, gyro.reading(0.0, dt)):
                p.handle(rate)
        for odometry in car.wheels(t0 + k * dt, 0.0, 0.0):
            p.handle(odometry)
    return n * dt


def _sample(res: CarResult, est: EstimateState, x: float, y: float, th: float) -> None:
    P = np.array(est.covariance)[:2, :2]
    e = np.array([x - est.x_m, y - est.y_m])
    nees = mahalanobis_sq_2d(float(e[0]), float(e[1]), P[0, 0], P[0, 1], P[1, 1])
    u = np.array([math.cos(th), math.sin(th)])
    n = np.array([-u[1], u[0]])
    res.nees.append(nees)
    res.along2.append(float((e @ u) ** 2 / (u @ P @ u)))
    res.across2.append(float((e @ n) ** 2 / (n @ P @ n)))
    err = float(np.hypot(*e))
    if err > 1e-6:
        res.axis_ratio.append(0.5 * est.ellipse.major_axis_m / err)
    if res.lost_at_error_m is None and est.lost:
        res.lost_at_error_m = err


@dataclass(slots=True)
class PopulationFigures:
    cars: int
    inside: float
    """Over all samples of all cars."""
    cars_below_half: float
    mean_nees: float
    median_axis_ratio: float
    along_nees: float
    across_nees: float
    per_car_inside: list[float]
    lost_errors_m: list[float]
    final_errors_m: list[float]
    """Each car's distance from the truth at the end of its drive (the estimate, not the
    ellipse)."""

    @property
    def below_half_interval(self) -> list[float] | None:
        """Wilson 95 % interval of the fraction of cars below 50 % inside (one draw per car)."""
        return wilson_pair(round(self.cars_below_half * self.cars), self.cars)

    @property
    def nees_band(self) -> tuple[float, float]:
        """The 95 % chi-square band of the mean NEES of an honest filter over these cars.

        A car's samples are one draw of its persistent errors, not independent: the band counts
        the cars (2 degrees of freedom each), not the samples, as a Monte Carlo NEES test does
        (Bar-Shalom, Li and Kirubarajan, 2001, section 5.4)."""
        dof = 2 * self.cars
        lo, hi = chi2.ppf([0.025, 0.975], dof) / self.cars
        return float(lo), float(hi)

    def summary(self) -> str:
        q = np.percentile(self.per_car_inside, [5, 25, 50, 75, 95])
        lost = sorted(self.lost_errors_m)
        lost_txt = (f"{len(lost)} declared lost, true error then: median {np.median(lost):.0f} m, "
                    f"min {lost[0]:.0f} m" if lost else "none declared lost")  # fmt: skip
        return "\n".join([
            f"{self.cars} cars: truth inside 2-sigma {100 * self.inside:.1f} % of all samples "
            f"(honest: 86.5 %); cars below 50 %: {100 * self.cars_below_half:.1f} %"
            f" (95 % interval {_pct(self.below_half_interval)})",
            f"per car inside: p5 {100 * q[0]:.0f} %, p25 {100 * q[1]:.0f} %, median "
            f"{100 * q[2]:.0f} %, p75 {100 * q[3]:.0f} %, p95 {100 * q[4]:.0f} %",
            f"mean NEES {self.mean_nees:.2f} (honest: 2, band for {self.cars} cars "
            f"{self.nees_band[0]:.2f}-{self.nees_band[1]:.2f}); (error/sigma)^2 along "
            f"{self.along_nees:.2f}, across {self.across_nees:.2f} (honest: 1 each)",
            f"median semi-major / error {self.median_axis_ratio:.2f}; median final error "
            f"{np.median(self.final_errors_m):.0f} m; {lost_txt}",
        ])  # fmt: skip


def _pct(interval: list[float] | None) -> str:
    return "n/a" if interval is None else f"{100 * interval[0]:.1f}-{100 * interval[1]:.1f} %"


def population(results: list[CarResult]) -> PopulationFigures:
    nees = np.concatenate([r.nees for r in results])
    per_car = [r.inside for r in results]
    return PopulationFigures(
        cars=len(results),
        inside=float(np.mean(nees <= CHI2_2D_2SIGMA)),
        cars_below_half=float(np.mean(np.asarray(per_car) < 0.5)),
        mean_nees=float(np.mean(nees)),
        median_axis_ratio=float(np.median(np.concatenate([r.axis_ratio for r in results]))),
        along_nees=float(np.mean(np.concatenate([r.along2 for r in results]))),
        across_nees=float(np.mean(np.concatenate([r.across2 for r in results]))),
        per_car_inside=per_car,
        lost_errors_m=[r.lost_at_error_m for r in results if r.lost_at_error_m is not None],
        final_errors_m=[r.final_error_m for r in results],
    )


@dataclass(frozen=True, slots=True)
class PersistentLimit:
    """What a Gaussian filter can promise when a car's whole error is one persistent 2-D draw
    (its error stays at the same number of sigmas for the whole drive)."""

    outside_matched: float
    """Cars outside the 2-sigma ellipse (so below 50 % inside) when the filter's covariance is
    the draws' own."""
    inflation_for: float
    """Variance factor on the filter's covariance that leaves ``max_below`` of the cars
    outside."""
    nees_then: float
    """The mean NEES of that inflated filter: 2 / ``inflation_for``."""


def persistent_limit(
    rng: np.random.Generator,
    cars: int = 1_000_000,
    *,
    df: float | None = None,
    max_below: float = 0.05,
) -> PersistentLimit:
    """Monte Carlo of the purely persistent limit: each car one draw of two independent unit-
    variance components, Gaussian (``df`` None; closed form: e^-2 outside, inflation
    chi2_2(0.95) / 4 = 1.50 for 5 %, NEES then 1.33) or Student t with ``df`` degrees of
    freedom scaled to unit variance (heavier tails at the same variance)."""
    if df is None:
        x = rng.standard_normal((cars, 2))
    else:
        x = rng.standard_t(df, (cars, 2)) * math.sqrt((df - 2.0) / df)
    r2 = np.sum(x * x, axis=1)
    k = float(np.quantile(r2, 1.0 - max_below)) / CHI2_2D_2SIGMA
    return PersistentLimit(float(np.mean(r2 > CHI2_2D_2SIGMA)), k, float(np.mean(r2)) / k)


@dataclass(slots=True)
class TwoDrives:
    """One car's first drive (with landmark fixes: it learns), and its next drive (another
    route, no landmarks, ``days`` later) from what it learned and from the priors."""

    first: CarResult
    from_learned: CarResult
    from_priors: CarResult


def learn_then_drive(
    seed: int, errors: CarErrors, *, compass: bool = False, days: float = 1.0,
    first_m: float = 3000.0, landmarks_per_km2: float = 40.0,
) -> TwoDrives:  # fmt: skip
    """Issue 21, item 3, for one car (``TwoDrives``); the second drive's seed is ``seed + 1000``."""
    cfg = car_model(EstimatorConfig(compass_two_sigma_deg=None), calibrated=False)
    first = drive_car(seed, errors, compass=compass, landmarks_per_km2=landmarks_per_km2,
                      distance_m=first_m)  # fmt: skip
    assert first.learned is not None  # the car model always has them
    later = first.learned.widened(first.learned.saved_unix_s + days * 86400.0, cfg)
    return TwoDrives(
        first,
        drive_car(seed + 1000, errors, compass=compass, learned=later),
        drive_car(seed + 1000, errors, compass=compass),
    )
