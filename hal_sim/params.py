"""Every noise, rate and size of the simulated world, in one place (SPEC section 4).

``SimParams`` is the documented source of truth; ``pack`` turns it, with the
estimator's and the navigator's configurations, into the flat float array the
compiled engine reads (indices ``I_*``). docs/simulation.md explains each value
and how the compass rate was calibrated against the paper's range figures.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from guidance.core.localize.estimator import EstimatorConfig
from guidance.core.messages import reset_sigma_m
from guidance.core.plan.navigator import NavigatorConfig


@dataclass(frozen=True, slots=True)
class SimParams:
    # --- city ----------------------------------------------------------------
    area_km2_min: float = 1.0
    area_km2_max: float = 100.0
    """City area, drawn log-uniformly in [min, max] km^2 for each trial."""
    block_m_min: float = 50.0
    block_m_max: float = 300.0
    """Each street's distance to the next, drawn uniformly in [min, max] m."""
    dead_end_frac: float = 0.04
    """Fraction of intersections made dead ends: they keep one street and lose the others."""
    one_way_frac: float = 0.12
    """Fraction of the remaining street segments made one-way (random direction)."""
    # --- vehicle: 2007 Chevrolet Tahoe (GMT900) ------------------------------------
    wheelbase_m: float = 2.946
    track_m: float = 1.72
    max_steer_rad: float = 0.55
    cruise_mps: float = 11.0
    """Urban cruise speed, about 40 km/h."""
    turn_mps: float = 5.0
    """Speed through a turn."""
    max_accel_mps2: float = 2.0
    dt_s: float = 0.1
    """Simulation and odometry step (wheel speeds arrive at 10 Hz or faster)."""
    # --- wheel encoders ---------------------------------------------------------
    wheel_quantum_m: float = 0.02
    """Distance per count (48-tooth ABS ring on a 0.39 m tyre: 2.4 m / 120 edges)."""
    wheel_slip_frac: float = 0.01
    """1-sigma random slip per wheel increment, as a fraction of it."""
    tyre_radius_err_frac: float = 0.0
    """1-sigma systematic tyre-radius error (per trial, both wheels alike); 0 = calibrated."""
    # --- compass -----------------------------------------------------------------
    compass_rate_hz: float = 6.0
    """Independent compass readings per second (cheap serial compasses give 1-20 Hz).

    Calibrated: with the paper's 2-sigma values this rate reproduces its lost
    distances (docs/simulation.md)."""
    # --- magnetic interference (issue 7; off in the calibrated studies) -----------
    interference_frac: float = 0.0
    """Fraction of street blocks (per direction of travel) inside a magnetic interference
    zone: tram lines, steel bridges, underground car parks. One zone covers one block
    (50-300 m). ``guidance study interference`` uses 0.1."""
    interference_bias_deg_min: float = 15.0
    interference_bias_deg_max: float = 45.0
    """Each zone biases the compass by a fixed angle, uniform in [min, max], random sign."""
    interference_noise_deg: float = 10.0
    """Extra 1-sigma compass noise inside a zone."""
    # --- landmarks ---------------------------------------------------------------
    sighting_range_m: float = 20.0
    """The camera recognises a landmark photo from at most this far."""
    landmark_sigma_m: float = 10.0
    """1-sigma of a landmark fix: the car is somewhere within the sighting range."""
    # --- trial -------------------------------------------------------------------
    range_cap_km: float = 40.0
    """Range study: a trial that is never lost stops here."""
    landmark_cap_factor: float = 4.0
    landmark_cap_extra_km: float = 5.0
    """Landmark study: timeout at factor * Manhattan start-goal + extra."""
    decision_distance_m: float = 30.0
    """The navigator is asked this far before an intersection."""
    field_time_limit_min: float = 75.0
    """Field protocol (SPEC 5): successive goals until lost or this much driving time."""
    field_goal_landmark: bool = True
    """Field protocol: place one landmark for each new goal (none when its node has one)."""
    relocalise: bool = False
    """The studies' relocalising arm (issue 36; off: the paper's definition, a trial ends at
    lost). On, a lost trial carries on; a landmark sighted while lost resets the position
    around it with a 1-sigma of ``guidance.core.messages.reset_sigma_m`` (the sighting range
    plus the landmark's position sigma, 0 here: the study's landmarks stand where the database
    says), the heading and its variance kept; the trial ends on arrival or at its limit."""

    def with_(self, **changes: Any) -> SimParams:
        return replace(self, **changes)


