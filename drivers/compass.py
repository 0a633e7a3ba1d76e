"""Serial compass: NMEA 0183 HDG / HDM / HDT over pyserial (SPEC sections 2, 6).

``NmeaCompassParser`` is pure: bytes of one line in, a ``CompassHeading`` or ``None`` out, every
rejection counted by reason. pynmea2 splits and checksums the sentences (wrapped here only).

Rules, chosen so that a corrupted line can never become a heading:

* A sentence must carry a ``*hh`` checksum, and it must match. Sentences without one are
  rejected (``no_checksum``) unless ``allow_missing_checksum`` is set, for devices that never
  send one; a line with a damaged checksum field is a ``checksum`` rejection.
* Junk before the last ``$`` of a line (a collision of two sentences, line noise) is dropped and
  the rest parsed; the checksum then decides.
* HDG carries the sensor heading plus the device's deviation and variation. The deviation is the
  device's own calibration for the vehicle's magnetic field, so it is applied (E positive) when
  present (``apply_hdg_deviation``); the variation is ignored: declination comes from the World
  Magnetic Model at the start position and date (``drivers.magnetic``), the same for every
  device. HDM is magnetic as sent; HDT is true (``is_true``), so no declination is added later.
* Headings must be finite and within [0, 360]; 360 is folded to 0.

``SerialCompass`` is the ``CompassSource``: a reader thread with read timeouts that assembles
lines itself (bounded length, so binary garbage or a missing newline cannot grow memory or hang
it), timestamps each line with ``time.monotonic()`` on arrival, and reconnects with exponential
backoff after an unplug, logging once when the device goes and once when it comes back.
"""

from __future__ import annotations

import logging
import math
import re
import time
from collections import Counter
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import pynmea2
import serial

from drivers._reader import ThreadedSource, rejection_counters
from guidance import files
from guidance.core.messages import CompassHeading, RawNmeaLine
from guidance.errors import UserError

log = logging.getLogger(__name__)

MAX_LINE_BYTES = 256
"""NMEA 0183 allows 82 characters; anything much longer is garbage or two lines run together."""
HEADING_TYPES = ("HDG", "HDM", "HDT")
REJECT_REASONS = (
    "not_nmea",
    "too_long",
    "no_checksum",
    "checksum",
    "parse",
    "unknown_type",
    "empty_heading",
    "out_of_range",
)
_CHECKSUM_RE = re.compile(r"\*([0-9A-Fa-f]{2})$")


class LineAssembler:
    """Split a byte stream into lines (CR, LF or CRLF), never holding more than ``max_bytes``.

    A run longer than that without a line end is dropped up to the next line end and reported
    once through ``on_too_long``. Empty lines are skipped.
    """

    def __init__(
        self, max_bytes: int = MAX_LINE_BYTES, on_too_long: Callable[[], None] | None = None
    ) -> None:
        self.max_bytes = max_bytes
        self._on_too_long = on_too_long
        self._buf = bytearray()
        self._discarding = False

    def feed(self, chunk: bytes) -> list[bytes]:
        out: list[bytes] = []
        start = 0
        for m in _EOL_RE.finditer(chunk):
            self._add(chunk[start : m.start()])
            if self._discarding:
                self._discarding = False
            elif self._buf:
                out.append(bytes(self._buf))
            self._buf.clear()
            start = m.end()
        self._add(chunk[start:])
        return out

    def flush(self) -> list[bytes]:
        """The unterminated tail (end of a file); a live stream keeps it for the next chunk."""
        tail = [] if self._discarding or not self._buf else [bytes(self._buf)]
        self._buf.clear()
        self._discarding = False
        return tail

    def _add(self, piece: bytes) -> None:
        if self._discarding or not piece:
            return
        if len(self._buf) + len(piece) > self.max_bytes:
            self._buf.clear()
            self._discarding = True
            if self._on_too_long is not None:
                self._on_too_long()
        else:
            self._buf += piece


