"""The chance of reaching the goal from where the car is (issue 26, item 5).

The study engine runs the landmark study's trials over a grid of conditions (method, landmark
density, detection rate, compass 2-sigma) and records, at distances along each trial, the
estimated distance still to go and the 2-sigma major axis, then whether the trial reached its
goal without being lost (``guidance study chance``, ``hal_sim.chance``). Per condition, a
logistic model of success in those two numbers is fitted; the package ships the coefficients
(``chance_table.json`` beside this module). ``ChanceTable.chance`` evaluates it for the car's
own condition, interpolating the linear predictor between grid points (clamped at the grid's
edges); ``ChanceWatch`` is what the pipeline holds: the current value for the state message and
the one spoken warning when it falls below ``ChanceSettings.warn_below``.

The table is the simulator's world (the paper's model of odometry, compass and camera), not a
measurement of any one car; the major axis is scaled to the table's lost threshold, so a car
with another ``lost_major_axis_m`` is judged by how close it is to its own.
"""

from __future__ import annotations

import bisect
import functools
import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

from guidance import files
from guidance.config_tables import rule
from guidance.core.messages import Say, Speech

if TYPE_CHECKING:
    import numpy as np
    import numpy.typing as npt

log = logging.getLogger(__name__)

F = TypeVar("F", float, "npt.NDArray[np.float64]")
"""A number, or an array of them."""
SCHEMA = "guidance.chance_table/1"
FEATURES = ("1", "to_go_km", "major_axis_per_lost", "major_axis_per_lost^2")
"""The logistic model's inputs: P = 1 / (1 + exp(-(w . [1, d, a, a^2]))) with d the estimated
distance to go (km, straight line) and a the 2-sigma major axis over the lost threshold."""
METHODS = ("straight_to_goal", "landmark_to_landmark", "hybrid")
REARM_MARGIN = 0.15
"""The warning re-arms once the chance is back this far above the threshold."""


def features(to_go_km: F, axis_ratio: F) -> tuple[F, F, F, F]:
    """``FEATURES`` of one point, or of arrays of points (the study's fit uses the same
    function: ``hal_sim.chance.feature_matrix``)."""
    return (to_go_km * 0 + 1, to_go_km, axis_ratio, axis_ratio * axis_ratio)


def sigmoid(z: float) -> float:
    return 1.0 / (1.0 + math.exp(-min(max(z, -30.0), 30.0)))


class ChanceTableError(ValueError):
    """A chance table that is not one this code can read."""


def _axis(values: object, name: str, lo: float, hi: float) -> tuple[float, ...]:
    if not isinstance(values, list) or not values:
        raise ChanceTableError(f"{name} must be a non-empty list")
    out = []
    for v in values:
        if isinstance(v, bool) or not isinstance(v, int | float) or not lo <= float(v) <= hi:
            raise ChanceTableError(f"{name}: {v!r} is not a number in [{lo:g}, {hi:g}]")
        out.append(float(v))
    if out != sorted(set(out)):
        raise ChanceTableError(f"{name} must be strictly increasing")
    return tuple(out)


