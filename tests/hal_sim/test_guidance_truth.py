"""Issue 20: every spoken manoeuvre checked against what the car then did, on populations of
simulated drives (hal_sim/guided.py through the car's pipeline; hal_sim/oracle.py the checker),
on the full ``guidance sim`` stack through its recording, and on a keyboard co-driver who
reports early. The seeds here are not the ones the figures in docs were measured on."""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import pytest

from hal_sim.drive import run_drive
from hal_sim.drive_options import DriveOptions
from hal_sim.guided import guided_drive
from hal_sim.oracle import CheckResult, from_recording

METHODS = ("straight_to_goal", "landmark_to_landmark", "hybrid")


def _merge(results: list[CheckResult]) -> CheckResult:
    total = results[0]
    for r in results[1:]:
        total.merge(r)
    return total


@pytest.mark.parametrize("distance_m", [30.0, 100.0, 250.0])
def test_every_manoeuvre_is_the_turn_the_car_then_makes(distance_m: float) -> None:
    """Seeds x methods x landmark densities at one report distance: no wrong manoeuvre, no
    late or unannounced turn, no repeat, spoken distances right."""
    results, outcomes = [], []
    for seed, method, density in itertools.product((11, 12, 13, 14), METHODS, (0.0, 5.0)):
        opts = DriveOptions(
            seed=seed, method=method, density_per_km2=density, decision_distance_m=distance_m
        )
        trip = guided_drive(opts)
        results.append(trip.check())
        outcomes.append(trip.outcome)
    total = _merge(results)
    assert total.manoeuvres_checked > 100 and total.turns > 50
    assert not total.wrong, total.summary()
    assert not total.unannounced and not total.late and not total.repeats, total.summary()
    assert total.distance_ok_frac >= 0.95, total.summary()
    assert outcomes.count("arrived") >= 0.9 * len(outcomes)


def test_with_faults_the_words_stay_right() -> None:
    """CAN dropouts of 3-6 s and a garbled compass on top: still no wrong manoeuvre. A turn
    goes unannounced only at an intersection the dropout left unplaced (reported before the
    wheels came back, more than 3.7 s of dead reckoning: ``Guide.after_gap``), so within
    the half minute after it (seed 23: a 6 s dropout at 11 m/s, the car's next two corners)."""
    results = []
    for seed, (t0, dur) in zip(
        (21, 22, 23, 24, 25, 26),
        itertools.cycle([(25.0, 5.0), (60.0, 3.0), (40.0, 6.0)]),
        strict=False,
    ):
        opts = DriveOptions(
            seed=seed, density_per_km2=1.0, can_silent=(t0, dur), compass_garbage=(t0 + 30.0, 5.0)
        )
        res = guided_drive(opts).check()
        assert all(t0 + dur <= f.t_s <= t0 + dur + 30.0 for f in res.unannounced), res.summary()
        results.append(res)
    total = _merge(results)
    assert not total.wrong and len(total.unannounced) <= 2, total.summary()


def test_the_next_intersection_is_announced_with_then_when_it_follows_closely() -> None:
    """The simulated co-driver reports the next two when both are in view: a "then" is said,
    and (above) checked against the intersection after the next."""
    thens = 0
    for seed in (31, 32, 33, 34, 35, 36):
        trip = guided_drive(DriveOptions(seed=seed, density_per_km2=1.0))
        thens += sum(", then " in p.text for p in trip.prompts)
        assert not trip.check().wrong
    assert thens > 0


def test_a_co_driver_who_reports_right_after_the_previous_intersection_gets_right_words() -> None:
    """The keyboard co-driver (typed lines through CoDriverLines, exits relative to the road,
    no distance) reports each intersection as soon as the previous one is behind, often while
    the car is still turning out of it: the manoeuvres are right, and no exit is ever taken as
    "different" when the driver did as told (the issue's false "Different exit taken")."""
    results, not_followed = [], 0
    for seed, method in itertools.product((41, 42, 43, 44, 45), METHODS):
        trip = guided_drive(
            DriveOptions(seed=seed, method=method, density_per_km2=1.0), codriver=True
        )
        results.append(trip.check())
        not_followed += trip.exits_not_followed
    total = _merge(results)
    assert total.manoeuvres_checked > 100
    assert not total.wrong, total.summary()
    assert not_followed == 0


