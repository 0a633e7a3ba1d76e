"""The simulated devices and camera, and a landmark database made as a user makes one.

``open_sim_devices`` puts the car's devices on simulated buses, read by the real drivers:
wheel speeds as CAN frames on a python-can virtual bus into ``CanOdometry``, headings as NMEA
on a pseudo-terminal into ``SerialCompass``, the roadway scene and the world's landmark
sightings; ``open_sim_camera`` adds the simulated camera and the real recogniser. A car TOML
whose ``[sim]`` table says ``devices = true`` (config/sim-landmarks.toml) makes ``guidance run``
drive the simulated city on them instead of opening hardware, through the car's own wiring
(``guidance.app.build``, ``App``, the real recogniser; the runner is ``hal_sim.sim_cli``'s,
the drive ``hal_sim.drive``'s: this module imports neither). Its landmark database is the
``[landmarks] database``, built on first use the way a user builds one: the city's landmark
photos written to a folder with a ``landmarks.csv``, then ``landmark-db init`` and
``landmark-db import``.
"""

from __future__ import annotations

import contextlib
import csv
import io
import itertools
import os
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import redirect_stdout
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from drivers.can_odometry import CanOdometry, CanOdometryConfig
from drivers.compass import SerialCompass, SerialCompassConfig
from guidance.errors import UserError
from hal_sim.sim_camera import SIM_ORIGIN, SimCamera, SimLandmark, facade, photo_seed
from hal_sim.sim_can import SimCanWheels
from hal_sim.sim_compass import SimCompassPty
from hal_sim.sim_scene import SimScene, SimSightings
from hal_sim.sim_world import SimWorld, landmark_name

if TYPE_CHECKING:
    from guidance.app.app import Source
    from guidance.core.plan.navigator import Landmark
    from hal_sim.drive_options import DriveOptions
    from landmark_db.recognise import Recogniser

_channel_ids = itertools.count()


@dataclass
class SimDevices:
    """The car's devices on simulated buses (``open_sim_devices``)."""

    wheels: SimCanWheels
    odometry: CanOdometry
    scene: SimScene
    sightings: SimSightings
    pty: SimCompassPty | None = None
    compass: SerialCompass | None = None

    def sources(self) -> dict[str, Source]:
        """The app's sources, as ``guidance run`` names them."""
        out: dict[str, Source] = {"odometry": self.odometry}
        if self.compass is not None:
            out["compass"] = self.compass
        out["scene"] = self.scene
        out["landmark"] = self.sightings
        return out


@contextlib.contextmanager
def open_sim_devices(
    world: SimWorld,
    profile: str,
    clock: Callable[[], float],
    *,
    compass: bool = True,
    drive_on_seed: int | None = None,
) -> Iterator[SimDevices]:
    """The devices of ``world`` (the compass with ``compass``), closed on the way out (on an
    error too); ``profile`` is the car's CAN profile, ``clock`` the compass's; the scene's
    driver chooses exits alone when told nothing (``drive_on_seed``: ``SimScene``)."""
    channel = f"sim-can-{os.getpid()}-{next(_channel_ids)}"
    with contextlib.ExitStack() as stack:
        wheels = SimCanWheels(channel, profile=profile).open()
        stack.callback(wheels.close)
        odo = CanOdometry(CanOdometryConfig(interface="virtual", channel=channel,
                          profile=profile, clock="frame", bitrate=None))  # fmt: skip
        stack.callback(_stop, odo)
        pty = reader = None
        if compass:
            pty = SimCompassPty()
            stack.callback(pty.close)
            reader = SerialCompass(SerialCompassConfig(port=pty.port, baudrate=4800), clock=clock)
            stack.callback(_stop, reader)
        scene = SimScene(world, drive_on_seed=drive_on_seed)
        yield SimDevices(wheels, odo, scene, SimSightings(world), pty, reader)


def _stop(source: CanOdometry | SerialCompass) -> None:
    with contextlib.suppress(Exception):
        source.stop()


