"""The world's events as the car's inputs, once (``hal_sim.car_inputs``): the device wire,
decoded by the car's own decoders, and ``guided`` the same car as ``SimDrive``."""

from __future__ import annotations

import itertools
import math
from dataclasses import replace

import pytest

from drivers.can_decode import MAX_GAP_S
from guidance.core.localize.compass_cal import compass_heading_to_theta
from guidance.core.model import wrap_angle
from hal_sim.car_inputs import COMPASS_GARBAGE, CarInputs, DeviceWire
from hal_sim.drive import DriveOptions, run_drive
from hal_sim.guided import guided_drive


def _drive(car: CarInputs, speeds: list[float], dt: float = 0.1) -> list[tuple[float, float]]:
    """(t, left distance) of every increment the decoder makes of frames at ``speeds``."""
    out = []
    for k, v in enumerate(speeds):
        out += [(o.t_s, o.d_left_m) for o in car.wheels((k + 1) * dt, v, v)]
    return out


def test_the_decoder_integrates_the_wire_by_the_trapezoid_rule() -> None:
    """From rest to 10 m/s in 5 s and on: each increment is the mean of the two speeds that
    close it times the step (the first frame anchors), to the DBC's resolution."""
    speeds = [min(2.0 * 0.1 * (k + 1), 10.0) for k in range(100)]
    got = _drive(CarInputs(DeviceWire(0.0)), speeds)
    assert len(got) == 99
    for k, (t, d) in enumerate(got, start=1):
        assert t == pytest.approx(0.1 * (k + 1))
        assert d == pytest.approx(0.5 * (speeds[k - 1] + speeds[k]) * 0.1, abs=2e-3)


@pytest.mark.parametrize("silent_s", [0.6, 2.0])
def test_a_silence_is_bridged_up_to_the_decoders_gap_and_not_beyond(silent_s: float) -> None:
    """CAN silent from 3 s: a gap within ``MAX_GAP_S`` is integrated in one increment (the
    car's own bridging), a longer one is not (its distance is the pipeline's to dead-reckon)."""
    car = CarInputs(DeviceWire(0.0, can_silent=(3.0, silent_s)))
    got = _drive(car, [10.0] * 60)
    gap = max(b[0] - a[0] for a, b in itertools.pairwise(got))
    driven = sum(d for _, d in got)
    if silent_s + 0.1 <= MAX_GAP_S:
        assert gap == pytest.approx(silent_s + 0.1)
        assert driven == pytest.approx(10.0 * 5.9, abs=0.05)
    else:
        assert car.odometry.rejected_by_reason["gap"] == 1
        assert driven == pytest.approx(10.0 * (5.9 - silent_s - 0.1), abs=0.05)


@pytest.mark.parametrize(
    ("profile", "step_deg_s"),
    [
        ("ford_lincoln_base_pt", math.degrees(0.0002)),
        ("gm_global_a", 0.0625),
        ("toyota", 0.244),
        ("vw_mqb", 0.01),
        ("vw_pq", 0.01),
    ],
)
def test_the_yaw_rate_reads_back_in_whole_steps_of_the_dbc(profile: str, step_deg_s: float) -> None:
    """A gyro car's yaw rate on its stability control's frame, decoded by ``guidance run``'s
    decoder: the DBC's nearest whole step (its offset included: Toyota's has no step at zero),
    stamped; nothing while CAN is silent, like the wheels."""
    from drivers.can_yaw import UNIT_TO_RAD_S
    from drivers.profiles import get_profile, load_dbc

    sig = get_profile(profile).yaw_rate
    assert sig is not None
    dbc = load_dbc(get_profile(profile).dbc_file).get_message_by_frame_id(sig.frame_id)
    spec = dbc.get_signal_by_name(sig.signal)
    to_rad = UNIT_TO_RAD_S[sig.unit]
    assert math.degrees(spec.scale * to_rad) == pytest.approx(step_deg_s)
    car = CarInputs(DeviceWire(0.0, profile=profile, can_silent=(10.0, 1.0)), yaw_rate=True)
    rates = [-1.3, -0.2, -0.004, 0.0, 0.00313, 0.05, 0.7]  # rad/s (none halfway between steps)
    for k, rate in enumerate(rates):
        (got,) = car.yaw_rate(0.1 * k, rate)
        assert got.t_s == 0.1 * k
        if sig.sign is None:
            steps = round((rate / to_rad - spec.offset) / spec.scale)
            want = (spec.offset + steps * spec.scale) * to_rad
        else:  # a magnitude and a sign bit (Volkswagen's): the sign comes back
            want = math.copysign(round(abs(rate) / to_rad / spec.scale) * spec.scale * to_rad, rate)
        assert got.yaw_rate_rad_s == pytest.approx(want, abs=1e-12)
        assert abs(math.degrees(got.yaw_rate_rad_s - rate)) <= 0.5 * step_deg_s + 1e-9
    assert list(car.yaw_rate(10.5, 0.3)) == []
    assert car.yaw is not None and car.yaw.frames == len(rates)


def test_a_profile_without_a_yaw_rate_signal_and_a_car_without_a_gyro_are_refused() -> None:
    from drivers.profiles import PROFILES
    from guidance.errors import UserError

    without = next(name for name, p in PROFILES.items() if p.yaw_rate is None)
    with pytest.raises(UserError, match="no yaw-rate signal"):
        CarInputs(DeviceWire(0.0, profile=without), yaw_rate=True)
    with pytest.raises(UserError, match="no yaw-rate signal"):
        DeviceWire(0.0, profile=without).yaw_frames(0.0, 0.1)
    with pytest.raises(ValueError, match="no yaw rate"):
        list(CarInputs(DeviceWire(0.0)).yaw_rate(0.0, 0.1))


def test_the_compass_line_reads_back_as_the_heading_and_garbage_is_rejected() -> None:
    decl = -12.3
    car = CarInputs(DeviceWire(decl, compass_garbage=(5.0, 1.0)))
    for k, heading in enumerate((-3.0, -1.0, 0.0, 0.5, 2.9)):
        msg = car.heading(0.2 * k, heading)
        assert msg is not None and msg.t_s == 0.2 * k
        theta = compass_heading_to_theta(msg, decl)
        assert abs(wrap_angle(theta - heading)) <= math.radians(0.05) + 1e-9  # NMEA's 0.1 deg
    assert car.heading(5.5, 1.0) is None
    assert car.compass.rejected == 1
    assert car.wire.compass_line(5.5, 1.0) == (COMPASS_GARBAGE, False)


FAST = DriveOptions(seed=7, voice="none", telemetry=False, record=False, png=False)


@pytest.mark.parametrize(
    "faults",
    [{}, {"can_silent": (30.0, 0.6), "compass_garbage": (20.0, 6.0)}, {"can_silent": (30.0, 2.0)}],
)
def test_guided_is_the_same_car_as_the_simulated_drive(faults: dict[str, object]) -> None:
    """The same seed through the real devices, threads and ``App`` (``SimDrive``) and
    through ``guided``: the same prompts at the same times and the same distance, with and
    without faults on the wire."""
    opts = replace(FAST, **faults)  # type: ignore[arg-type]
    sim = run_drive(opts)
    trip = guided_drive(opts)
    assert [(round(p.t_s, 1), p.text) for p in trip.prompts] == [
        (round(t, 1), text) for t, text in sim.prompt_log
    ]
    assert trip.outcome == sim.outcome
    assert trip.driven_m / 1000.0 == pytest.approx(sim.driven_km, abs=1e-4)
