"""Cars that get lost, with and without finding themselves again (issue 36): how many recover,
how far they then get, false relocalisations, and the words said while lost.

Each drive is a quick guided trip through the car's own ``Pipeline`` (``hal_sim.guided``),
checked by the truth oracle (``hal_sim.oracle``). Two ways to get lost, alternating:

* **no compass** (heading from the wheels alone), landmarks at 1, 2, 3 or 5 per km2;
* **a long CAN gap** (60-120 s of no wheel speeds, the compass working), the same densities.

Every drive runs twice on the same world and seed: relocalising (the car drives on while
lost; a landmark sighted then is a whole-database find, the position reset there when it is
outside the gate) and the paper's definition (the trip ends at "Position lost"). The world's
sighting events stand in for the camera and the whole-database search (their recall: the
world's detection rate, 0.6 as in the paper's field condition); the real search's false-match
rate is landmark_db's (docs/landmarks.md), not measured here.

A relocalisation is **false** when the truth is outside the 2-sigma ellipse right after it.
Run: ``.venv/bin/python benchmarks/relocalisation.py [--drives N] [--seed S]``
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hal_sim.drive_options import DriveOptions
from hal_sim.guided import GuidedTrip, guided_drive
from hal_sim.oracle import TruthPath

DENSITIES = (1.0, 2.0, 3.0, 5.0)


@dataclass
class Arm:
    drives: int = 0
    lost: int = 0
    recovered: int = 0
    arrived: int = 0
    arrived_after_lost: int = 0
    km_after_lost: list[float] = field(default_factory=list)
    relocalisations: int = 0
    false_relocalisations: int = 0
    words_while_lost: int = 0
    wrong_while_lost: int = 0
    wrong: int = 0
    checked: int = 0
    coarse: int = 0

    def add(self, trip: GuidedTrip) -> None:
        res = trip.check()
        self.drives += 1
        self.checked += res.manoeuvres_checked
        self.wrong += len(res.wrong)
        self.coarse += res.coarse
        self.relocalisations += len(trip.relocalisations)
        self.false_relocalisations += sum(not ok for _t, ok in trip.relocalisations)
        arrived = trip.outcome == "arrived"
        self.arrived += arrived
        if not trip.lost_at:
            return
        self.lost += 1
        t_lost = trip.lost_at[0]
        self.recovered += any(t >= t_lost for t, _ok in trip.relocalisations)
        self.arrived_after_lost += arrived
        path = TruthPath(trip.truth)
        self.km_after_lost.append((path.length_m - path.s_at(t_lost)) / 1000.0)
        windows = _lost_windows(trip)
        turn = [p for p in trip.prompts if p.kind == "turn"]
        self.words_while_lost += sum(any(a <= p.t_s < b for a, b in windows) for p in turn)
        self.wrong_while_lost += sum(
            any(a <= f.t_s < b for a, b in windows) for f in res.wrong
        )


def _lost_windows(trip: GuidedTrip) -> list[tuple[float, float]]:
    found = sorted(t for t, _ok in trip.relocalisations)
    out = []
    for t0 in trip.lost_at:
        t1 = next((t for t in found if t >= t0), math.inf)
        out.append((t0, t1))
    return out


def options(i: int, seed: int) -> DriveOptions:
    density = DENSITIES[(i // 2) % len(DENSITIES)]
    common = dict(seed=seed + i, density_per_km2=density, voice="none", png=False,
                  record=False, telemetry=False)  # fmt: skip
    if i % 2 == 0:
        return DriveOptions(compass_deg=None, **common)  # type: ignore[arg-type]
    gap = 60.0 + 60.0 * ((i * 7919) % 100) / 100.0
    return DriveOptions(compass_deg=20.0, can_silent=(30.0, gap), **common)  # type: ignore[arg-type]


def line(name: str, a: Arm) -> str:
    med = sorted(a.km_after_lost)[len(a.km_after_lost) // 2] if a.km_after_lost else 0.0
    return (
        f"{name:<14} drives {a.drives:4d}  lost {a.lost:4d}  recovered {a.recovered:4d} "
        f"({100 * a.recovered / max(1, a.lost):5.1f} %)  arrived after lost "
        f"{a.arrived_after_lost:4d} ({100 * a.arrived_after_lost / max(1, a.lost):5.1f} %)  "
        f"km after lost: median {med:5.2f}  relocalisations {a.relocalisations:4d} "
        f"(false {a.false_relocalisations})  turn words while lost {a.words_while_lost:4d} "
        f"(wrong {a.wrong_while_lost})  all words wrong {a.wrong}/{a.checked}, "
        f"said coarser {a.coarse}"
    )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--drives", type=int, default=240)
    ap.add_argument("--seed", type=int, default=36_000)
    args = ap.parse_args()
    arms = {"relocalising": Arm(), "paper (stops)": Arm()}
    t0 = time.perf_counter()
    for i in range(args.drives):
        opts = options(i, args.seed)
        arms["relocalising"].add(guided_drive(opts))
        arms["paper (stops)"].add(guided_drive(DriveOptions(**{
            **{f: getattr(opts, f) for f in opts.__dataclass_fields__}, "relocalise": False})))
        if (i + 1) % 20 == 0:
            print(f"  {i + 1}/{args.drives} drives, {time.perf_counter() - t0:.0f} s",
                  file=sys.stderr, flush=True)  # fmt: skip
    for name, a in arms.items():
        print(line(name, a))
    print(f"wall {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
