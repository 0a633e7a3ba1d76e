"""Survey mode: build a sparse landmark map in one drive (issue 5).

While driving with a temporary position source, camera frames are saved as new landmarks
at marked places (typically intersections). Inputs:

* frames: a video file (timestamps from the container) or a folder of images (sorted by
  name, one every ``1 / fps`` seconds);
* positions: a GPS NMEA log (RMC/GGA fixes, pynmea2) and/or a marks CSV. A mark is a time
  ``t_s`` (seconds from the first frame) with an optional position (``lat``/``lon`` or
  ``x_m``/``y_m``) and name. A mark without a position takes the GPS position interpolated
  at its time. With GPS and no marks, a frame is saved every ``every_m`` metres driven.

The NMEA clock is aligned so that the first fix is at ``nmea_offset_s`` on the frame clock.
"""

from __future__ import annotations

import math
from array import array
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

import cv2
import numpy as np
import pynmea2

from guidance import files
from landmark_db.acceptance import IMAGE_EXTS
from landmark_db.features import decode_image, extract
from landmark_db.inputs import read_csv_rows, read_photo
from landmark_db.matcher import SAME_PLACE_RADIUS_M, agreement_config, photo_agreement
from landmark_db.store import LandmarkDb, LandmarkDbError, LandmarkRecord


@dataclass(frozen=True, slots=True)
class Mark:
    """A place to save a frame: time on the frame clock, optional position and name."""

    t_s: float
    name: str = ""
    lat_deg: float | None = None
    lon_deg: float | None = None
    x_m: float | None = None
    y_m: float | None = None


@dataclass(frozen=True, slots=True)
class GpsTrack:
    """GPS fixes: times (s, from the first fix) and lat/lon (degrees), sorted by time."""

    t_s: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray

    def at(self, t_s: float) -> tuple[float, float] | None:
        """Position interpolated at ``t_s``; None outside the track."""
        if len(self.t_s) == 0 or t_s < self.t_s[0] or t_s > self.t_s[-1]:
            return None
        return (
            float(np.interp(t_s, self.t_s, self.lat_deg)),
            float(np.interp(t_s, self.t_s, self.lon_deg)),
        )


def read_nmea(path: Path) -> GpsTrack:
    """Valid RMC fixes (else GGA fixes with quality > 0) of an NMEA log; bad lines are skipped.

    The log is streamed through the door line by line (``files.text_lines``: a line at most
    ``files.MAX_NMEA_LINE_BYTES``), and the fixes kept as doubles (24 bytes a fix), so a
    gigabyte of log never sits in memory as text (issue 40, noticed)."""
    rmc, gga = _Fixes(), _Fixes()
    t0_rmc: datetime | None = None
    try:
        with files.opened(path, "nmea_log") as f:
            for raw in files.text_lines(f, files.MAX_NMEA_LINE_BYTES):
                msg = _sentence(raw)
                if msg is None:
                    continue
                try:
                    if isinstance(msg, pynmea2.types.talker.RMC):
                        if msg.status == "A" and msg.datestamp and msg.timestamp:
                            when = datetime.combine(msg.datestamp, msg.timestamp)
                            la, lo = float(msg.latitude), float(msg.longitude)
                            t0_rmc = when if t0_rmc is None else t0_rmc
                            rmc.add((when - t0_rmc).total_seconds(), la, lo)
                    elif (
                        isinstance(msg, pynmea2.types.talker.GGA)
                        and msg.gps_qual
                        and int(msg.gps_qual) > 0
                        and msg.timestamp
                    ):
                        ts = msg.timestamp
                        sod = ts.hour * 3600 + ts.minute * 60 + ts.second + ts.microsecond / 1e6
                        gga.add(sod, float(msg.latitude), float(msg.longitude))
                except (TypeError, ValueError):
                    continue
    except OSError as exc:
        raise LandmarkDbError(f"{path}: {exc.strerror}") from exc
    if len(rmc.t):
        t, lat, lon = rmc.arrays()
    elif len(gga.t):
        t, lat, lon = gga.arrays()
        t = (t - t[0]) % 86400.0
    else:
        raise LandmarkDbError(f"{path}: no valid GPS fixes (RMC or GGA)")
    order = np.lexsort((lon, lat, t))  # by time (then position: the order sorted() gave)
    return GpsTrack(t[order], lat[order], lon[order])


class _Fixes:
    """Fixes as three arrays of doubles."""

    def __init__(self) -> None:
        self.t, self.lat, self.lon = array("d"), array("d"), array("d")

    def add(self, t_s: float, lat_deg: float, lon_deg: float) -> None:
        self.t.append(t_s)
        self.lat.append(lat_deg)
        self.lon.append(lon_deg)

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        t, lat, lon = (np.array(a, dtype=np.float64) for a in (self.t, self.lat, self.lon))
        return t, lat, lon