def open_sim_camera(
    world: SimWorld, opts: DriveOptions, out_dir: Path
) -> tuple[SimCamera, Recogniser, tuple[Landmark, ...]]:
    """The simulated camera, the real recogniser on a database of the city's landmarks, and
    the navigator's landmark list with the database ids (``guidance sim --camera``)."""
    from guidance.core.plan.navigator import Landmark
    from hal_sim.sim_camera import build_sim_landmark_db
    from landmark_db.recognise import Recogniser, RecogniserConfig

    if opts.landmark_db:  # made as a user makes one: photos + CSV + landmark-db import
        from landmark_db.store import open_db

        lms = import_sim_landmark_db(opts.landmark_db, world.lm_xy, opts.seed)
        db = open_db(opts.landmark_db, readonly=True)
    else:
        out_dir.mkdir(parents=True, exist_ok=True)
        path = out_dir / f"landmarks-seed{opts.seed}.sqlite"
        _remove_sqlite_files(path)  # this run's own file of an earlier run, and its sidecars
        db, lms = build_sim_landmark_db(path, world.lm_xy, opts.seed)
    recogniser = Recogniser(db, RecogniserConfig(sighting_range_m=world.sim.sighting_range_m))
    camera = SimCamera(lms, opts.seed)
    landmarks = tuple(Landmark(lm.id, lm.x_m, lm.y_m, landmark_name(i)) for i, lm in enumerate(lms))
    return camera, recogniser, landmarks


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
    images = [photo_file(seed, i) for i in range(len(xy))]
    if not _holds(path, names, images, xy):
        from landmark_db.cli_io import progress

        why = _not_the_simulators(path)
        if why:  # never delete what the simulator did not make (issue 40, defect 11)
            raise UserError(
                f"{path}: {why}: the simulated city's landmark database is built only where "
                "no file is, or over one the simulator built; move it away or name another "
                "[landmarks] database"
            )

        t0 = time.monotonic()
        err = sys.stderr
        err.write(
            f"first use: building the landmark database of the simulated city, "
            f"{os.path.normpath(path)} "
            f"({len(xy)} landmarks: their photos, then landmark-db init and import; about a "
            "minute, once; later runs reuse it)\n"
        )
        err.flush()
        photos = path.parent / f"{path.stem}-photos"
        photos.mkdir(parents=True, exist_ok=True)
        import cv2

        with (photos / "landmarks.csv").open("w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(["image", "name", "x_m", "y_m", "sigma_m"])
            for i, (x, y) in enumerate(xy):
                cv2.imwrite(str(photos / images[i]), facade(photo_seed(seed, i)))
                w.writerow([images[i], names[i], f"{x:.3f}", f"{y:.3f}", "0.5"])
                progress("writing photos", i + 1, len(xy), err)
        # built beside, then renamed over: a stop mid-build leaves the configured path as it was
        tmp = path.with_name(f".{path.name}.building-{os.getpid()}")
        _remove_sqlite_files(tmp)
        log = io.StringIO()
        try:
            with redirect_stdout(log):
                origin = [str(SIM_ORIGIN.lat_deg), str(SIM_ORIGIN.lon_deg)]
                codes = (
                    landmark_db(["init", str(tmp), "--origin", *origin]),
                    landmark_db(["import", str(tmp), str(photos), "--progress"]),
                )
            if any(c not in (0, None) for c in codes):
                raise UserError(
                    f"landmark-db import of the simulated city failed: {log.getvalue()}"
                )
            _remove_sqlite_files(path, keep_db=True)  # the old file's journal must not apply
            os.replace(tmp, path)
        finally:
            _remove_sqlite_files(tmp)
        err.write(
            f"landmark database built in {time.monotonic() - t0:.0f} s: {os.path.normpath(path)}\n"
        )
        err.flush()
    db = open_db(path, readonly=True)
    try:
        by_name = {lm.name: lm for lm in db.landmarks()}
    finally:
        db.close()
    return [
        SimLandmark(by_name[n].id, float(xy[i, 0]), float(xy[i, 1]), photo_seed(seed, i))
        for i, n in enumerate(names)
    ]


def _remove_sqlite_files(path: Path, *, keep_db: bool = False) -> None:
    """``path`` (unless ``keep_db``) and SQLite's own files beside it (``-wal``, ``-shm``,
    ``-journal``), by their exact names: only for a file the simulator made."""
    names = [path.name + s for s in ("-wal", "-shm", "-journal")]
    for name in names if keep_db else [path.name, *names]:
        with contextlib.suppress(FileNotFoundError):
            (path.parent / name).unlink()


def _not_the_simulators(path: Path) -> str:
    """Why the simulator may not build over ``path`` (it did not make it), or "" (no file
    there, or a database of simulated landmarks only, of another city)."""
    if not os.path.lexists(path):
        return ""
    if not path.is_file() or path.is_symlink():
        return "not a regular file"
    from landmark_db.store import open_db

    try:
        db = open_db(path, readonly=True)
    except Exception as exc:  # damaged or foreign: not ours to replace
        return f"it cannot be read as a landmark database ({str(exc)[:80]})"
    try:
        found = sorted(lm.name for lm in db.landmarks())
    finally:
        db.close()
    if found != sorted(landmark_name(i) for i in range(len(found))):
        return f"it holds {len(found)} landmarks the simulator did not make"
    return ""


def photo_file(seed: int, index: int) -> str:
    """The file name of landmark ``index``'s photo in a city of ``seed``: it names the photo's
    seed, and import keeps it as the landmark's ``source``, so a database of another city with
    the same landmark names and positions (another seed's photos) is told apart."""
    return f"landmark{index:05d}-{photo_seed(seed, index):016x}.png"


POSITION_TOLERANCE_M = 0.002
"""How far a stored landmark may be from the city's and still be it: the CSV writes positions
to the millimetre (``%.3f``), so half of that, plus what a float's round trip adds."""


def _holds(path: Path, names: list[str], images: list[str], xy: np.ndarray) -> bool:
    """True when ``path`` is a landmark database of exactly this city: the same landmark
    names, each with its photo (``photo_file``: the city's seed) and position. Names alone
    (issue 40, noticed) reused another city's database of the same size: the camera then saw
    the other city's photos at this city's places."""
    if not path.is_file():
        return False
    from landmark_db.store import open_db

    try:
        db = open_db(path, readonly=True)
    except Exception:  # damaged or foreign: rebuild it
        return False
    try:
        rows = list(db.landmarks())
    finally:
        db.close()
    found = {lm.name: lm for lm in rows}
    if len(rows) != len(names) or sorted(found) != sorted(names):
        return False
    for name, image, (x, y) in zip(names, images, xy, strict=True):
        lm = found[name]
        far = max(abs(lm.x_m - x), abs(lm.y_m - y)) > POSITION_TOLERANCE_M
        if lm.source != image or far:
            return False
    return True
