"""Quick simulated trips straight through the car's ``Pipeline``, checked by the truth oracle.

``guided_drive`` steps the same world as ``guidance sim`` (``hal_sim.drive.make_world``, the
same pipeline configuration) and the same simulated co-driver (``SimScene``: reports once in
view, the next one behind it, ``Approach`` distances, the driver following the car's plan),
and the same device wire (``hal_sim.car_inputs``: the wheel speeds as the car's CAN frames,
the compass as NMEA sentences with the drive's declination, the same fault windows), decoded
in-process by the car's own decoders (``WheelSpeedDecoder``: its trapezoid rule and gap
bridging; ``NmeaCompassParser``) instead of through a virtual bus, a pseudo-terminal and the
drivers' threads: a trip takes a fraction of a second, so the test suite and
``benchmarks/guidance_truth.py`` can check hundreds of them. With ``codriver`` the reports are
typed lines instead (``drivers.keyboard.CoDriverLines``: exits relative to the road, no
distance, reported as soon as the previous intersection is behind), the case of a real car.

Every output with a truth is kept for ``hal_sim.oracle.check``: the true track, each report's
true distance (also for the co-driver's reports, which carry none), the prompts, and the
estimate against the truth (``inside_2sigma``: the share of steps where the truth is inside
the 2-sigma ellipse, over a window such as a CAN dropout).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

from drivers.keyboard import CoDriverLines
from guidance.core.messages import (
    Approach,
    EstimateState,
    LandmarkFix,
    Prompt,
)
from guidance.core.model import CHI2_2D_2SIGMA, mahalanobis_sq_2d, wrap_angle
from guidance.core.pipeline import Input, Outputs, Pipeline
from guidance.core.stages import RELOCALISED
from hal_sim import world as world_mod
from hal_sim.car_inputs import CarInputs, DeviceWire
from hal_sim.drive import drive_cap_m, drive_pipeline_config, make_world, sim_declination_deg
from hal_sim.drive_options import DriveOptions
from hal_sim.oracle import CheckResult, Report, SpokenPrompt, TruthSample, check
from hal_sim.sim_scene import SimScene, sighting_fix

TRUTH_EVERY = 1
"""Truth samples every this many world steps (the world's 10 Hz, as the recorder's /truth)."""


@dataclass(slots=True)
class GuidedTrip:
    """One trip's outcome and everything the oracle needs."""

    opts: DriveOptions
    codriver: bool
    outcome: str = "timeout"
    truth: list[TruthSample] = field(default_factory=list)
    reports: list[Report] = field(default_factory=list)
    prompts: list[SpokenPrompt] = field(default_factory=list)
    driven_m: float = 0.0
    inside: list[tuple[float, bool]] = field(default_factory=list)
    """(t, truth inside the 2-sigma ellipse) per truth sample."""
    exits_not_followed: int = 0
    relocalisations: list[tuple[float, bool]] = field(default_factory=list)
    """(t, truth inside the reset 2-sigma ellipse) per relocalisation: False is a false one."""
    lost_at: list[float] = field(default_factory=list)
    """When the car was declared lost (each episode)."""

    def check(self) -> CheckResult:
        return check(self.truth, self.reports, self.prompts)

    def inside_2sigma(self, t0: float = -math.inf, t1: float = math.inf) -> float:
        """The share of samples in [t0, t1) with the truth inside the 2-sigma ellipse."""
        sel = [ok for t, ok in self.inside if t0 <= t < t1]
        return sum(sel) / len(sel) if sel else 1.0