def test_the_oracle_fails_the_old_behaviour() -> None:
    """The checker is not a rubber stamp: the same trips with the turn frozen at the report
    (the defect of issue 20: the turn taken relative to the heading when the co-driver
    reported, 250 m ahead and often before the car had turned out of the previous corner)
    give wrong manoeuvres."""
    import guidance.core.plan.guide as guide

    real = guide.Guide._set_approach

    def frozen(self: guide.Guide, a: guide.Ahead, prev: object, est: object, *args: object) -> None:
        if a.approach_heading_rad is None:
            a.approach_heading_rad = a.report_heading_rad  # the heading at the report

    guide.Guide._set_approach = frozen  # type: ignore[method-assign,assignment]
    try:
        wrong = sum(
            len(guided_drive(DriveOptions(seed=s, density_per_km2=5.0)).check().wrong)
            for s in (1, 2, 3)
        )
    finally:
        guide.Guide._set_approach = real  # type: ignore[method-assign]
    assert wrong >= 3


def test_guidance_sim_full_stack_checked_through_its_recording(tmp_path: Path) -> None:
    """The real drivers on the simulated devices (CAN frames, the compass pty), the App, the
    recorder: the oracle reads the recording (/truth, /scene, /prompt)."""
    results = []
    for seed, dist in ((3, 250.0), (7, 30.0), (7, 100.0), (9, 250.0)):
        out = tmp_path / f"s{seed}-{dist:.0f}"
        opts = DriveOptions(
            seed=seed,
            density_per_km2=5.0,
            decision_distance_m=dist,
            voice="none",
            out=str(out),
            png=False,
            telemetry=False,
        )
        res = run_drive(opts)
        assert res.outcome == "arrived"
        assert res.recording
        results.append(from_recording(res.recording[0]))
    total = _merge(results)
    assert total.manoeuvres_checked > 10
    assert total.ok(), total.summary()


def test_a_5_s_can_dropout_keeps_the_truth_inside_the_ellipse_and_the_car_arrives(
    tmp_path: Path,
) -> None:
    """``guidance sim --can-silent 30:5 --compass-garbage 60:5``: it arrives, and through the
    gap the truth stays inside the 2-sigma ellipse (dead reckoning along the road, widened by
    what the car could gain or lose), checked against the simulator's truth."""
    opts = DriveOptions(
        seed=7,
        density_per_km2=5.0,
        can_silent=(30.0, 5.0),
        compass_garbage=(60.0, 5.0),
        voice="none",
        out=str(tmp_path),
        png=False,
        telemetry=False,
    )
    res = run_drive(opts)
    assert res.outcome == "arrived"
    inside = _inside_from_recording(res.recording[0], 29.0, 40.0)
    assert inside >= 0.95, inside
    trip = guided_drive(DriveOptions(seed=7, density_per_km2=5.0, can_silent=(30.0, 5.0)))
    assert trip.outcome == "arrived" and trip.inside_2sigma(30.0, 36.0) == 1.0


def _inside_from_recording(path: str, t0: float, t1: float) -> float:
    """The share of /state messages in [t0, t1) whose 2-sigma ellipse holds the truth."""
    import bisect

    from guidance.core.model import CHI2_2D_2SIGMA, mahalanobis_sq_2d
    from guidance.recording.reader import Reader

    truth: list[tuple[float, float, float]] = []
    states: list[tuple[float, float, float, list[list[float]]]] = []
    for m in Reader(path, topics=("/truth", "/state")):
        d = m.data
        if m.topic == "/truth":
            truth.append((d["t_s"], d["x_m"], d["y_m"]))
        elif t0 <= d["t_s"] < t1:
            cov = d["covariance"]
            states.append((d["t_s"], d["x_m"], d["y_m"], [row[:2] for row in cov[:2]]))
    ts = [t for t, _, _ in truth]
    ok = []
    for t, x, y, cov in states:
        i = min(max(bisect.bisect_left(ts, t), 0), len(truth) - 1)
        d2 = mahalanobis_sq_2d(truth[i][1] - x, truth[i][2] - y, cov[0][0], cov[0][1], cov[1][1])
        ok.append(d2 <= CHI2_2D_2SIGMA)
    assert ok, "no state messages in the window"
    return sum(ok) / len(ok)


def test_spoken_distances_and_margins_are_reported_per_km() -> None:
    trip = guided_drive(DriveOptions(seed=51, density_per_km2=1.0))
    res = trip.check()
    assert res.km > 0.5 and res.prompts_per_km > 0
    assert all(m >= 3.0 for m in res.margins_s)
    assert math.isfinite(res.distance_ok_frac)