# Indices into the packed parameter array.
(
    I_DT,
    I_WHEELBASE,
    I_TRACK,
    I_MAX_STEER,
    I_CRUISE,
    I_TURN_V,
    I_MAX_ACCEL,
    I_QUANTUM,
    I_SLIP,
    I_TYRE_ERR,
    I_COMPASS_SIGMA,
    I_COMPASS_PERIOD,
    I_SIGHT_RANGE,
    I_DETECT,
    I_LM_SIGMA,
    I_LOST,
    I_ARRIVE,
    I_TABU,
    I_LOOKAHEAD,
    I_HYBRID_SWITCH,
    I_COMPASS_GATE,
    I_LM_GATE,
    I_INIT_POS_SIGMA,
    I_INIT_HEAD_SIGMA,
    I_REVISIT_GATE,
    I_REVISIT_FLOOR,
    I_EXIT_TOL,
    I_LM_PASS,
    I_DECISION_DIST,
    I_MAX_WHEEL_STEP,
    I_TRUE_QUANTUM,
    I_TRUE_SLIP,
    I_TRUE_COMPASS_SIGMA,
    I_AREA_MIN,
    I_AREA_MAX,
    I_BLOCK_MIN,
    I_BLOCK_MAX,
    I_DEAD_FRAC,
    I_ONEWAY_FRAC,
    I_RANGE_CAP,
    I_LM_CAP_FACTOR,
    I_LM_CAP_EXTRA,
    I_SAMPLE_FIRST,
    I_MAG_DETECT,
    I_MAG_ALPHA,
    I_MAG_ON,
    I_MAG_OFF,
    I_MAG_FRAC,
    I_MAG_BIAS_MIN,
    I_MAG_BIAS_MAX,
    I_MAG_NOISE,
    I_FIELD_STEPS,
    I_FIELD_GOAL_LM,
    I_RELOCALISE,
    I_RESET_SIGMA,
    N_PARAMS,
) = range(56)

LANDMARK_POSITION_SIGMA_M = 0.0
"""The study's landmarks stand exactly where the database says (``world.place_landmarks``):
their position sigma in the relocalising arm's reset (``reset_sigma_m``)."""
SAMPLE_FIRST_M = 10.0
N_SAMPLES = 120
"""The major axis is recorded at N_SAMPLES distances, log-spaced from SAMPLE_FIRST_M to the cap."""


def estimator_config(sim: SimParams, compass_two_sigma_deg: float | None) -> EstimatorConfig:
    """The filter tuned to the simulated sensors (what a calibrated car would use)."""
    return EstimatorConfig(
        track_m=sim.track_m,
        wheel_quantum_m=sim.wheel_quantum_m,
        wheel_slip_frac=sim.wheel_slip_frac,
        compass_two_sigma_deg=compass_two_sigma_deg,
    )