def guided_drive(
    opts: DriveOptions,
    *,
    codriver: bool = False,
    report_next: bool = True,
    on_prompt: Callable[[Prompt], None] | None = None,
) -> GuidedTrip:
    """One trip (see the module doc); ``opts`` as for ``guidance sim`` (its faults
    ``can_silent`` and ``compass_garbage`` too: no odometry, or no compass, in that window)."""
    opts = replace(opts, camera_hz=None)
    world = make_world(opts)
    decl = sim_declination_deg()
    pipeline = Pipeline(drive_pipeline_config(world, opts, world.landmarks(), decl))
    wire = DeviceWire(decl, profile=opts.profile, can_silent=opts.can_silent,
                      compass_garbage=opts.compass_garbage)  # fmt: skip
    car = CarInputs(wire)  # the wire through the car's own decoders
    trip = GuidedTrip(opts, codriver)
    scene = SimScene(world, report_next=report_next and not codriver, drive_on_seed=opts.seed)

    def feed(msg: Input) -> None:
        if isinstance(msg, Approach):  # the co-driver's distances place it for the oracle too
            trip.reports.append(Report(msg.t_s, msg.distance_m))
        was_lost = pipeline.lost
        out = pipeline.feed(msg)
        found = out.reason == RELOCALISED or was_lost
        if isinstance(msg, LandmarkFix) and out.accepted and found:
            tx, ty, _ = world.truth
            d2 = _d2(tx, ty, pipeline.estimate)
            trip.relocalisations.append((msg.t_s, d2 <= CHI2_2D_2SIGMA))
        said(out)

    def said(out: Outputs) -> None:  # an input's outputs, or the clock's (the sensors' health)
        for pr in out.prompts:
            if pr.kind == "lost":
                trip.lost_at.append(pr.t_s)
            trip.prompts.append(SpokenPrompt(pr.t_s, pr.text, pr.kind))
            if on_prompt is not None:
                on_prompt(pr)
        trip.exits_not_followed += sum(not e.followed for e in out.exits_taken)

    def oracle_only(msg: Input) -> None:  # the co-driver gives no distance: the oracle's alone
        if isinstance(msg, Approach):
            trip.reports.append(Report(msg.t_s, msg.distance_m))

    scene.start(oracle_only if codriver else feed)
    lines = CoDriverLines(
        "co-driver", lambda: pipeline.estimate.heading_rad, clock=lambda: world.t_s,
        feedback=lambda _text: None,
    )  # fmt: skip
    cap = drive_cap_m(world, opts)
    at_node: dict[int, int] = {}  # node -> index in trip.reports, until the car is through
    while True:
        seg_before = float(world.ts[world_mod.T_SEG_H])
        ev = world.step()
        if ev.passed:  # the exact turn at the node just passed, for the oracle
            k = at_node.pop(int(world.ns[world_mod.R_A]), None)
            if k is not None:
                turn = wrap_angle(float(world.ts[world_mod.T_SEG_H]) - seg_before)
                trip.reports[k] = replace(trip.reports[k], true_turn_rad=turn)
        t = ev.t_s
        for odometry in car.wheels(t, ev.left_mps, ev.right_mps):
            feed(odometry)
        if ev.heading_rad is not None and opts.compass_deg is not None:
            heading = car.heading(t, ev.heading_rad)
            if heading is not None:
                feed(heading)
        if ev.landmark is not None:
            feed(sighting_fix(world, t, ev.landmark, pipeline.searching))
        said(pipeline.tick(t))  # the car's clock: a silent sensor is said as the app says it
        if world.step_count % TRUTH_EVERY == 0:
            _sample(trip, world.truth, t, pipeline)
        if pipeline.finished:
            trip.outcome = "arrived" if pipeline.arrived else "lost"
            break
        if world.driven_m >= cap:
            break
        scene.update(ev)
        msg = scene.due_report(ev)
        before = pipeline.reports
        if msg is not None:
            at_node[int(world.ns[world_mod.R_B])] = len(trip.reports)
            trip.reports.append(Report(t, float(ev.to_intersection_m)))
            if codriver:
                lines.handle(scene.exits_line(), feed)
            else:
                feed(msg)
            if pipeline.reports > before:
                scene.reported(pipeline.last_report_seq)
        scene.follow(pipeline.planned_exit)
        msg = scene.due_next(ev)
        before = pipeline.reports
        if msg is not None:
            assert msg.distance_m is not None
            at_node[int(world.ns[world_mod.R_C])] = len(trip.reports)
            trip.reports.append(Report(t, msg.distance_m))
            feed(msg)
            if pipeline.reports > before:
                scene.reported_next(pipeline.last_report_seq)
    _sample(trip, world.truth, world.t_s, pipeline)
    trip.driven_m = world.driven_m
    return trip


def _sample(trip: GuidedTrip, truth: tuple[float, float, float], t: float, p: Pipeline) -> None:
    tx, ty, th = truth
    trip.truth.append(TruthSample(t, tx, ty, th))
    d2 = _d2(tx, ty, p.estimate)
    trip.inside.append((t, d2 <= CHI2_2D_2SIGMA))


def _d2(tx: float, ty: float, est: EstimateState) -> float:
    """The truth's squared Mahalanobis distance from the estimate."""
    c = est.covariance
    return float(mahalanobis_sq_2d(tx - est.x_m, ty - est.y_m, c[0][0], c[0][1], c[1][1]))