class NmeaCompassParser:
    """NMEA heading sentences -> ``CompassHeading``; everything else counted and skipped."""

    def __init__(
        self,
        *,
        allow_missing_checksum: bool = False,
        apply_hdg_deviation: bool = True,
        max_line_bytes: int = MAX_LINE_BYTES,
    ) -> None:
        self.allow_missing_checksum = allow_missing_checksum
        self.apply_hdg_deviation = apply_hdg_deviation
        self.max_line_bytes = max_line_bytes
        self.lines = 0
        self.last_outcome = "none"
        """What the last ``feed_line`` did: "ok", or the reason the line was rejected."""
        self.headings = 0
        self.true_headings = 0
        self.resynced = 0
        """Lines whose junk before the last '$' was dropped (collisions, noise)."""
        self.rejected_by_reason: Counter[str] = Counter()
        self.by_type: Counter[str] = Counter()

    @property
    def rejected(self) -> int:
        return sum(self.rejected_by_reason.values())

    def stats(self) -> dict[str, int]:
        out = {
            "lines": self.lines,
            "headings": self.headings,
            "true_headings": self.true_headings,
            "resynced": self.resynced,
            "rejected": self.rejected,
        }
        out.update(rejection_counters(self.rejected_by_reason, REJECT_REASONS))
        return out

    def reject(self, reason: str) -> None:
        """Count one line rejected outside ``feed_line`` (e.g. too long to assemble)."""
        self.lines += 1
        self.rejected_by_reason[reason] += 1
        self.last_outcome = reason

    def feed_line(self, line: bytes, t_s: float | None = None) -> CompassHeading | None:
        """Parse one line; ``t_s`` is its arrival time (``time.monotonic()`` now if omitted)."""
        self.lines += 1
        reason, heading = self._parse(line.strip())
        self.last_outcome = reason or "ok"
        if reason is not None:
            self.rejected_by_reason[reason] += 1
            return None
        assert heading is not None
        self.headings += 1
        if heading.is_true:
            self.true_headings += 1
        return CompassHeading(
            t_s=time.monotonic() if t_s is None else t_s,
            heading_deg=heading.heading_deg,
            is_true=heading.is_true,
        )

    def _parse(self, raw: bytes) -> tuple[str | None, CompassHeading | None]:
        if len(raw) > self.max_line_bytes:
            return "too_long", None
        try:
            text = raw.decode("ascii")
        except UnicodeDecodeError:
            return "not_nmea", None
        if not text.isprintable():
            return "not_nmea", None
        start = text.rfind("$")
        if start < 0:
            # '!' is NMEA's encapsulation start (AIS): a sentence, just not ours.
            return ("unknown_type" if text.startswith("!") else "not_nmea"), None
        if start > 0:
            self.resynced += 1
            text = text[start:]
        if "*" in text:
            if not _CHECKSUM_RE.search(text):
                return "checksum", None
        elif not self.allow_missing_checksum:
            return "no_checksum", None
        try:
            msg = pynmea2.parse(text)
        except pynmea2.ChecksumError:
            return "checksum", None
        except pynmea2.SentenceTypeError:
            return "unknown_type", None
        except Exception:  # pynmea2.ParseError and anything else its regexes let through
            return "parse", None
        kind = getattr(msg, "sentence_type", "")
        if kind not in HEADING_TYPES or not isinstance(msg, pynmea2.TalkerSentence):
            return "unknown_type", None
        self.by_type[kind] += 1
        value = _number(msg.data[0] if msg.data else "")
        if value is None:
            return "empty_heading", None
        if isinstance(value, str):
            return "parse", None
        if not (math.isfinite(value) and 0.0 <= value <= 360.0):
            return "out_of_range", None
        if kind == "HDG" and self.apply_hdg_deviation:
            deviation = _signed_field(msg.data, 1, 2)
            if isinstance(deviation, str):
                return "parse", None
            if deviation is not None:
                if not (math.isfinite(deviation) and abs(deviation) <= 180.0):
                    return "out_of_range", None
                value += deviation
        return None, CompassHeading(t_s=0.0, heading_deg=value % 360.0, is_true=kind == "HDT")


_EOL_RE = re.compile(rb"[\r\n]")


_DECIMAL = re.compile(r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)")
"""An NMEA number: ASCII digits and one decimal point, nothing else."""


def _number(field_text: str) -> float | str | None:
    """None for an empty field, the float, or the text itself when it is not a number."""
    field_text = field_text.strip()
    if not field_text:
        return None
    if _DECIMAL.fullmatch(field_text) is None:  # float() takes 1_0_0, 1e3, unicode digits
        try:
            special = float(field_text)
        except ValueError:
            return field_text
        return special if not math.isfinite(special) else field_text  # nan, inf: out of range
    return float(field_text)


def _signed_field(data: Sequence[str], value_idx: int, dir_idx: int) -> float | str | None:
    """An 'angle, E/W' field pair of HDG as degrees, east positive; text when malformed."""
    value = _number(data[value_idx] if len(data) > value_idx else "")
    if value is None or isinstance(value, str):
        return value
    direction = (data[dir_idx] if len(data) > dir_idx else "").strip().upper()
    if direction == "E":
        return value
    if direction == "W":
        return -value
    if not direction and value == 0.0:
        return 0.0
    return direction or "missing E/W"


