"""Survey inputs: the GPS log is streamed through the door (the survey's drives are in
tests/landmark_db/test_cli.py)."""

from __future__ import annotations

import shutil
import tracemalloc
from pathlib import Path

import numpy as np

from landmark_db.survey import read_nmea

REPO = Path(__file__).resolve().parents[2]
GPS_LOG = REPO / "tests" / "data" / "nmea" / "rst39.log"
LOG_BYTES = 64 << 20
PEAK_LIMIT_BYTES = 16 << 20
"""What reading the log may allocate at its peak: the line buffer (4 KiB), the fixes (24 bytes
each) and pynmea2's objects; a log read whole costs at least its size (64 MiB here)."""


def test_a_big_gps_log_is_streamed_not_read_whole(tmp_path: Path) -> None:
    """Issue 40 (noticed): ``read_nmea`` read the whole log (up to the door's 1 GiB), decoded
    it and split it into lines: several times the file in memory. A 64 MiB log (the real
    log's fixes, then a sparse tail of NUL bytes: no line ends) gives the real log's fixes,
    with Python's allocations at their peak far below the file's size."""
    path = tmp_path / "gps.log"
    shutil.copyfile(GPS_LOG, path)
    with path.open("r+b") as f:
        f.truncate(LOG_BYTES)  # sparse: costs no disk
    want = read_nmea(GPS_LOG)
    tracemalloc.start()
    try:
        got = read_nmea(path)
        _now, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < PEAK_LIMIT_BYTES, f"peak {peak / 2**20:.1f} MiB reading a 64 MiB log"
    assert len(want.t_s) == 4
    for a, b in ((got.t_s, want.t_s), (got.lat_deg, want.lat_deg), (got.lon_deg, want.lon_deg)):
        assert np.array_equal(a, b)
