"""Look-alikes passed by a lost car (issue 36): how often the whole-database search verifies
a wrong place, and how often two agreeing frames relocalise the car there.

The city of ``tests/landmark_db/test_search.py`` (24 simulated places 200 m apart, one photo
each, built photo by photo); per seed, a lost car passes a look-alike of every place (same
style and window grid, other details; 4 frames 0.5 s apart, 4-12 m away, the gentle camera
of that test), and ``Recogniser.process`` searches the whole file for each frame. Prints per
seed the frames that verified a (wrong) place, the relocalisations, the most significant
evidence and the level.

    python benchmarks/search_lookalikes.py [--seeds 11 21 31]
"""

from __future__ import annotations

import argparse
import math
import tempfile
from pathlib import Path

import numpy as np

from guidance.core.messages import CameraFrame, Ellipse, EstimateState
from hal_sim.sim_camera import SimCamera, SimCameraConfig, build_sim_landmark_db, facade
from landmark_db.recognise import Recogniser
from landmark_db.threads import cap_threads

EASY = SimCameraConfig(
    perspective=0.08, occlusion=(0.0, 0.1), blur_sigma_px=(0.0, 0.8), motion_blur_px=(0.0, 1.0)
)


def lost(t: float) -> EstimateState:
    big = 1e8
    c = ((big, 0.0, 0.0), (0.0, big, 0.0), (0.0, 0.0, 3.0))
    return EstimateState(t, 5e4, -5e4, 0.0, c, Ellipse(2e4, 2e4, 0.0, 180.0), True, False)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--seeds", type=int, nargs="+", default=[11, 21, 31])
    args = ap.parse_args()
    cap_threads(1)
    path = Path(tempfile.mkdtemp(prefix="lookalikes-")) / "city.sqlite"
    xy = np.array([[200.0 * (i % 6), 200.0 * (i // 6)] for i in range(24)])
    db, lms = build_sim_landmark_db(path, xy, seed=41)
    db.close()
    total = [0, 0, 0, 0]
    for s in args.seeds:
        rec = Recogniser.from_path(path)
        rng = np.random.default_rng(s)
        cam = SimCamera(lms, seed=s + 1, config=EASY)
        t, verified, best, level = 0.0, 0, math.inf, math.nan
        for lm in lms:
            look = facade(lm.photo_seed + s, family_seed=lm.photo_seed)
            for _k in range(4):
                t += 0.5
                img = cam.view(look, float(rng.uniform(4.0, 12.0)))
                r = rec.process(CameraFrame(t, img), lost(t))
                verified += r.landmark_id is not None
                best = min([best, *(e.log_nfa for e in r.evidence)])
                level = r.level
            t += 60.0
        st = rec.stats()
        rec.close()
        total = [total[0] + st["frames"], total[1] + verified, total[2] + len(lms),
                 total[3] + st["relocalisations"]]  # fmt: skip
        print(
            f"seed {s}: {st['frames']} lost frames of look-alikes, {verified} verified a place"
            f" (all wrong), {st['relocalisations']} relocalisations in {len(lms)} passes;"
            f" most significant log10 NFA {best:.1f}, level {level:.1f}",
            flush=True,
        )
    print(
        f"all: {total[1]} of {total[0]} frames verified a wrong place; {total[3]} false"
        f" relocalisations in {total[2]} passes"
    )


if __name__ == "__main__":
    main()