def heading_stats(headings_deg: Iterable[float]) -> dict[str, float] | None:
    """Circular mean and standard deviation (sqrt(-2 ln R)), min and max, in degrees."""
    values = list(headings_deg)
    if not values:
        return None
    c = sum(math.cos(math.radians(v)) for v in values) / len(values)
    s = sum(math.sin(math.radians(v)) for v in values) / len(values)
    r = min(1.0, math.hypot(c, s))
    std = math.degrees(math.sqrt(-2.0 * math.log(r))) if r > 1e-12 else math.inf
    return {
        "mean_deg": math.degrees(math.atan2(s, c)) % 360.0,
        "std_deg": std,
        "min_deg": min(values),
        "max_deg": max(values),
        "resultant_length": r,
    }


@dataclass
class CaptureSummary:
    """What ``guidance compass`` prints for one recorded capture."""

    file: str
    lines: int
    headings: int
    rejected: int
    rejected_by_reason: dict[str, int]
    comments: int
    true_headings: int
    magnetic_headings: int
    resynced: int
    by_type: dict[str, int]
    stats: dict[str, float] | None = None

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


def parse_capture(
    path: Path | str, *, allow_missing_checksum: bool = False, chunk_bytes: int = 1 << 16
) -> CaptureSummary:
    """Run a recorded capture through the live framing and parser.

    Lines starting with '#' are comments (gpsd's test-log convention) and are counted apart.
    """
    path = Path(path)
    parser = NmeaCompassParser(allow_missing_checksum=allow_missing_checksum)
    assembler = LineAssembler(on_too_long=lambda: parser.reject("too_long"))
    values: list[float] = []
    comments = 0

    def take(lines: list[bytes]) -> None:
        nonlocal comments
        for line in lines:
            if line.lstrip().startswith(b"#"):
                comments += 1
                continue
            out = parser.feed_line(line, t_s=0.0)
            if out is not None:
                values.append(out.heading_deg)

    try:
        with files.opened(path, "nmea_log") as f:
            while chunk := f.read(chunk_bytes):
                take(assembler.feed(chunk))
    except OSError as exc:
        raise UserError(f"{path}: {exc.strerror or exc}") from exc
    take(assembler.flush())
    return CaptureSummary(
        file=str(path),
        lines=parser.lines,
        headings=parser.headings,
        rejected=parser.rejected,
        rejected_by_reason={r: parser.rejected_by_reason[r] for r in REJECT_REASONS},
        comments=comments,
        true_headings=parser.true_headings,
        magnetic_headings=parser.headings - parser.true_headings,
        resynced=parser.resynced,
        by_type=dict(parser.by_type),
        stats=heading_stats(values),
    )


# -- the live source ---------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class SerialCompassConfig:
    """Where the compass is and how it talks. NMEA 0183 default: 4800 baud, 8N1."""

    port: str = "/dev/ttyUSB0"
    baudrate: int = 4800
    allow_missing_checksum: bool = False
    apply_hdg_deviation: bool = True
    read_timeout_s: float = 0.1
    reconnect_initial_s: float = 0.2
    reconnect_max_s: float = 5.0
    max_line_bytes: int = MAX_LINE_BYTES
    serial_options: dict[str, Any] = field(default_factory=dict)
    """Extra keyword arguments for ``serial.Serial`` (parity, rtscts...)."""
    stale_after_s: float = 3.0
    """No line for this long: ``health()`` says 'silent'. Compasses send at 1-20 Hz."""
    stall_flush_s: float = 1.0
    """The reader did not run for this long (the process was stopped, starved or suspended):
    what waits in the serial buffer is old, so it is discarded (counted ``stale_bytes``) rather
    than stamped "now" and fused as the current heading."""

    def __post_init__(self) -> None:
        if not isinstance(self.port, str) or not self.port:
            raise UserError(f"port must be a device path such as /dev/ttyUSB0, not {self.port!r}")
        if not (isinstance(self.baudrate, int) and self.baudrate > 0):
            raise UserError(f"baudrate must be a positive integer, not {self.baudrate!r}")
        for name in (
            "read_timeout_s",
            "reconnect_initial_s",
            "reconnect_max_s",
            "stale_after_s",
            "stall_flush_s",
        ):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and value > 0):
                raise UserError(f"{name} must be a positive number of seconds, not {value!r}")
        if not (isinstance(self.max_line_bytes, int) and self.max_line_bytes >= 82):
            raise UserError(f"max_line_bytes must be an integer >= 82, not {self.max_line_bytes!r}")


NEUTRAL_REASONS = frozenset({"unknown_type"})
"""Rejections that say nothing about the compass: other sentences of a multi-sentence device."""