def _sentence(raw: bytes) -> pynmea2.NMEASentence | None:
    """The NMEA sentence a log line holds from its first ``$`` (checksum checked), or None."""
    line = raw.decode(errors="replace")
    start = line.find("$")
    if start < 0:
        return None
    try:
        return pynmea2.parse(line[start:].strip(), check=True)
    except (pynmea2.ParseError, ValueError, AttributeError):
        return None


def _opt_float(row: dict[str, str], *keys: str) -> float | None:
    for k in keys:
        v = (row.get(k) or "").strip()
        if v:
            return float(v)
    return None


def read_marks(path: Path) -> list[Mark]:
    """Marks CSV: ``t_s`` required; ``name``, ``lat``/``lon`` or ``x_m``/``y_m`` optional."""
    rows = read_csv_rows(path)
    marks = []
    for i, row in enumerate(rows, start=2):
        try:
            t = _opt_float(row, "t_s", "t")
            if t is None:
                raise ValueError("no t_s")
            marks.append(
                Mark(
                    t,
                    (row.get("name") or "").strip(),
                    _opt_float(row, "lat", "lat_deg"),
                    _opt_float(row, "lon", "lon_deg"),
                    _opt_float(row, "x_m", "x"),
                    _opt_float(row, "y_m", "y"),
                )
            )
        except ValueError as exc:
            raise LandmarkDbError(f"{path}:{i}: bad mark ({exc})") from exc
    return sorted(marks, key=lambda m: m.t_s)


def marks_every(track: GpsTrack, every_m: float) -> list[Mark]:
    """A mark each ``every_m`` metres along the GPS track (equirectangular distances)."""
    if len(track.t_s) < 2:
        return []
    lat0 = math.radians(float(track.lat_deg[0]))
    r = 6_371_000.0
    dx = np.diff(np.radians(track.lon_deg)) * math.cos(lat0) * r
    dy = np.diff(np.radians(track.lat_deg)) * r
    s = np.concatenate([[0.0], np.cumsum(np.hypot(dx, dy))])
    targets = np.arange(0.0, s[-1] + 1e-9, every_m)
    return [Mark(float(np.interp(d, s, track.t_s))) for d in targets]


def frames_from_video(path: Path) -> Iterator[tuple[float, np.ndarray]]:
    """(t_s, image) of every frame of a video file."""
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise LandmarkDbError(f"{path}: cannot open video")
    fps = cap.get(cv2.CAP_PROP_FPS) or 30.0
    try:
        i = 0
        while True:
            ok, image = cap.read()
            if not ok or image is None:
                return
            ms = cap.get(cv2.CAP_PROP_POS_MSEC)
            yield (ms / 1000.0 if ms and ms > 0 else i / fps), image
            i += 1
    finally:
        cap.release()


def frames_from_folder(path: Path, fps: float) -> Iterator[tuple[float, np.ndarray]]:
    """(t_s, image) for the images of a folder, sorted by name, ``1 / fps`` apart."""
    images = sorted(p for p in path.iterdir() if p.suffix.lower() in IMAGE_EXTS)
    if not images:
        raise LandmarkDbError(f"{path}: no images")
    for i, p in enumerate(images):
        try:
            image = decode_image(read_photo(p))  # refuses a truncated file
        except (OSError, ValueError) as exc:
            raise LandmarkDbError(f"{p}: cannot read image ({exc})") from exc
        yield i / fps, image


@dataclass(frozen=True, slots=True)
class Saved:
    landmark_id: int
    name: str
    t_s: float
    frame_t_s: float
    """Time of the frame nearest the mark (the landmark's first photo)."""
    photos: int = 1


def pick_frames(times: list[float], t_mark: float, max_gap_s: float, n: int) -> list[int]:
    """Indexes of up to ``n`` frames for a mark: the nearest, then the nearest to
    ``t_mark -/+ k * max_gap_s / 2`` (before and after: the car approaching and passing, so
    several distances and angles), each within ``max_gap_s`` of the mark, no frame twice."""
    offsets = [0.0]
    for k in range(1, n):
        offsets += [-k * max_gap_s / 2.0, k * max_gap_s / 2.0]
    chosen: list[int] = []
    for off in offsets:
        if len(chosen) == n:
            break
        target = t_mark + off
        best = None
        for i, t in enumerate(times):
            if i in chosen or abs(t - t_mark) > max_gap_s + 1e-9:
                continue
            if best is None or abs(t - target) < abs(times[best] - target):
                best = i
        if best is not None and (off == 0.0 or abs(times[best] - target) <= max_gap_s / 4.0):
            chosen.append(best)
    return chosen


