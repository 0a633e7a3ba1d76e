"""The simulated car's one sensor-error model (``hal_sim.car``): the compiled world's encoders
and compass are the model on the world's own draws; a population car's sensors count its
errors."""

from __future__ import annotations

import math

import numpy as np
import pytest

from guidance.core.model import wrap_angle
from guidance.core.plan.navigator import NavigatorConfig
from hal_sim import car, car_errors, rng, world
from hal_sim.car_errors import CarErrors, draw_car
from hal_sim.params import (
    I_COMPASS_PERIOD,
    I_TRUE_COMPASS_SIGMA,
    I_TRUE_QUANTUM,
    I_TRUE_SLIP,
    SimParams,
    estimator_config,
)
from hal_sim.sim_world import SimWorld, WorldSpec


def test_the_worlds_encoders_and_compass_are_the_model_on_the_worlds_own_draws() -> None:
    """Step a world whose tyre is 3 % off (1-sigma draw) and take each step's draws as
    ``world_step`` takes them (``draw_step`` on the step's generator words): every wheel's
    count and every compass reading is ``hal_sim.car``'s on those draws."""
    sim = SimParams(tyre_radius_err_frac=0.03)
    w = SimWorld(WorldSpec(seed=5), sim, estimator_config(sim, 20.0), NavigatorConfig())
    p = w.p
    tyre = float(w.ts[world.T_TYRE])
    assert tyre != 0.0
    period = float(p[I_COMPASS_PERIOD])
    q = float(p[I_TRUE_QUANTUM])
    readings = counts = 0
    for _ in range(1500):
        s = w.step_count
        due = math.floor((s + 1) / period) > math.floor(s / period)
        s0 = np.uint64(rng.from_word(w.ns[world.R_RNG0]))  # uint64: the world's own typing
        s1 = np.uint64(rng.from_word(w.ns[world.R_RNG1]))
        u_l, u_r, gauss, _s0, _s1 = world.draw_step(due, p[I_TRUE_COMPASS_SIGMA], s0, s1)
        before = w.ts.copy()
        ev = w.step()
        if ev.decide and int(w.ns[world.R_C]) < 0:
            w.take_exit(len(w.exits()) - 1)
        d = w.ts[world.T_DRIVEN] - before[world.T_DRIVEN]
        dth = wrap_angle(w.ts[world.T_TH] - before[world.T_TH])
        half = 0.5 * sim.track_m * dth
        for cum, cnt, d_side, u, inc in (
            (world.T_CUM_L, world.T_CNT_L, d - half, u_l, ev.left_mps * w.dt_s),
            (world.T_CUM_R, world.T_CNT_R, d + half, u_r, ev.right_mps * w.dt_s),
        ):
            slip = car.slip_noise(u, p[I_TRUE_SLIP], d_side)
            travel = car.wheel_travel(d_side, tyre, slip)
            assert w.ts[cum] - before[cum] == pytest.approx(travel, abs=1e-9)
            count, counted = car.quantise(w.ts[cum], before[cnt], 1.0 / q, q)
            assert (count, counted) == (w.ts[cnt], pytest.approx(inc, abs=1e-12))
            counts += counted != 0.0
        if due:
            reading = car.compass_reading(w.ts[world.T_TH], 0.0, gauss, p[I_TRUE_COMPASS_SIGMA])
            assert ev.heading_rad == pytest.approx(reading, abs=1e-12)
            readings += 1
    assert readings > 800 and counts > 2000


def _car(**changes: float) -> CarErrors:
    base = draw_car(np.random.default_rng(3))
    zero = dict(scale=0.0, diff=0.0, walk_m2_per_m=0.0, compass_offset_deg=0.0,
                hard_iron_ratio=0.0, compass_drift_deg2_per_s=0.0, compass_noise_deg=0.0,
                turn_scale=0.0)  # fmt: skip
    fields = {**zero, **changes}
    return CarErrors(**{**{f: getattr(base, f) for f in CarErrors.__dataclass_fields__}, **fields})


def test_a_cars_wheels_count_its_scale_its_difference_and_its_effective_track() -> None:
    """No walk: each wheel's count is its true travel (over the effective track) times its
    side's scale, exactly as the model is written."""
    e = _car(scale=0.012, diff=0.002, turn_scale=0.05)
    s = car_errors.CarSensors(e, np.random.default_rng(1), np.random.default_rng(2), 1.72)
    dl, dr = s.wheels(1.0, 0.1)
    true_l = 1.0 - 0.5 * 1.72 * 1.05 * 0.1
    true_r = 1.0 + 0.5 * 1.72 * 1.05 * 0.1
    assert dl == pytest.approx(true_l * (1.0 + 0.012 - 0.001), rel=1e-14)
    assert dr == pytest.approx(true_r * (1.0 + 0.012 + 0.001), rel=1e-14)


def test_a_cars_wheel_walk_has_the_variance_per_metre_it_is_drawn_with() -> None:
    e = _car(walk_m2_per_m=5e-6)
    s = car_errors.CarSensors(e, np.random.default_rng(1), np.random.default_rng(2), 1.72)
    errors = [s.wheels(4.0, 0.0)[0] - 4.0 for _ in range(20000)]
    # 20,000 draws: the sample variance is within 3 % of the true one (sd 1 %)
    assert np.var(errors) == pytest.approx(5e-6 * 4.0, rel=0.03)


def test_a_cars_compass_reads_its_deviation_curve_and_noise() -> None:
    """The mean error at a heading is the car's deviation there (offset plus hard iron); the
    spread is the noise."""
    e = _car(compass_offset_deg=12.0, hard_iron_ratio=0.3, hard_iron_dir_rad=0.7,
             compass_noise_deg=3.0)  # fmt: skip
    s = car_errors.CarSensors(e, np.random.default_rng(1), np.random.default_rng(2), 1.72)
    for heading in (-2.5, 0.0, 1.2):
        errs = [wrap_angle(s.compass(heading, 0.2) - heading) for _ in range(4000)]
        # 4000 draws of 3 deg: the mean within 0.15 deg (3 sigma), the sd within 5 %
        assert math.degrees(np.mean(errs)) == pytest.approx(
            math.degrees(e.deviation_rad(heading)), abs=0.15
        )
        assert math.degrees(np.std(errs)) == pytest.approx(3.0, rel=0.05)
    expected = math.radians(12.0) + car.hard_iron_rad(0.3, 0.7, 1.2)
    assert e.deviation_rad(1.2) == pytest.approx(expected, abs=1e-15)


def test_the_papers_compass_is_the_model_without_a_deviation() -> None:
    assert car.compass_reading(0.5, 0.0, 1.5, 0.1) == pytest.approx(0.65, abs=1e-15)
    assert car.compass_reading(3.1, 0.0, 1.0, 0.1) == pytest.approx(3.2 - 2 * math.pi)

