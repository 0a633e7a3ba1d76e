"""Simulated camera frames that exercise the real landmark matcher (SPEC section 4, issue 5).

Every landmark of a simulated city gets a distinct procedurally generated photo (a
building facade: wall texture, a window grid, a door, shop signs with random text, random
shapes), seeded so that the same seed always draws the same photo. ``build_sim_landmark_db``
writes those photos into a real landmark database; ``SimCamera.frame_at`` renders what the
camera sees at the car's true position:

* within ``sighting_range_m`` of a landmark: a perturbed view of its photo (random
  perspective warp, scale by distance, brightness/contrast, blur, partial occlusion, noise)
  pasted on a street background;
* elsewhere: another scene, and with probability ``lookalike_prob`` a *look-alike* of the
  nearest landmark (same wall colour, window style and grid as its facade, different
  details: window positions, signs, door, ornaments). An exact copy of a facade cannot
  be told apart by any matcher; gating is the defence against those.

The landmark's detection rate is then whatever the real ``landmark_db.recognise`` pipeline
makes of these frames (``python -m hal_sim.sim_camera`` measures it).
"""

from __future__ import annotations

import math
import string
from collections import Counter, OrderedDict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from guidance.core.geo import Origin
from guidance.core.messages import CameraFrame
from landmark_db.store import LandmarkDb, create_db

PHOTO_SIZE = (480, 640)
"""(height, width) of a generated landmark photo."""
SIM_ORIGIN = Origin(42.4440, -76.5019)
"""Default origin of a simulated city's database (Ithaca, NY, where the paper's car drove)."""
_FONTS = (
    cv2.FONT_HERSHEY_SIMPLEX,
    cv2.FONT_HERSHEY_DUPLEX,
    cv2.FONT_HERSHEY_COMPLEX,
    cv2.FONT_HERSHEY_TRIPLEX,
    cv2.FONT_HERSHEY_PLAIN,
)


def _colour(rng: np.random.Generator, lo: int = 0, hi: int = 256) -> tuple[int, int, int]:
    c = rng.integers(lo, hi, 3)
    return int(c[0]), int(c[1]), int(c[2])