@dataclass(frozen=True, slots=True)
class ChanceTable:
    """Coefficients per (method, compass, density index, detection index)."""

    densities_per_km2: tuple[float, ...]
    detection_rates: tuple[float, ...]
    compass_two_sigma_deg: tuple[float | None, ...]
    """Grid values; None is the slice for a car without a (usable) compass."""
    coef: Mapping[tuple[str, float | None], tuple[tuple[tuple[float, ...], ...], ...]]
    """(method, compass) -> [density][detection] -> the four weights."""
    lost_major_axis_m: float
    provenance: Mapping[str, Any] = field(default_factory=dict)

    # -- reading -----------------------------------------------------------------------------
    @classmethod
    def from_json(cls, data: object) -> ChanceTable:
        """Validate and read a table (``as_json``'s shape); ``ChanceTableError`` says what is
        wrong."""
        if not isinstance(data, Mapping) or data.get("schema") != SCHEMA:
            raise ChanceTableError(f"not a chance table (schema must be {SCHEMA!r})")
        if data.get("features") != list(FEATURES):
            raise ChanceTableError(f"features must be {list(FEATURES)}")
        dens = _axis(data.get("densities_per_km2"), "densities_per_km2", 0.0, 1e4)
        det = _axis(data.get("detection_rates"), "detection_rates", 0.0, 1.0)
        raw_c = data.get("compass_two_sigma_deg")
        if not isinstance(raw_c, list) or not raw_c:
            raise ChanceTableError("compass_two_sigma_deg must be a non-empty list")
        numbers = [c for c in raw_c if c is not None]
        if not numbers:  # a car with a compass would find no slice of its own
            raise ChanceTableError("compass_two_sigma_deg must hold at least one number")
        comp: tuple[float | None, ...] = ((None,) if None in raw_c else ()) + (
            _axis(numbers, "compass_two_sigma_deg", 0.0, 180.0) if numbers else ()
        )
        lost = data.get("lost_major_axis_m")
        if isinstance(lost, bool) or not isinstance(lost, int | float) or not lost > 0:
            raise ChanceTableError("lost_major_axis_m must be a positive number")
        coef_in = data.get("coef")
        if not isinstance(coef_in, Mapping):
            raise ChanceTableError("coef must be a table")
        coef: dict[tuple[str, float | None], tuple[tuple[tuple[float, ...], ...], ...]] = {}
        for method in METHODS:
            for c in comp:
                key = f"{method}/{'none' if c is None else f'{c:g}'}"
                grid = coef_in.get(key)
                if not isinstance(grid, list) or len(grid) != len(dens):
                    raise ChanceTableError(f"coef[{key!r}] must hold one row per density")
                rows = []
                for row in grid:
                    if not isinstance(row, list) or len(row) != len(det):
                        raise ChanceTableError(f"coef[{key!r}]: one entry per detection rate")
                    cells = []
                    for w in row:
                        if (
                            not isinstance(w, list)
                            or len(w) != len(FEATURES)
                            or not all(
                                isinstance(v, int | float) and math.isfinite(v) and abs(v) < 1e4
                                for v in w
                            )
                        ):
                            raise ChanceTableError(f"coef[{key!r}]: four finite weights each")
                        cells.append(tuple(float(v) for v in w))
                    rows.append(tuple(cells))
                coef[(method, c)] = tuple(rows)
        prov = data.get("provenance", {})
        return cls(dens, det, comp, coef, float(lost), prov if isinstance(prov, Mapping) else {})

    @classmethod
    def shipped(cls) -> ChanceTable:
        """The table the package ships (``chance_table.json``), read once per process."""
        return _shipped()

    def as_json(self) -> dict[str, Any]:
        coef = {
            f"{m}/{'none' if c is None else f'{c:g}'}": [[list(w) for w in row] for row in grid]
            for (m, c), grid in self.coef.items()
        }
        return {
            "schema": SCHEMA,
            "features": list(FEATURES),
            "densities_per_km2": list(self.densities_per_km2),
            "detection_rates": list(self.detection_rates),
            "compass_two_sigma_deg": list(self.compass_two_sigma_deg),
            "lost_major_axis_m": self.lost_major_axis_m,
            "coef": coef,
            "provenance": dict(self.provenance),
        }

    # -- evaluating --------------------------------------------------------------------------
    def weights(
        self,
        method: str,
        density_per_km2: float,
        detection_rate: float,
        compass_two_sigma_deg: float | None,
    ) -> tuple[float, ...]:
        """The condition's weights: multilinear in density, detection and compass sigma between
        the grid's points, clamped at its edges (a method the table lacks: straight to goal)."""
        m = method if method in METHODS else "straight_to_goal"
        numeric = [c for c in self.compass_two_sigma_deg if c is not None]
        if compass_two_sigma_deg is None or not numeric:
            comp: list[tuple[float | None, float]] = [(None, 1.0)]
        else:
            comp = [(c, f) for c, f in _bracket(numeric, compass_two_sigma_deg)]
        out = [0.0] * len(FEATURES)
        for c, fc in comp:
            grid = self.coef[(m, c)]
            for i, fd in _bracket_index(self.densities_per_km2, density_per_km2):
                for j, fr in _bracket_index(self.detection_rates, detection_rate):
                    f = fc * fd * fr
                    for k, w in enumerate(grid[i][j]):
                        out[k] += f * w
        return tuple(out)

    def chance(
        self,
        method: str,
        density_per_km2: float,
        detection_rate: float,
        compass_two_sigma_deg: float | None,
        to_go_m: float,
        major_axis_m: float,
        lost_major_axis_m: float | None = None,
    ) -> float:
        """The probability of reaching the goal ``to_go_m`` away (straight line) with the
        current 2-sigma major axis, in the simulated world of the table's condition."""
        w = self.weights(method, density_per_km2, detection_rate, compass_two_sigma_deg)
        lost = lost_major_axis_m or self.lost_major_axis_m
        ratio = max(0.0, major_axis_m) / lost
        if ratio >= 1.0:
            return 0.0  # lost already
        x = features(max(0.0, to_go_m) / 1000.0, ratio)
        return sigmoid(sum(wi * xi for wi, xi in zip(w, x, strict=True)))


def load_table(path: Path) -> ChanceTable:
    """A chance table from a file, read through the product's one door (``guidance.files``:
    a regular file of at most 1 MiB, strict JSON); ``FileRefused`` or ``ChanceTableError``."""
    return ChanceTable.from_json(files.read_json(path, "chance_table"))


@functools.cache
def _shipped() -> ChanceTable:
    return load_table(TABLE_PATH)


TABLE_FILE = "chance_table.json"
TABLE_PATH = Path(__file__).with_name(TABLE_FILE)
"""The package's table, beside this module (read with ``load_table``)."""


@functools.cache
def shipped_or_none() -> ChanceTable | None:
    """The shipped table, or None (logged once: the answer is kept) when it cannot be read: a
    damaged install costs the car its chance of success (published as null), never its
    guidance."""
    try:
        return ChanceTable.shipped()
    except (files.FileRefused, ValueError) as e:  # ChanceTableError is a ValueError
        log.error("no chance of success: the package's %s cannot be read (%s)", TABLE_FILE, e)
        return None