def test_guidance_run_on_the_simulated_devices_checked_through_its_recording(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``guidance run --config`` with ``[sim] devices = true`` (the README's way to try the
    in-car process): its recording passes the oracle, and so does ``guidance check-guidance``."""
    import re

    from guidance.tools.cli import main

    repo = Path(__file__).resolve().parents[2]
    text = (repo / "config" / "sim.toml").read_text()
    text = re.sub(r'directory = ".*"', f'directory = "{tmp_path / "rec"}"', text)
    text = text.replace(
        "[sim]\n",
        f'[sim]\ndevices = true\ntelemetry = false\npng = false\nvoice = "none"\n'
        f'out = "{tmp_path}"\n',
    )
    text = re.sub(r"seed = 7", "seed = 17", text)
    text = re.sub(r"density_per_km2 = 1.0", "density_per_km2 = 5.0", text)
    cfg = tmp_path / "sim.toml"
    cfg.write_text(text)
    assert main(["run", "--config", str(cfg), "--json"]) == 0
    files = sorted(tmp_path.rglob("*.mcap"))
    assert files
    res = from_recording(files[0])
    assert res.manoeuvres_checked >= 3 and res.ok(), res.summary()
    capsys.readouterr()
    assert main(["check-guidance", str(files[0]), "--json"]) == 0
    assert '"wrong": 0' in capsys.readouterr().out


def test_lost_cars_find_themselves_again_and_say_only_true_words() -> None:
    """Issue 36: drives that get lost (no compass; a 60-90 s CAN gap with the compass on) at
    3 landmarks per km2 drive on while lost; a landmark sighted then resets the position
    around it, never with the truth outside the reset ellipse; cars recover and arrive; the
    words said while lost are checked against the turns the car then made (hal_sim/oracle.py,
    which takes "go left" and "take the road towards the north" for what they say)."""
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
    from relocalisation import Arm, options  # the benchmark's drives, other seeds

    arm = Arm()
    for i in range(12):
        arm.add(guided_drive(options(i, 71_000)))
    assert arm.lost == 12
    assert arm.relocalisations >= 4 and arm.false_relocalisations == 0
    assert arm.recovered >= arm.lost // 3
    assert arm.words_while_lost > 20 and arm.coarse > 0  # the uncertain heading said coarsely
    # not yet the 0: a few prompts after a long gap or a reset are about another
    # intersection than the one the car reaches next (docs/app.md, "While lost")
    assert arm.wrong_while_lost <= 0.05 * arm.words_while_lost


def test_no_turn_is_announced_for_an_intersection_the_car_never_reaches() -> None:
    """Issue 36: at half the arrivals a turn prompt for the goal's own intersection came just
    before "You have arrived"; now a prompt is only about an intersection the car gets to."""
    unchecked = 0
    for seed in (51, 52, 53, 54, 55, 56, 57, 58):
        trip = guided_drive(DriveOptions(seed=seed, density_per_km2=1.0))
        res = trip.check()
        assert trip.outcome == "arrived" and not res.wrong and not res.unannounced
        unchecked += res.unchecked
    assert unchecked == 0


def test_cars_that_start_anywhere_find_themselves_and_say_only_true_words() -> None:
    """Issue 36, "start anywhere" (``--start-unknown``): the car is not told where it starts;
    the simulated driver, told nothing, chooses exits alone until a landmark is found (the
    world's sighting stands for the whole-database search). Most find themselves and arrive,
    no reset leaves the truth outside its ellipse, and every word said is checked against
    the turn the car then made (seeds no development run used)."""
    found = arrived = checked = 0
    for seed in range(300, 308):
        trip = guided_drive(DriveOptions(seed=seed, density_per_km2=3.0, start_unknown=True))
        res = trip.check()
        assert not res.wrong, [f.line() for f in res.wrong]
        assert all(ok for _t, ok in trip.relocalisations)
        found += bool(trip.relocalisations)
        arrived += trip.outcome == "arrived"
        checked += res.manoeuvres_checked
        assert trip.prompts[0].text.startswith("Position unknown")
    # 40 such drives (seeds 300-339): 30 found themselves, 23 arrived, 0 wrong of 298 words
    assert found >= 4 and arrived >= 3 and checked >= 40
