"""The studies' design (SPEC section 5): their conditions and the figures' lines, and the data a
study gathers (``StudyData``). Apart from the runner (``hal_sim.studies``), so the analyses
(``analysis``, ``figures``, ``field_study``, ``chance``) read it without importing the runner
that imports them: no import circle (``tests/test_layers.py``)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from guidance.core.plan.navigator import Method

RANGE_COMPASS_DEG: tuple[float | None, ...] = (10.0, 20.0, 30.0, None)
LANDMARK_COMPASS_DEG = 30.0
LANDMARK_DENSITIES = (0.5, 1.0, 2.0, 5.0, 10.0)
LANDMARK_DETECTION_RATES = (0.2, 0.4, 0.6, 0.8, 1.0)
LANDMARK_METHODS = (Method.STRAIGHT_TO_GOAL, Method.LANDMARK_TO_LANDMARK, Method.HYBRID)
INTERFERENCE_COMPASS_DEG = (20.0, 30.0)
INTERFERENCE_FRAC = 0.1
"""Interference study: a tenth of the blocks (per direction) are magnetically disturbed."""
FIELD_DENSITY = 0.55
FIELD_DETECTION = 0.6
"""The paper's field conditions (SPEC 5): 0.55 landmarks per km2, 60 % detection."""
SUCCESS_TARGET = 0.8
LOSS_LINE_M = 100.0


@dataclass(frozen=True, slots=True)
class Condition:
    index: int
    key: str
    study: str
    method: Method
    compass_two_sigma_deg: float | None
    density_per_km2: float
    detection_rate: float
    interference_frac: float = 0.0
    interference_detection: bool = True

    @property
    def label(self) -> str:
        c = self.compass_two_sigma_deg
        text = "no compass" if c is None else f"compass ±{c:g}° (2σ)"
        if self.study == "interference":
            zones = "zones" if self.interference_frac > 0 else "no zones"
            text += f", {zones}, detection {'on' if self.interference_detection else 'off'}"
        return text


def range_conditions() -> list[Condition]:
    return [
        Condition(
            i,
            f"compass_{'none' if c is None else f'{c:g}'}",
            "range",
            Method.STRAIGHT_TO_GOAL,
            c,
            0.0,
            0.0,
        )
        for i, c in enumerate(RANGE_COMPASS_DEG)
    ]


def landmark_conditions() -> list[Condition]:
    out: list[Condition] = []
    for m in LANDMARK_METHODS:
        for d in LANDMARK_DENSITIES:
            for r in LANDMARK_DETECTION_RATES:
                out.append(
                    Condition(
                        len(out),
                        f"{m.value}_d{d:g}_p{r:g}",
                        "landmarks",
                        m,
                        LANDMARK_COMPASS_DEG,
                        d,
                        r,
                    )
                )
    return out


def interference_conditions() -> list[Condition]:
    """Range with and without magnetic interference zones, detection on and off."""
    out: list[Condition] = []
    for c in INTERFERENCE_COMPASS_DEG:
        for frac, detect in ((0.0, True), (INTERFERENCE_FRAC, False), (INTERFERENCE_FRAC, True)):
            zones = "zones" if frac else "clean"
            key = f"compass_{c:g}_{zones}_{'detect' if detect else 'nodetect'}"
            cond = Condition(len(out), key, "interference", Method.STRAIGHT_TO_GOAL, c, 0.0, 0.0)
            out.append(replace(cond, interference_frac=frac, interference_detection=detect))
    return out


def field_conditions() -> list[Condition]:
    """The field protocol at the paper's field conditions, one condition per method."""
    return [
        Condition(
            i, f"field_{m.value}", "field", m, LANDMARK_COMPASS_DEG, FIELD_DENSITY, FIELD_DETECTION
        )
        for i, m in enumerate(LANDMARK_METHODS)
    ]


@dataclass
class StudyData:
    conditions: list[Condition]
    results: dict[str, np.ndarray]
    samples: dict[str, np.ndarray]
    sample_km: np.ndarray