class SerialCompass(ThreadedSource[CompassHeading]):
    """``CompassSource`` on a serial port (USB adapter, pty in simulation).

    Only lines that parse to a heading reach the sink; garbage, broken checksums and
    out-of-range values are counted by reason. ``health()`` reports the device lost, silent or
    sending mostly bad lines (alive: lines arriving; valid: most recent lines were good headings).
    """

    sink_kind = "compass"
    unit = "lines"
    announce_first_connect = True

    def __init__(
        self,
        config: SerialCompassConfig | None = None,
        name: str = "serial_compass",
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        """``clock`` stamps line arrival: ``time.monotonic`` live, the world's clock in an
        accelerated simulation (so compass and CAN frame times share one time base)."""
        self.config = config or SerialCompassConfig()
        super().__init__(name, self.config, clock=clock)
        self._device = self.config.port
        self._clock = clock
        self.parser = NmeaCompassParser(
            allow_missing_checksum=self.config.allow_missing_checksum,
            apply_hdg_deviation=self.config.apply_hdg_deviation,
            max_line_bytes=self.config.max_line_bytes,
        )
        self._got_data = False

    # CompassSource -----------------------------------------------------------------------------

    @property
    def connected(self) -> bool:
        return bool(self._connected)

    # internals ---------------------------------------------------------------------------------

    def _source_stats(self) -> dict[str, int]:
        return self.parser.stats()

    def _open(self) -> serial.Serial:
        cfg = self.config
        return serial.Serial(
            port=cfg.port, baudrate=cfg.baudrate, timeout=cfg.read_timeout_s, **cfg.serial_options
        )

    def _run(self, sink: Callable[[CompassHeading], None]) -> None:
        delay = self.config.reconnect_initial_s
        first = True
        while not self._stop.is_set():
            if not first and self._stop.wait(delay):
                break
            first = False
            try:
                port = self._open()
            except (serial.SerialException, OSError, ValueError) as exc:
                self._set_connected(False, exc)
                delay = self._backoff(delay)
                continue
            if self._connected is False:
                self._count("reconnects")
            self._set_connected(True)
            self._got_data = False
            try:
                self._read(port, sink)
            except (serial.SerialException, OSError) as exc:
                self._set_connected(False, exc)
            finally:
                port.close()
            # A device that delivered is retried quickly; one that fails at once backs off.
            delay = self.config.reconnect_initial_s if self._got_data else self._backoff(delay)

    def _discard_stale(self, port: serial.Serial, n_read: int, gap_s: float) -> None:
        """Drop what the port buffered while the reader was not running (and the bytes just
        read from it); counted in ``stale_bytes`` and ``stale_flushes``, logged."""
        try:
            waiting = int(port.in_waiting)
            port.reset_input_buffer()
        except (serial.SerialException, OSError, ValueError):
            waiting = 0
        self._count("stale_flushes")
        self._count("stale_bytes", n_read + waiting)
        self._log.warning(
            "%s: the reader did not run for %.1f s: %d buffered bytes discarded as stale",
            self.name,
            gap_s,
            n_read + waiting,
        )

    def _read(self, port: serial.Serial, sink: Callable[[CompassHeading], None]) -> None:
        def too_long() -> None:
            with self._lock:
                self.parser.reject("too_long")
            self._health.data(False)
            self._health.error("line longer than max_line_bytes")

        assembler = LineAssembler(self.config.max_line_bytes, too_long)
        last_read = time.monotonic()
        while not self._stop.is_set():
            chunk = port.read(max(1, min(port.in_waiting, 4096)))
            now = time.monotonic()
            gap_s, last_read = now - last_read, now
            if chunk and gap_s > self.config.stall_flush_s:  # buffered while nobody read: old
                self._discard_stale(port, len(chunk), gap_s)
                assembler = LineAssembler(self.config.max_line_bytes, too_long)
                continue
            if not chunk:
                self._health.evaluate()  # notices (and logs) a silence
                continue
            t_s = self._clock()
            self._got_data = True
            self._count("bytes", len(chunk))
            for line in assembler.feed(chunk):
                with self._in_order():  # recorded in the order the consumer gets it
                    if self._raw_sink is not None:  # recording raw lines
                        self._offer_raw(RawNmeaLine(t_s, line, str(self.config.port)))
                    with self._lock:
                        out = self.parser.feed_line(line, t_s)
                        outcome = self.parser.last_outcome
                    if outcome != "ok":
                        self._health.error(f"rejected line ({outcome}): {line[:40]!r}")
                    self._health.data(None if outcome in NEUTRAL_REASONS else outcome == "ok", t_s)
                    if out is not None:
                        self._deliver(sink, out)