def _texture(rng: np.random.Generator, h: int, w: int, base: tuple[int, int, int]) -> np.ndarray:
    """A wall: base colour with low-frequency blotches and fine grain."""
    coarse = rng.normal(0.0, 18.0, (max(2, h // 40), max(2, w // 40)))
    low = cv2.resize(coarse, (w, h), interpolation=cv2.INTER_CUBIC)[..., None]
    grain = rng.normal(0.0, 6.0, (h, w, 1))
    img = np.asarray(base, np.float64)[None, None, :] + low + grain
    return np.clip(img, 0, 255).astype(np.uint8)


@dataclass(frozen=True, slots=True)
class _Style:
    """What a facade and its look-alikes share."""

    wall: tuple[int, int, int]
    frame: tuple[int, int, int]
    glass: tuple[int, int, int]
    rows: int
    cols: int


def _style(family_seed: int) -> _Style:
    rng = np.random.default_rng([family_seed, 1])
    return _Style(
        wall=_colour(rng, 60, 220),
        frame=_colour(rng, 0, 255),
        glass=_colour(rng, 20, 120),
        rows=int(rng.integers(2, 5)),
        cols=int(rng.integers(3, 7)),
    )


def facade(
    seed: int, family_seed: int | None = None, size: tuple[int, int] = PHOTO_SIZE
) -> np.ndarray:
    """A building facade photo (BGR). ``seed`` draws the details; ``family_seed`` (default:
    ``seed``) the shared style, so ``facade(s2, family_seed=s1)`` is a look-alike of
    ``facade(s1)``."""
    h, w = size
    style = _style(seed if family_seed is None else family_seed)
    rng = np.random.default_rng([seed, 2])
    img = _texture(rng, h, w, style.wall)
    # Window grid: same grid for a family, jittered sizes and positions per building.
    top, bottom = int(0.08 * h), int(0.62 * h)
    cell_h = (bottom - top) / style.rows
    cell_w = w / style.cols
    for r in range(style.rows):
        for c in range(style.cols):
            if rng.random() < 0.12:
                continue  # a blank bay
            ww = cell_w * rng.uniform(0.35, 0.7)
            wh = cell_h * rng.uniform(0.45, 0.8)
            x0 = int(c * cell_w + rng.uniform(0.1, 0.9) * (cell_w - ww))
            y0 = int(top + r * cell_h + rng.uniform(0.1, 0.9) * (cell_h - wh))
            x1, y1 = int(x0 + ww), int(y0 + wh)
            glass = tuple(
                int(v) for v in np.clip(np.add(style.glass, rng.integers(-40, 40, 3)), 0, 255)
            )
            cv2.rectangle(img, (x0, y0), (x1, y1), glass, -1)
            cv2.rectangle(img, (x0, y0), (x1, y1), style.frame, int(rng.integers(2, 6)))
            if rng.random() < 0.6:  # glazing bars or curtains
                cv2.line(img, ((x0 + x1) // 2, y0), ((x0 + x1) // 2, y1), style.frame, 2)
            if rng.random() < 0.4:
                cv2.line(img, (x0, (y0 + y1) // 2), (x1, (y0 + y1) // 2), style.frame, 2)
            if rng.random() < 0.3:
                pts = rng.integers([x0, y0], [x1 + 1, y1 + 1], (3, 2)).astype(np.int32)
                cv2.fillPoly(img, [pts], _colour(rng))
    # Ground floor: door and shop signs with random text.
    gy = int(0.66 * h)
    dx = int(rng.uniform(0.05, 0.8) * w)
    cv2.rectangle(img, (dx, gy), (dx + int(0.12 * w), h - 1), _colour(rng, 0, 120), -1)
    cv2.circle(img, (dx + int(0.1 * w), int(0.83 * h)), 5, _colour(rng, 150, 256), -1)
    for _ in range(int(rng.integers(1, 3))):
        sx0 = int(rng.uniform(0.0, 0.6) * w)
        sy0 = int(rng.uniform(0.63, 0.85) * h)
        sx1 = min(w - 1, sx0 + int(rng.uniform(0.25, 0.4) * w))
        sy1 = min(h - 1, sy0 + int(rng.uniform(0.07, 0.12) * h))
        bg = _colour(rng)
        cv2.rectangle(img, (sx0, sy0), (sx1, sy1), bg, -1)
        text = "".join(
            rng.choice(list(string.ascii_uppercase + string.digits), int(rng.integers(4, 9)))
        )
        fg = tuple(255 - v for v in bg)
        font = _FONTS[int(rng.integers(len(_FONTS)))]
        scale = (sy1 - sy0) / 30.0
        cv2.putText(img, text, (sx0 + 4, sy1 - 6), font, scale, fg, 2, cv2.LINE_AA)
    # Ornaments: circles, polygons, a cornice.
    for _ in range(int(rng.integers(3, 8))):
        centre = (int(rng.integers(0, w)), int(rng.integers(0, h)))
        if rng.random() < 0.5:
            cv2.circle(
                img, centre, int(rng.integers(6, 30)), _colour(rng), int(rng.choice([-1, 3]))
            )
        else:
            pts = (np.array(centre) + rng.integers(-40, 40, (int(rng.integers(3, 6)), 2))).astype(
                np.int32
            )
            cv2.fillPoly(img, [pts], _colour(rng))
    cv2.rectangle(img, (0, 0), (w - 1, int(rng.uniform(0.02, 0.06) * h)), _colour(rng), -1)
    return img


@dataclass(frozen=True, slots=True)
class SimLandmark:
    """A landmark of the simulated city: its database id, true position and photo seed."""

    id: int
    x_m: float
    y_m: float
    photo_seed: int


def photo_seed(city_seed: int, index: int) -> int:
    """The photo seed of landmark ``index`` of a city (distinct per landmark and city)."""
    return int(np.random.default_rng([city_seed, index, 7]).integers(1, 2**62))


def build_sim_landmark_db(
    path: str | Path,
    landmarks_xy: np.ndarray,
    seed: int,
    origin: Origin = SIM_ORIGIN,
) -> tuple[LandmarkDb, list[SimLandmark]]:
    """A landmark database for a simulated city: one generated photo per landmark.

    ``landmarks_xy`` is N x 2 local metres (``hal_sim.world.place_landmarks``'s positions);
    positions are exact (``position_sigma_m = 0``), so a fix has sigma = range / 2. Returns
    the open (writable) database and the landmarks for ``SimCamera``. About 15 ms per
    landmark.
    """
    xy = np.asarray(landmarks_xy, dtype=np.float64).reshape(-1, 2)
    db = create_db(path, origin)
    out = []
    for i, (x, y) in enumerate(xy):
        ps = photo_seed(seed, i)
        lid = db.add(
            f"sim-{i:05d}",
            facade(ps),
            x_m=float(x),
            y_m=float(y),
            position_sigma_m=0.0,
            source=f"hal_sim seed={seed} photo_seed={ps}",
        )
        out.append(SimLandmark(lid, float(x), float(y), ps))
    return db, out


def sim_landmarks_from_db(db: LandmarkDb) -> list[SimLandmark]:
    """The ``SimLandmark`` list of a database made by ``build_sim_landmark_db``."""
    out = []
    for lm in db.landmarks():
        seed_txt = lm.source.rpartition("photo_seed=")[2]
        if not seed_txt.isdigit():
            raise ValueError(f"landmark {lm.id} was not made by build_sim_landmark_db")
        out.append(SimLandmark(lm.id, lm.x_m, lm.y_m, int(seed_txt)))
    return out


@dataclass(frozen=True, slots=True)
class SimCameraConfig:
    """How the simulated camera sees. Sizes in pixels, distances in metres."""

    width: int = 640
    height: int = 480
    sighting_range_m: float = 20.0
    perspective: float = 0.2
    """Corner jitter of the warp, as a fraction of the facade's size in the frame."""
    brightness: float = 60.0
    """Brightness offset drawn from +-this (grey levels)."""
    contrast: tuple[float, float] = (0.5, 1.4)
    blur_sigma_px: tuple[float, float] = (0.0, 2.5)
    motion_blur_px: tuple[float, float] = (0.0, 12.0)
    """Length of a horizontal motion-blur streak (the car moves, the shutter is open)."""
    occlusion: tuple[float, float] = (0.0, 0.6)
    """Share of the facade's width covered by an occluder (a parked van, a pedestrian)."""
    noise_sigma: float = 4.0
    lookalike_prob: float = 0.5
    """Away from landmarks: probability that the frame shows a look-alike of the nearest."""

    def __post_init__(self) -> None:
        if self.width < 64 or self.height < 64:
            raise ValueError("frame must be at least 64x64")
        if not 0.0 <= self.lookalike_prob <= 1.0:
            raise ValueError("lookalike_prob must be in [0, 1]")


class SimCamera:
    """Renders the camera frame at the car's true position (see the module docstring).

    Deterministic for a given ``seed`` and call sequence. ``last_truth`` says what the last
    frame showed: ``("landmark", id)``, ``("lookalike", id)`` or ``("scene", None)``.
    """

    name = "sim-camera"

    def __init__(
        self,
        landmarks: Sequence[SimLandmark],
        seed: int = 0,
        config: SimCameraConfig | None = None,
    ) -> None:
        self.config = config or SimCameraConfig()
        self._lm = list(landmarks)
        self._xy = np.array([(lm.x_m, lm.y_m) for lm in self._lm], dtype=np.float64).reshape(-1, 2)
        self._rng = np.random.default_rng([seed, 11])
        self._photos: OrderedDict[tuple[int, int], np.ndarray] = OrderedDict()
        self._counts: Counter[str] = Counter()
        self.last_truth: tuple[str, int | None] = ("scene", None)

    def stats(self) -> Mapping[str, int]:
        return {k: self._counts[k] for k in ("frames", "landmark", "lookalike", "scene")}

    def _photo(self, seed: int, family: int) -> np.ndarray:
        key = (seed, family)
        img = self._photos.get(key)
        if img is None:
            img = facade(seed, family)
            self._photos[key] = img
            if len(self._photos) > 64:
                self._photos.popitem(last=False)
        return img

    def nearest(self, x_m: float, y_m: float) -> tuple[int, float]:
        """Index and distance of the nearest landmark (-1, inf when there are none)."""
        if len(self._xy) == 0:
            return -1, math.inf
        d = np.hypot(self._xy[:, 0] - x_m, self._xy[:, 1] - y_m)
        i = int(np.argmin(d))
        return i, float(d[i])

    def frame_at(self, t_s: float, x_m: float, y_m: float) -> CameraFrame:
        """The frame seen from true position (x, y) at time ``t_s``."""
        cfg = self.config
        i, d = self.nearest(x_m, y_m)
        if i >= 0 and d <= cfg.sighting_range_m:
            lm = self._lm[i]
            image = self.view(self._photo(lm.photo_seed, lm.photo_seed), d)
            self.last_truth = ("landmark", lm.id)
        elif i >= 0 and self._rng.random() < cfg.lookalike_prob:
            lm = self._lm[i]
            other = int(self._rng.integers(1, 2**62))
            image = self.view(self._photo(other, lm.photo_seed), cfg.sighting_range_m * 0.5)
            self.last_truth = ("lookalike", lm.id)
        else:
            other = int(self._rng.integers(1, 2**62))
            image = self.view(self._photo(other, other), cfg.sighting_range_m * 0.5)
            self.last_truth = ("scene", None)
        self._counts["frames"] += 1
        self._counts[self.last_truth[0]] += 1
        return CameraFrame(t_s=t_s, image=image, source=self.name)

    def view(self, photo: np.ndarray, distance_m: float) -> np.ndarray:
        """A perturbed view of ``photo`` from ``distance_m`` away, on a street background."""
        cfg = self.config
        rng = self._rng
        W, H = cfg.width, cfg.height
        frame = self._background(rng, H, W)
        # Apparent size: about the frame's width when close, a third of it at the range;
        # off-centre by up to a quarter of the frame (part of it may be cut off).
        near = 1.0 - min(max(distance_m / max(cfg.sighting_range_m, 1e-6), 0.0), 1.0)
        fw = W * (0.35 + 0.65 * near) * rng.uniform(0.85, 1.1)
        ph, pw = photo.shape[:2]
        fh = fw * ph / pw
        cx = W / 2 + rng.uniform(-0.25, 0.25) * W
        cy = H / 2 + rng.uniform(-0.2, 0.2) * H
        dst = np.array(
            [
                [cx - fw / 2, cy - fh / 2],
                [cx + fw / 2, cy - fh / 2],
                [cx + fw / 2, cy + fh / 2],
                [cx - fw / 2, cy + fh / 2],
            ],
            dtype=np.float64,
        )
        dst += rng.uniform(-cfg.perspective, cfg.perspective, (4, 2)) * [fw, fh]
        src = np.array([[0, 0], [pw, 0], [pw, ph], [0, ph]], dtype=np.float32)
        M = cv2.getPerspectiveTransform(src, dst.astype(np.float32))
        warped = cv2.warpPerspective(photo, M, (W, H))
        mask = cv2.warpPerspective(np.full((ph, pw), 255, np.uint8), M, (W, H))
        frame[mask > 0] = warped[mask > 0]
        # Occluder: a dark box from the bottom (a van) or a tall one (a pedestrian, a pole).
        occ = rng.uniform(*cfg.occlusion)
        if occ > 0.01:
            ow = int(occ * fw)
            ox = int(rng.uniform(cx - fw / 2, cx + fw / 2 - ow))
            oy = int(rng.uniform(0.3, 0.7) * H)
            cv2.rectangle(frame, (ox, oy), (ox + ow, H - 1), _colour(rng, 0, 90), -1)
        # Photometric: contrast, brightness, blur, sensor noise.
        alpha = rng.uniform(*cfg.contrast)
        beta = rng.uniform(-cfg.brightness, cfg.brightness)
        lit = frame.astype(np.float32) * alpha + beta
        sigma = rng.uniform(*cfg.blur_sigma_px)
        if sigma > 0.3:
            lit = np.asarray(cv2.GaussianBlur(lit, (0, 0), sigma), np.float32)
        streak = int(rng.uniform(*cfg.motion_blur_px))
        if streak >= 2:
            kernel = np.full((1, streak), 1.0 / streak, np.float32)
            lit = np.asarray(cv2.filter2D(lit, -1, kernel), np.float32)
        noise = np.empty(lit.shape, np.float32)
        cv2.setRNGSeed(int(rng.integers(2**31)))
        cv2.randn(noise, np.zeros(1), np.full(1, cfg.noise_sigma))
        lit += noise
        return np.clip(lit, 0, 255).astype(np.uint8)

    @staticmethod
    def _background(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
        """Sky, a road and some street clutter (smooth: few corners for ORB)."""
        img = np.empty((h, w, 3), np.uint8)
        horizon = int(rng.uniform(0.3, 0.5) * h)
        img[:horizon] = _colour(rng, 150, 256)
        img[horizon:] = _colour(rng, 40, 110)
        for _ in range(int(rng.integers(2, 6))):
            x = int(rng.integers(0, w))
            cv2.line(img, (x, horizon), (int(rng.integers(0, w)), h - 1), _colour(rng, 100, 256), 3)
        return img


def measure_detection(
    n_sightings: int = 200,
    frames_per_sighting: int = 4,
    n_landmarks: int = 40,
    seed: int = 1,
    workdir: str | Path | None = None,
) -> dict[str, float]:
    """Run the real recogniser on simulated passes and return the figures.

    A sighting is a pass of the car by a landmark: ``frames_per_sighting`` frames at
    random distances within the sighting range (4 frames: 2 s in range at the 2 Hz a
    recogniser sustains beside the estimator on the reference laptop), with the estimate
    centred on the truth and a 2-sigma ellipse of 30 m; it is *confirmed* if the
    recogniser emits a fix for that landmark. A look-alike pass is the same with frames of
    look-alikes of the candidate; any fix there is a false match.
    """
    import tempfile

    from landmark_db.recognise import Recogniser

    rng = np.random.default_rng([seed, 3])
    # Landmarks 200 m apart on a line: one candidate per pass, as at city densities.
    xy = np.column_stack([np.arange(n_landmarks) * 200.0, np.zeros(n_landmarks)])
    cov = ((15.0**2, 0.0), (0.0, 15.0**2))
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        db, lms = build_sim_landmark_db(Path(tmp) / "sim.sqlite", xy, seed)
        cam = SimCamera(lms, seed)
        kin = SimCamera(lms, seed + 1, SimCameraConfig(lookalike_prob=1.0))
        rec = Recogniser(db)
        confirmed = frames_ok = false_fix = false_frames = 0
        t = 0.0
        try:
            for _ in range(n_sightings):
                lm = lms[int(rng.integers(len(lms)))]
                got = False
                for _ in range(frames_per_sighting):
                    t += 0.5
                    ang = rng.uniform(0, 2 * math.pi)
                    dist = rng.uniform(0, cam.config.sighting_range_m)
                    x, y = lm.x_m + dist * math.cos(ang), lm.y_m + dist * math.sin(ang)
                    res = rec.process_xy(cam.frame_at(t, x, y), (x, y), cov)
                    frames_ok += res.landmark_id == lm.id
                    got |= res.fix is not None and res.fix.landmark_id == lm.id
                    false_fix += res.fix is not None and res.fix.landmark_id != lm.id
                confirmed += got
                t += 60.0  # next pass later: no refix hold-off, no streak carried over
                # A look-alike pass: the estimate says we are near lm, the camera sees its kin.
                for _ in range(frames_per_sighting):
                    t += 0.5
                    x, y = lm.x_m + 3 * kin.config.sighting_range_m, lm.y_m
                    frame = kin.frame_at(t, x, y)  # out of range: a look-alike of lm
                    res = rec.process_xy(frame, (lm.x_m, lm.y_m), cov)
                    false_frames += res.landmark_id is not None
                    false_fix += res.fix is not None
                t += 60.0
        finally:
            rec.close()
    return {
        "sightings": float(n_sightings),
        "confirmed_rate": confirmed / n_sightings,
        "frame_verify_rate": frames_ok / (n_sightings * frames_per_sighting),
        "lookalike_frames": float(n_sightings * frames_per_sighting),
        "lookalike_verified_frames": float(false_frames),
        "false_fixes": float(false_fix),
    }


if __name__ == "__main__":  # pragma: no cover - prints the figures for docs/landmarks.md
    import time as _time

    t0 = _time.perf_counter()
    figs = measure_detection()
    for key, value in figs.items():
        print(f"{key:>32}: {value:.3f}")  # noqa: T201
    print(f"{'elapsed_s':>32}: {_time.perf_counter() - t0:.1f}")  # noqa: T201