def _bracket_index(grid: Sequence[float], v: float) -> list[tuple[int, float]]:
    """The grid indices around ``v`` and their linear weights (clamped at the ends)."""
    if not math.isfinite(v) or v <= grid[0]:
        return [(0, 1.0)]
    if v >= grid[-1]:
        return [(len(grid) - 1, 1.0)]
    hi = bisect.bisect_right(grid, v)
    lo = hi - 1
    f = (v - grid[lo]) / (grid[hi] - grid[lo])
    return [(lo, 1.0 - f), (hi, f)]


def _bracket(grid: Sequence[float], v: float) -> list[tuple[float, float]]:
    return [(grid[i], f) for i, f in _bracket_index(grid, v)]


# -- the car's side ---------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class ChanceSettings:
    """``[chance]``: the live chance of reaching the goal (docs/app.md)."""

    enabled: bool = True
    detection_rate: float = field(default=0.6, metadata=rule(lo=0.0, hi=1.0))
    """The share of landmarks passed that the camera confirms: 0.6 is the paper's field
    figure for its matcher (SPEC 5); set it from your own matcher's recall."""
    density_per_km2: float | None = field(default=None, metadata=rule(lo=0.0))
    """Landmarks per km2 of the area driven; None: counted from the car's landmarks in the
    trip's box (start and goal, with ``TRIP_MARGIN_M`` around)."""
    warn_below: float = field(default=0.5, metadata=rule(lo=0.0, hi=1.0))
    """Say the chance once when it falls below this (0: never)."""


TRIP_MARGIN_M = 1000.0
"""How far around the start-goal box landmarks count towards the trip's density."""
MIN_AREA_KM2 = 1.0
"""The smallest area a density is counted over (a short trip's box is not a city)."""


def trip_density_per_km2(
    landmarks_xy: Sequence[tuple[float, float]],
    start_xy: tuple[float, float],
    goal_xy: tuple[float, float],
) -> float:
    """Landmarks per km2 in the box around start and goal (``TRIP_MARGIN_M`` on each side)."""
    x0 = min(start_xy[0], goal_xy[0]) - TRIP_MARGIN_M
    x1 = max(start_xy[0], goal_xy[0]) + TRIP_MARGIN_M
    y0 = min(start_xy[1], goal_xy[1]) - TRIP_MARGIN_M
    y1 = max(start_xy[1], goal_xy[1]) + TRIP_MARGIN_M
    n = sum(1 for x, y in landmarks_xy if x0 <= x <= x1 and y0 <= y <= y1)
    area = max(MIN_AREA_KM2, (x1 - x0) * (y1 - y0) / 1e6)
    return n / area


class ChanceWatch:
    """The pipeline's chance of success: ``update`` at each state publication gives the value
    for the state message and, once each time it falls below the threshold, a sentence. Whether
    it has been said is the caller's (the pipeline's checkpointed state)."""

    def __init__(self, settings: ChanceSettings, table: ChanceTable | None, method: str) -> None:
        self.settings = settings
        self.table = table if settings.enabled else None
        self.method = method
        self.density_per_km2 = settings.density_per_km2 or 0.0
        self.value: float | None = None

    def set_trip(
        self,
        landmarks_xy: Sequence[tuple[float, float]],
        start_xy: tuple[float, float],
        goal_xy: tuple[float, float],
    ) -> None:
        """A new trip (the start, or a new goal): the density counted unless configured."""
        if self.settings.density_per_km2 is None:
            self.density_per_km2 = trip_density_per_km2(landmarks_xy, start_xy, goal_xy)

    def update(
        self,
        to_go_m: float,
        major_axis_m: float,
        lost_major_axis_m: float,
        compass_two_sigma_deg: float | None,
        *,
        said: bool,
        quiet: bool,
    ) -> tuple[Say | None, bool]:
        """Recompute ``value``; (what to say now or None, whether it is said). It is
        said when the chance has just fallen below the threshold, never while ``quiet`` (lost
        already said, arrived), and again only after it has risen ``REARM_MARGIN`` above."""
        if self.table is None:
            self.value = None
            return None, said
        p = self.table.chance(
            self.method, self.density_per_km2, self.settings.detection_rate,
            compass_two_sigma_deg, to_go_m, major_axis_m, lost_major_axis_m,
        )  # fmt: skip
        self.value = p
        warn = self.settings.warn_below
        if said and p > min(1.0, warn + REARM_MARGIN):
            said = False
        if quiet or said or p >= warn:
            return None, said
        return Say(Speech.CHANCE, chance=p), True


def shown(p: float | None) -> str:
    """The screen's and monitor's form: '70 %' (rounded to 5 %), '<5 %', or '-'."""
    if p is None or not math.isfinite(p):
        return "-"
    if p < 0.05:
        return "<5 %"
    if p > 0.95:
        return ">95 %"
    return f"{round(p * 20) * 5:.0f} %"
