"""A simulated NMEA compass on a pseudo-terminal (SPEC sections 4, 6).

``SimCompassPty`` opens a pty pair (``os.openpty``) and writes ``$HCHDG`` sentences with correct
checksums into the master side; the application opens the slave side with the real pyserial
driver (``drivers.compass.SerialCompass``). ``port`` is a stable symlink to the slave device
(like a udev ``/dev/serial/by-id`` link), so an "unplug" (close the pty, remove the link) and a
"replug" (new pty, same link) look to the driver like a USB adapter coming and going.
Faults for tests: raw garbage bytes, bad checksums, sentences without checksum, unplug/replug.
"""

from __future__ import annotations

import contextlib
import logging
import os
import tempfile
import threading
import tty
from collections.abc import Callable
from pathlib import Path

from hal_sim._periodic import PeriodicThread

log = logging.getLogger(__name__)


def nmea_checksum(body: str) -> int:
    """XOR of the characters between '$' and '*' (NMEA 0183)."""
    cs = 0
    for ch in body.encode("ascii"):
        cs ^= ch
    return cs


def nmea_sentence(body: str, *, checksum: bool = True, corrupt_checksum: bool = False) -> bytes:
    """``$body*hh\\r\\n``; ``corrupt_checksum`` writes a wrong one, ``checksum=False`` none."""
    if not checksum:
        return f"${body}\r\n".encode("ascii")
    cs = nmea_checksum(body) ^ (0x5A if corrupt_checksum else 0)
    return f"${body}*{cs:02X}\r\n".encode("ascii")


def hdg_body(
    heading_deg: float,
    deviation_deg: float | None = None,
    variation_deg: float | None = None,
    talker: str = "HC",
) -> str:
    """HDG fields: sensor heading, deviation E/W, variation E/W (empty when None)."""

    def signed(v: float | None) -> str:
        return "," if v is None else f"{abs(v):.1f},{'E' if v >= 0 else 'W'}"

    return f"{talker}HDG,{heading_deg % 360.0:.1f},{signed(deviation_deg)},{signed(variation_deg)}"


class SimCompassPty:
    """A compass device on a pty: write headings, inject faults, unplug and replug."""

    def __init__(
        self,
        *,
        rate_hz: float = 10.0,
        talker: str = "HC",
        link_dir: str | Path | None = None,
        heading_fn: Callable[[], float] | None = None,
        name: str = "sim_compass",
    ) -> None:
        self.rate_hz = rate_hz
        self.talker = talker
        self.name = name
        self._heading_fn = heading_fn
        self._heading_deg = 0.0
        self._own_dir = link_dir is None
        self._dir = (
            Path(tempfile.mkdtemp(prefix="simcompass-")) if link_dir is None else Path(link_dir)
        )
        self.port = str(self._dir / "ttySIMCOMPASS")
        """Stable path for the driver's ``port`` setting (a symlink to the current slave)."""
        self.slave_path: str | None = None
        self._master: int | None = None
        self._slave: int | None = None
        self._lock = threading.Lock()
        self._tx: PeriodicThread | None = None
        self.sentences_written = 0
        self.bytes_dropped = 0
        self.plug()

    # the device --------------------------------------------------------------------------------

    @property
    def plugged(self) -> bool:
        return self._master is not None

    def plug(self) -> None:
        """Create the pty and point ``port`` at it (again, after ``unplug``)."""
        with self._lock:
            if self._master is not None:
                return
            master, slave = os.openpty()
            tty.setraw(slave)  # no echo, no CR/LF translation: bytes arrive as written
            os.set_blocking(master, False)  # a reader that stalls costs dropped bytes, not us
            self._master, self._slave = master, slave
            self.slave_path = os.ttyname(slave)
            tmp = f"{self.port}.tmp"
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp)
            os.symlink(self.slave_path, tmp)
            os.replace(tmp, self.port)

    def unplug(self) -> None:
        """Close the pty and remove ``port``: the driver's reads fail, its reopen finds nothing."""
        with self._lock:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(self.port)
            for fd in (self._master, self._slave):
                if fd is not None:
                    os.close(fd)
            self._master = self._slave = None
            self.slave_path = None

    def close(self) -> None:
        self.stop()
        self.unplug()
        if self._own_dir:
            with contextlib.suppress(OSError):
                self._dir.rmdir()

    def __enter__(self) -> SimCompassPty:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # writing -----------------------------------------------------------------------------------

    def write_raw(self, data: bytes) -> int:
        """Write bytes as they are (garbage, partial lines); returns how many were accepted."""
        with self._lock:
            if self._master is None:
                self.bytes_dropped += len(data)
                return 0
            try:
                n = os.write(self._master, data)
            except (BlockingIOError, OSError):
                n = 0
            self.bytes_dropped += len(data) - n
            return n

    def write_sentence(
        self, body: str, *, checksum: bool = True, corrupt_checksum: bool = False
    ) -> None:
        self.write_line(nmea_sentence(body, checksum=checksum, corrupt_checksum=corrupt_checksum))

    def write_line(self, line: bytes, *, sentence: bool = True) -> None:
        """Write one whole line (``hal_sim.car_inputs.DeviceWire.compass_line``); a
        ``sentence`` written is counted in ``sentences_written``."""
        if self.write_raw(line) and sentence:
            self.sentences_written += 1

    def write_heading(
        self,
        heading_deg: float,
        *,
        deviation_deg: float | None = None,
        variation_deg: float | None = None,
        corrupt_checksum: bool = False,
    ) -> None:
        """One ``$HCHDG`` sentence now (a stepped simulation calls this at its compass rate)."""
        body = hdg_body(heading_deg, deviation_deg, variation_deg, self.talker)
        self.write_sentence(body, corrupt_checksum=corrupt_checksum)

    def set_heading(self, heading_deg: float) -> None:
        """Heading (magnetic, degrees clockwise from north) the writer thread sends next."""
        self._heading_deg = heading_deg

    # own thread at the device's rate -----------------------------------------------------------

    def start(self) -> None:
        if self._tx is None:
            self._tx = PeriodicThread(f"{self.name}-tx", 1.0 / self.rate_hz, self._send_current)
            self._tx.start()

    def stop(self) -> None:
        if self._tx is not None:
            self._tx.stop()
            self._tx = None

    def _send_current(self) -> None:
        heading = self._heading_fn() if self._heading_fn is not None else self._heading_deg
        self.write_heading(heading)