def survey(
    db: LandmarkDb,
    frames: Iterator[tuple[float, np.ndarray]],
    marks: list[Mark],
    track: GpsTrack | None = None,
    name_prefix: str = "survey",
    max_gap_s: float = 1.0,
    position_sigma_m: float = 5.0,
    frames_per_mark: int = 3,
) -> tuple[list[Saved], list[str]]:
    """Save, for each mark, up to ``frames_per_mark`` frames within ``max_gap_s`` of it as
    photos of one landmark (``pick_frames``). A mark named like an existing landmark (the
    same place passed again, e.g. in the other direction) adds its photos to that landmark.

    Returns (saved landmarks, one-line notes on marks that were skipped).
    """
    if frames_per_mark < 1:
        raise LandmarkDbError("frames per mark must be at least 1")
    pending = sorted(marks, key=lambda m: m.t_s)
    saved: list[Saved] = []
    notes: list[str] = []
    window: list[tuple[float, np.ndarray]] = []
    k = 0

    def save(mark: Mark) -> None:
        nonlocal k
        k += 1
        name = mark.name or f"{name_prefix}-{k:04d}"
        times = [t for t, _ in window]
        picked = pick_frames(times, mark.t_s, max_gap_s, frames_per_mark)
        if not picked:
            notes.append(f"{name}: no frame within {max_gap_s} s of t={mark.t_s:.2f}")
            return
        src = f"survey t={mark.t_s:.2f}"
        existing = db.find(name) if mark.name else None
        first = 0
        pos: dict[str, float] = {}
        if mark.lat_deg is not None and mark.lon_deg is not None:
            pos = {"lat_deg": mark.lat_deg, "lon_deg": mark.lon_deg}
        elif mark.x_m is not None and mark.y_m is not None:
            pos = {"x_m": mark.x_m, "y_m": mark.y_m}
        elif track is not None and (ll := track.at(mark.t_s)) is not None:
            pos = {"lat_deg": ll[0], "lon_deg": ll[1]}
        if existing is not None:
            lid = existing.id
            picked = _agreeing(
                db, existing, pos, [window[i][1] for i in picked], picked, name, notes
            )
            if not picked:
                return
        else:
            if not pos:
                notes.append(f"{name}: no position at t={mark.t_s:.2f} (no mark position, no GPS)")
                return
            lid = db.add(
                name,
                window[picked[0]][1],
                position_sigma_m=position_sigma_m,
                source=src,
                image_format=".jpg",
                **pos,  # type: ignore[arg-type]
            )
            first = 1
        for i in picked[first:]:
            t_f = window[i][0]
            db.add_photo(lid, window[i][1], source=f"{src} frame t={t_f:.2f}", image_format=".jpg")
        saved.append(Saved(lid, name, mark.t_s, window[picked[0]][0], len(picked)))

    for t, image in frames:
        while pending and pending[0].t_s + max_gap_s < t:
            save(pending.pop(0))
        window = [(tf, im) for tf, im in window if not pending or tf >= pending[0].t_s - max_gap_s]
        window.append((t, image))
        if not pending:
            break
    for mark in pending:
        if window:
            save(mark)
        else:
            notes.append(f"mark at t={mark.t_s:.2f}: no frames")
    return saved, notes


def _agreeing(
    db: LandmarkDb,
    landmark: LandmarkRecord,
    pos: dict[str, float],
    images: list[np.ndarray],
    picked: list[int],
    name: str,
    notes: list[str],
) -> list[int]:
    """The frames of a mark naming an existing landmark (the place passed again) that may
    join it: each must match the landmark's photos by the decision rule, or by the weaker
    level when the mark's position is within ``SAME_PLACE_RADIUS_M`` of the landmark
    (``matcher.agreement_config``). The others are left out with a note."""
    near = False
    if pos:
        if "x_m" in pos:
            xy = (pos["x_m"], pos["y_m"])
        else:
            xy = db.origin.to_local(pos["lat_deg"], pos["lon_deg"])
        near = math.hypot(xy[0] - landmark.x_m, xy[1] - landmark.y_m) <= SAME_PLACE_RADIUS_M
    kind = db.extractor.kind
    cfg = agreement_config(kind, near)
    existing = db.photo_features(landmark.id)
    keep = []
    for i, image in zip(picked, images, strict=True):
        e = photo_agreement(landmark.id, extract(image, db.extractor), existing, cfg)
        if e is None or e.verified:
            keep.append(i)
        else:
            nfa = f"{e.log_nfa:.1f}" if math.isfinite(e.log_nfa) else "none"
            where = "near it" if near else "not within 40 m of it"
            notes.append(
                f"{name}: a frame does not match landmark {landmark.id}'s photos ({where}:"
                f" {e.inliers} inliers, log10 NFA {nfa}, needs <= {cfg.nfa_needed(kind):g})"
            )
    return keep