def pack(
    sim: SimParams,
    est: EstimatorConfig,
    nav: NavigatorConfig,
    detection_rate: float = 1.0,
    true_compass_two_sigma_deg: float | None = -1.0,
) -> np.ndarray:
    """The engine's parameter vector. Compass sigma <= 0 means no compass.

    The truth's sensor noise comes from ``sim``; the filter's model of it from
    ``est``. The true compass defaults to the filter's.
    """
    p = np.zeros(N_PARAMS)
    p[I_DT] = sim.dt_s
    p[I_WHEELBASE] = sim.wheelbase_m
    p[I_TRACK] = est.track_m
    p[I_MAX_STEER] = sim.max_steer_rad
    p[I_CRUISE] = sim.cruise_mps
    p[I_TURN_V] = sim.turn_mps
    p[I_MAX_ACCEL] = sim.max_accel_mps2
    p[I_QUANTUM] = est.wheel_quantum_m
    p[I_SLIP] = est.wheel_slip_frac
    p[I_TYRE_ERR] = sim.tyre_radius_err_frac
    p[I_COMPASS_SIGMA] = (
        -1.0 if est.compass_two_sigma_deg is None else math.radians(est.compass_two_sigma_deg) / 2
    )
    p[I_COMPASS_PERIOD] = max(1.0, 1.0 / (sim.compass_rate_hz * sim.dt_s))
    """Steps between compass readings (fractional: readings fall on the step after each period)."""
    p[I_SIGHT_RANGE] = sim.sighting_range_m
    p[I_DETECT] = detection_rate
    p[I_LM_SIGMA] = sim.landmark_sigma_m
    p[I_LOST] = est.lost_major_axis_m
    p[I_ARRIVE] = nav.arrival_radius_m
    p[I_TABU] = nav.tabu_step_rad
    p[I_LOOKAHEAD] = nav.lookahead_m
    p[I_HYBRID_SWITCH] = nav.hybrid_switch_m
    p[I_COMPASS_GATE] = est.compass_gate_chi2
    p[I_LM_GATE] = est.landmark_gate_chi2
    p[I_INIT_POS_SIGMA] = est.initial_position_sigma_m
    p[I_INIT_HEAD_SIGMA] = math.radians(est.initial_heading_sigma_deg)
    p[I_REVISIT_GATE] = nav.revisit_gate_chi2
    p[I_REVISIT_FLOOR] = nav.revisit_floor_sigma_m
    p[I_EXIT_TOL] = nav.exit_match_tol_rad
    p[I_LM_PASS] = nav.landmark_pass_radius_m
    p[I_DECISION_DIST] = sim.decision_distance_m
    p[I_MAX_WHEEL_STEP] = est.max_wheel_step_m
    p[I_TRUE_QUANTUM] = sim.wheel_quantum_m
    p[I_TRUE_SLIP] = sim.wheel_slip_frac
    if true_compass_two_sigma_deg is not None and true_compass_two_sigma_deg < 0:
        p[I_TRUE_COMPASS_SIGMA] = p[I_COMPASS_SIGMA]
    else:
        p[I_TRUE_COMPASS_SIGMA] = (
            -1.0
            if true_compass_two_sigma_deg is None
            else math.radians(true_compass_two_sigma_deg) / 2
        )
    p[I_AREA_MIN] = sim.area_km2_min
    p[I_AREA_MAX] = sim.area_km2_max
    p[I_BLOCK_MIN] = sim.block_m_min
    p[I_BLOCK_MAX] = sim.block_m_max
    p[I_DEAD_FRAC] = sim.dead_end_frac
    p[I_ONEWAY_FRAC] = sim.one_way_frac
    p[I_RANGE_CAP] = sim.range_cap_km * 1000.0
    p[I_LM_CAP_FACTOR] = sim.landmark_cap_factor
    p[I_LM_CAP_EXTRA] = sim.landmark_cap_extra_km * 1000.0
    p[I_SAMPLE_FIRST] = SAMPLE_FIRST_M
    p[I_MAG_DETECT] = 1.0 if est.interference_detection else 0.0
    p[I_MAG_ALPHA] = est.interference_alpha
    p[I_MAG_ON] = est.interference_on_nis
    p[I_MAG_OFF] = est.interference_off_nis
    p[I_MAG_FRAC] = sim.interference_frac
    p[I_MAG_BIAS_MIN] = math.radians(sim.interference_bias_deg_min)
    p[I_MAG_BIAS_MAX] = math.radians(sim.interference_bias_deg_max)
    p[I_MAG_NOISE] = math.radians(sim.interference_noise_deg)
    p[I_FIELD_STEPS] = round(sim.field_time_limit_min * 60.0 / sim.dt_s)
    p[I_FIELD_GOAL_LM] = 1.0 if sim.field_goal_landmark else 0.0
    p[I_RELOCALISE] = 1.0 if sim.relocalise else 0.0
    p[I_RESET_SIGMA] = reset_sigma_m(sim.sighting_range_m, LANDMARK_POSITION_SIGMA_M)
    return p
