"""``guidance run`` on the simulated devices, and a landmark database made as a user makes one.

A car TOML whose ``[sim]`` table says ``devices = true`` (config/sim-landmarks.toml) makes
``guidance run`` drive the simulated city instead of opening hardware: CAN frames on a
python-can virtual bus, NMEA on a pseudo-terminal, the simulated camera, and the car's own
wiring (``guidance.app.build``, ``App``, the real recogniser). Its landmark database is the
``[landmarks] database``, built on first use the way a user builds one: the city's landmark
photos written to a folder with a ``landmarks.csv``, then ``landmark-db init`` and
``landmark-db import``.
"""

from __future__ import annotations

import csv
import io
import sys
from contextlib import redirect_stdout
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from guidance.errors import UserError
from hal_sim.sim_camera import SIM_ORIGIN, SimLandmark, facade, photo_seed
from hal_sim.sim_scene import landmark_name


def import_sim_landmark_db(
    path: str | Path, landmarks_xy: np.ndarray, seed: int
) -> list[SimLandmark]:
    """Build ``path`` with ``landmark-db import`` from the city's landmark photos (reused when
    it exists and holds this city); returns the landmarks as the simulated camera sees them."""
    from landmark_db.cli import main as landmark_db
    from landmark_db.store import open_db

    path = Path(path)
    xy = np.asarray(landmarks_xy, dtype=np.float64).reshape(-1, 2)
    names = [landmark_name(i) for i in range(len(xy))]
    if not _holds(path, names):
        for old in path.parent.glob(path.name + "*"):
            old.unlink()
        photos = path.parent / f"{path.stem}-photos"
        photos.mkdir(parents=True, exist_ok=True)
        import cv2

        with (photos / "landmarks.csv").open("w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(["image", "name", "x_m", "y_m", "sigma_m"])
            for i, (x, y) in enumerate(xy):
                image = f"landmark{i:05d}.png"
                cv2.imwrite(str(photos / image), facade(photo_seed(seed, i)))
                w.writerow([image, names[i], f"{x:.3f}", f"{y:.3f}", "0.5"])
        log = io.StringIO()
        with redirect_stdout(log):
            origin = [str(SIM_ORIGIN.lat_deg), str(SIM_ORIGIN.lon_deg)]
            codes = (
                landmark_db(["init", str(path), "--origin", *origin]),
                landmark_db(["import", str(path), str(photos)]),
            )
        if any(c not in (0, None) for c in codes):
            raise UserError(f"landmark-db import of the simulated city failed: {log.getvalue()}")
    db = open_db(path, readonly=True)
    try:
        by_name = {lm.name: lm for lm in db.landmarks()}
    finally:
        db.close()
    return [
        SimLandmark(by_name[n].id, float(xy[i, 0]), float(xy[i, 1]), photo_seed(seed, i))
        for i, n in enumerate(names)
    ]


def _holds(path: Path, names: list[str]) -> bool:
    """True when ``path`` is a landmark database with exactly these landmark names."""
    if not path.is_file():
        return False
    from landmark_db.store import open_db

    try:
        db = open_db(path, readonly=True)
    except Exception:  # damaged or foreign: rebuild it
        return False
    try:
        return sorted(lm.name for lm in db.landmarks()) == sorted(names)
    finally:
        db.close()


def run_on_simulated_devices(config_path: str, *, as_json: bool = False) -> int:
    """``guidance run --config`` with ``[sim] devices = true``: one simulated drive through the
    car's wiring; prints the prompts, the summary and, with ``as_json``, the result as the last
    line (``outcome``, ``landmark_updates``, ``prompts``...)."""
    import json

    from hal_sim.drive import DriveOptions, options_from_config, print_summary, run_drive

    opts, cfg = options_from_config(config_path, DriveOptions())
    if cfg.landmark_db is not None:
        opts = replace(opts, landmark_db=cfg.landmark_db.database)
    if cfg.voice.backend == "none":
        opts = replace(opts, voice="none")
    elif cfg.voice.backend == "wav" and cfg.voice.wav_path:
        opts = replace(opts, voice_to=cfg.voice.wav_path)

    def printer(line: str) -> None:
        sys.stdout.write(line + "\n")

    result = run_drive(opts, printer=printer, app_config=cfg)
    print_summary(result, opts)
    if as_json:
        sys.stdout.write(json.dumps(result.to_json()) + "\n")
    return 0 if result.outcome in ("arrived", "time_limit") else 1


def devices_are_simulated(cfg: Any) -> bool:
    """The config asks ``guidance run`` to drive the simulated devices."""
    return bool(cfg.sim.get("devices", False))
