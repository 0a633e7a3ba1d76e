"""CAN wheel odometry: wheel-speed frames -> rear-wheel distance increments (SPEC sections 2, 6).

``WheelSpeedDecoder`` is pure: it takes python-can ``Message`` objects (live, simulated or read
from a log) and returns ``WheelOdometry`` increments, integrating the wheel speeds over the time
between frames (trapezoid rule). Bad frames are counted by reason and never raise. cantools is
used here and nowhere else (HOUSE_STYLE: wrap a library at one place).

``CanOdometry`` is the ``OdometrySource`` for the car: a python-can bus chosen by configuration
only (``socketcan`` in the car, ``virtual`` in CI), a reader thread, reconnect with backoff.

``replay_log`` runs a recorded log (candump, ASC, BLF... via python-can's readers) through the
same decoder; ``guidance odometry`` prints its summary.
"""

from __future__ import annotations

import logging
import math
import time
from collections import Counter
from collections.abc import Callable, Iterator, Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import can

from drivers._reader import ThreadedSource, rejection_counters
from drivers.candump import read_candump
from drivers.clock import ClockMapper
from drivers.profiles import CHECKSUMS, VehicleProfile, WheelSignals, get_profile, load_dbc
from guidance.core.messages import Health, WheelOdometry
from guidance.errors import UserError

log = logging.getLogger(__name__)

# Sanity limits, unit-named (openpilot locationd style).
MAX_SPEED_MPS = 90.0
"""Above this (324 km/h) a wheel speed is garbage, e.g. GM's 0xFFFF 'invalid' = 2038 km/h."""
MAX_ACCEL_MPS2 = 20.0
"""About 2 g: a wheel speed changing faster than this between frames is a spike."""
SPIKE_MARGIN_MPS = 3.0
"""Allowed step on top of MAX_ACCEL_MPS2 * dt: ABS modules report 0 below a few km/h and then
jump (the Civic 8th-generation log goes from 0 to 7.2 km/h in one 20 ms frame)."""
MAX_CONSECUTIVE_SPIKES = 3
"""After this many spikes in a row the new level is believed (re-anchored, not integrated)."""
MAX_GAP_S = 1.0
"""No integration across a silence longer than this: the speed in between is unknown.

Shorter gaps are bridged with the trapezoid rule (exact at constant acceleration); lossy
loggers drop 0.5-0.7 s at a time (RAV4 log), which must not lose the distance driven."""
FALLBACK_MIN_MPS = 0.5
"""Front wheels are used only when they move at least this fast while both rears read 0."""

REJECT_REASONS = (
    "dlc",
    "checksum",
    "decode",
    "fault",
    "implausible",
    "non_monotonic",
    "gap",
    "spike",
)


@dataclass(frozen=True, slots=True)
class _Axle:
    """Speeds of one axle (m/s, signed) and the frame time they came with."""

    left: float = 0.0
    right: float = 0.0
    t: float | None = None


class WheelSpeedDecoder:
    """Decode wheel-speed frames of one vehicle profile and integrate them into distances.

    ``feed`` returns a ``WheelOdometry`` for every rear wheel-speed frame that closes a valid
    interval; ``None`` for anything else (other ids, the first frame, rejected frames). The
    output time is the frame timestamp plus ``clock_offset_s`` (the live driver moves wall-clock
    frame times onto the monotonic clock with it).
    """

    def __init__(
        self,
        profile: VehicleProfile | str,
        *,
        max_gap_s: float = MAX_GAP_S,
        max_speed_mps: float = MAX_SPEED_MPS,
        max_accel_mps2: float = MAX_ACCEL_MPS2,
        clock_offset_s: float = 0.0,
    ) -> None:
        self.profile = get_profile(profile) if isinstance(profile, str) else profile
        self.max_gap_s = max_gap_s
        self.max_speed_mps = max_speed_mps
        self.max_accel_mps2 = max_accel_mps2
        self.clock_offset_s = clock_offset_s
        db = load_dbc(self.profile.dbc_file)
        p = self.profile
        self._rear_msg = db.get_message_by_frame_id(p.rear.frame_id)
        self._front_msg = db.get_message_by_frame_id(p.front.frame_id)
        self._shared = p.rear.frame_id == p.front.frame_id
        self._checksum = CHECKSUMS[p.checksum] if p.checksum else None
        self._scale = p.unit_to_mps * p.speed_scale
        self._prev_t: float | None = None
        self._prev_used: tuple[float, float] = (0.0, 0.0)
        self._front_latest = _Axle()
        self._spikes_in_row = 0

        self.frames = 0
        self.ignored = 0
        self.decoded = 0
        self.emitted = 0
        self.front_fallback = 0
        self.fallback_active = False
        self.rejected_by_reason: Counter[str] = Counter()
        self.left_m = 0.0
        self.right_m = 0.0
        self.distance_m = 0.0
        """Path length: sum of |mean of the two wheels| over the increments."""
        self.integrated_s = 0.0
        self.gap_s = 0.0
        self.max_speed_seen_mps = 0.0
        self.t_first: float | None = None
        self.t_last: float | None = None
        self.last_outcome = "none"
        """What the last ``feed`` did: "ignored" (not a wheel-speed frame), "ok" (decoded and
        usable: integrated or an anchor), or the reason it was rejected."""

    # -- counters ------------------------------------------------------------------------------

    @property
    def rejected(self) -> int:
        return sum(self.rejected_by_reason.values())

    @property
    def duration_s(self) -> float:
        if self.t_first is None or self.t_last is None:
            return 0.0
        return self.t_last - self.t_first

    def stats(self) -> dict[str, int]:
        out = {
            "frames": self.frames,
            "ignored": self.ignored,
            "decoded": self.decoded,
            "emitted": self.emitted,
            "rejected": self.rejected,
            "front_fallback": self.front_fallback,
        }
        out.update(rejection_counters(self.rejected_by_reason, REJECT_REASONS))
        return out

    def _reject(self, reason: str) -> None:
        self.rejected_by_reason[reason] += 1
        self.last_outcome = reason

    # -- decoding ------------------------------------------------------------------------------

    def feed(self, msg: can.Message) -> WheelOdometry | None:
        """Take one frame; return a distance increment when it closes a valid interval."""
        self.frames += 1
        self.last_outcome = "ok"
        t = float(msg.timestamp)
        if math.isfinite(t):
            self.t_first = t if self.t_first is None else min(self.t_first, t)
            self.t_last = t if self.t_last is None else max(self.t_last, t)
        fid = msg.arbitration_id
        p = self.profile
        if (
            msg.is_error_frame
            or msg.is_remote_frame
            or msg.is_extended_id
            or (fid != p.rear.frame_id and fid != p.front.frame_id)
        ):
            self.ignored += 1
            self.last_outcome = "ignored"
            return None
        is_rear = fid == p.rear.frame_id
        spec = self._rear_msg if is_rear else self._front_msg
        data = bytes(msg.data)
        if len(data) != spec.length:
            self._reject("dlc")
            return None
        if self._checksum is not None and not self._checksum(fid, data):
            self._reject("checksum")
            return None
        try:
            values = spec.decode(data, decode_choices=False)
        except Exception:  # cantools raises several types on odd payloads; all mean "bad frame"
            self._reject("decode")
            return None
        self.decoded += 1
        if not math.isfinite(t):
            self._reject("non_monotonic")
            return None

        if not is_rear:  # a separate front message (GM): remember it for the fallback
            front = self._wheel_pair(values, p.front)
            if front is not None:
                self._front_latest = _Axle(front[0], front[1], t)
            return None

        rear = self._wheel_pair(values, p.rear)
        if rear is None:
            return None
        if self._shared:
            front = self._wheel_pair(values, p.front, count=False)
        else:
            latest = self._front_latest
            fresh = latest.t is not None and abs(t - latest.t) <= self.max_gap_s
            front = (latest.left, latest.right) if fresh else None
        return self._integrate(t, rear, front)

    def _wheel_pair(
        self, values: Mapping[str, Any], sig: WheelSignals, count: bool = True
    ) -> tuple[float, float] | None:
        """Signed speeds (m/s) of one axle, or None (counted) when faulted or implausible."""
        try:
            left = float(values[sig.left]) * self._scale
            right = float(values[sig.right]) * self._scale
            faulted = any(
                name is not None and int(values[name]) != 0
                for name in (sig.left_fault, sig.right_fault)
            )
            for name, side in ((sig.left_direction, 0), (sig.right_direction, 1)):
                if name is None:
                    continue
                direction = int(values[name])
                faulted = faulted or direction in self.profile.fault_direction_values
                if direction in self.profile.reverse_values:
                    if side == 0:
                        left = -abs(left)
                    else:
                        right = -abs(right)
        except (KeyError, TypeError, ValueError):
            if count:
                self._reject("decode")
            return None
        if faulted:
            if count:
                self._reject("fault")
            return None
        if not (
            math.isfinite(left)
            and math.isfinite(right)
            and abs(left) <= self.max_speed_mps
            and abs(right) <= self.max_speed_mps
        ):
            if count:
                self._reject("implausible")
            return None
        return left, right

    def _integrate(
        self, t: float, rear: tuple[float, float], front: tuple[float, float] | None
    ) -> WheelOdometry | None:
        """Close the interval since the last accepted rear frame (trapezoid rule).

        The interval starts from the speeds used last time (rear or front), so switching to or
        from the front-wheel fallback keeps the car's speed continuous.
        """
        use_front = (
            front is not None
            and self.profile.allow_front_fallback
            and rear[0] == 0.0
            and rear[1] == 0.0
            and 0.5 * (abs(front[0]) + abs(front[1])) >= FALLBACK_MIN_MPS
        )
        now = front if use_front and front is not None else rear
        prev_t = self._prev_t
        if prev_t is None:  # first frame: an anchor, nothing to integrate yet
            self._anchor(t, now)
            return None
        dt = t - prev_t
        if dt <= 0.0:
            self._reject("non_monotonic")
            if -dt > self.max_gap_s:  # the clock stepped back: start again from here
                self._anchor(t, now)
            return None
        if dt > self.max_gap_s:
            self._reject("gap")
            self.gap_s += dt
            self._anchor(t, now)
            return None
        prev = self._prev_used
        allowed = self.max_accel_mps2 * dt + SPIKE_MARGIN_MPS
        if abs(now[0] - prev[0]) > allowed or abs(now[1] - prev[1]) > allowed:
            self._reject("spike")
            self._spikes_in_row += 1
            if self._spikes_in_row > MAX_CONSECUTIVE_SPIKES:
                self._anchor(t, now)  # a real change after all: believe it from now on
            return None

        d_left = 0.5 * (prev[0] + now[0]) * dt
        d_right = 0.5 * (prev[1] + now[1]) * dt
        self._set_fallback(use_front, t)
        self._anchor(t, now)
        self.emitted += 1
        self.left_m += d_left
        self.right_m += d_right
        self.distance_m += abs(0.5 * (d_left + d_right))
        self.integrated_s += dt
        self.max_speed_seen_mps = max(self.max_speed_seen_mps, abs(0.5 * (now[0] + now[1])))
        return WheelOdometry(t_s=t + self.clock_offset_s, d_left_m=d_left, d_right_m=d_right)

    def _anchor(self, t: float, used: tuple[float, float]) -> None:
        self._spikes_in_row = 0
        self._prev_t = t
        self._prev_used = used

    def _set_fallback(self, active: bool, t: float) -> None:
        if active:
            self.front_fallback += 1
        if active != self.fallback_active:
            self.fallback_active = active
            if active:
                log.warning(
                    "rear wheel speeds read 0 while the fronts move (t=%.3f): using the front "
                    "wheels for odometry",
                    t,
                )
            else:
                log.warning("front-wheel fallback ended (t=%.3f): using the rear wheels", t)


# -- the live source ---------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class CanOdometryConfig:
    """How to reach the car's bus. The python-can interface is chosen here and only here."""

    interface: str = "socketcan"
    channel: str = "can0"
    bitrate: int | None = 500_000
    """GM high-speed GMLAN runs at 500 kbit/s; socketcan takes it from ``ip link`` instead."""
    profile: str = "gm_global_a"
    clock: str = "wall"
    """'wall': frame timestamps are Unix time (socketcan, virtual) and are moved onto
    ``time.monotonic()``; 'frame': timestamps are used as they are (simulated clock, replay)."""
    max_gap_s: float = MAX_GAP_S
    receive_timeout_s: float = 0.1
    reconnect_initial_s: float = 0.2
    reconnect_max_s: float = 5.0
    hardware_filters: bool = True
    """Ask the bus (the kernel, for socketcan) for the wheel-speed ids only."""
    bus_options: Mapping[str, Any] = field(default_factory=dict)
    """Extra keyword arguments for ``can.Bus`` (e.g. ``preserve_timestamps`` for virtual)."""
    stale_after_s: float = MAX_GAP_S
    """No wheel-speed frame for this long: ``health()`` says 'silent' (not alive)."""

    def __post_init__(self) -> None:
        """Reject bad values at start, naming the field (the app prefixes its config section)."""
        get_profile(self.profile)
        if self.interface not in can.VALID_INTERFACES:  # at --check, not an ExceptionGroup later
            raise UserError(
                f"interface {self.interface!r} is not a python-can interface; known: "
                f"{', '.join(sorted(can.VALID_INTERFACES))}"
            )
        if self.clock not in ("wall", "frame"):
            raise UserError(f"clock must be 'wall' or 'frame', not {self.clock!r}")
        for name in (
            "max_gap_s",
            "receive_timeout_s",
            "reconnect_initial_s",
            "reconnect_max_s",
            "stale_after_s",
        ):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and value > 0):
                raise UserError(f"{name} must be a positive number of seconds, not {value!r}")
        if self.bitrate is not None and not (isinstance(self.bitrate, int) and self.bitrate > 0):
            raise UserError(f"bitrate must be a positive integer (bit/s), not {self.bitrate!r}")


WARNINGS = {
    "silent": "Wheel speed signal lost. Position is getting less certain.",
    "invalid": "Wheel speed data is unreliable. Position is getting less certain.",
    "disconnected": "Wheel speed bus disconnected. Position is getting less certain.",
}
"""Spoken when ``health()`` turns bad (docs/reliability.md)."""


class CanOdometry(ThreadedSource[WheelOdometry]):
    """``OdometrySource`` on a python-can bus: reader thread, decoder, reconnect with backoff.

    Bad frames (wrong length, checksum, fault bits, implausible speeds, spikes, time going
    backwards) are counted and never reach the sink; a silence longer than ``max_gap_s`` is not
    integrated (``health()`` counts it in ``gap_s``). ``clock`` times arrivals for ``health()``:
    ``time.monotonic`` live, the simulation's clock with ``clock="frame"``.
    """

    sink_kind = "odometry"

    def __init__(
        self,
        config: CanOdometryConfig | None = None,
        name: str = "can_odometry",
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.config = config or CanOdometryConfig()
        super().__init__(name, self.config, clock=clock, warnings=WARNINGS)
        self._clock_map = ClockMapper()
        self.decoder = WheelSpeedDecoder(self.config.profile, max_gap_s=self.config.max_gap_s)
        self._bus: can.BusABC | None = None
        self._offline = False

    # OdometrySource ------------------------------------------------------------------------------

    def health(self) -> Health:
        """alive: wheel-speed frames arriving; valid: most of the recent ones usable."""
        counters = self.stats()
        with self._lock:
            counters["gap_ms"] = round(self.decoder.gap_s * 1000.0)
        return self._health.evaluate(counters)

    # internals ---------------------------------------------------------------------------------

    def _source_stats(self) -> dict[str, int]:
        return self.decoder.stats()

    def _on_start(self) -> None:
        """Open the bus; a bus that is down now is retried by the reader, not fatal."""
        self._resync_clock()
        try:
            self._bus = self._open_bus()
        except (can.CanInterfaceNotImplementedError, ImportError, TypeError, ValueError) as exc:
            raise UserError(
                f"CAN interface {self.config.interface!r} channel {self.config.channel!r}: {exc}"
            ) from exc
        except (can.CanError, OSError) as exc:
            self._went_offline(exc)

    def _on_stop(self) -> None:
        self._close_bus()

    def _open_bus(self) -> can.BusABC:
        cfg = self.config
        kwargs: dict[str, Any] = dict(cfg.bus_options)
        if cfg.bitrate is not None:
            kwargs.setdefault("bitrate", cfg.bitrate)
        if cfg.hardware_filters:
            kwargs.setdefault(
                "can_filters",
                [
                    {"can_id": fid, "can_mask": 0x7FF, "extended": False}
                    for fid in self.decoder.profile.frame_ids
                ],
            )
        return can.Bus(interface=cfg.interface, channel=cfg.channel, **kwargs)

    def _close_bus(self) -> None:
        bus, self._bus = self._bus, None
        if bus is not None:
            try:
                bus.shutdown()
            except (can.CanError, OSError) as exc:
                log.debug("%s: shutdown: %s", self.name, exc)

    def _resync_clock(self) -> None:
        """Wall-clock frame stamps are mapped onto the monotonic clock frame by frame
        (``drivers.clock.ClockMapper``: steps followed and reported, glitches ignored)."""
        self.decoder.clock_offset_s = 0.0
        self._clock_map = ClockMapper()

    def _went_offline(self, exc: BaseException) -> None:
        cfg = self.config
        self._health.connected(False, f"{cfg.interface}/{cfg.channel}: {type(exc).__name__}: {exc}")
        self._count("bus_errors")
        if not self._offline:
            self._offline = True
            log.warning(
                "%s: CAN bus %s/%s unavailable (%s); retrying with backoff",
                self.name,
                self.config.interface,
                self.config.channel,
                exc,
            )

    def _merge(self, held: WheelOdometry, new: WheelOdometry) -> WheelOdometry:
        """Back-pressure: one increment for both (distances summed, the later time)."""
        return WheelOdometry(new.t_s, held.d_left_m + new.d_left_m, held.d_right_m + new.d_right_m)

    def _run(self, sink: Callable[[WheelOdometry], None]) -> None:
        delay = self.config.reconnect_initial_s
        while not self._stop.is_set():
            if self._bus is None:
                if self._stop.wait(delay):
                    break
                delay = self._backoff(delay)
                try:
                    self._bus = self._open_bus()
                except (can.CanError, OSError, ValueError) as exc:
                    self._went_offline(exc)
                    continue
                self._count("reconnects")
                self._health.connected(True)
            try:
                msg = self._bus.recv(timeout=self.config.receive_timeout_s)
            except (can.CanError, OSError) as exc:
                self._went_offline(exc)
                self._close_bus()
                continue
            if msg is None:
                self._health.evaluate()  # notices (and logs) a silence while nothing arrives
                self._deliver_bounded(sink, None)  # what was held while the consumer was behind
                continue
            if self._offline:
                self._offline = False
                delay = self.config.reconnect_initial_s
                log.warning("%s: CAN bus %s is back", self.name, self.config.channel)
            if self.config.clock == "wall":  # wall-clock stamps onto the monotonic clock
                mapped, step = self._clock_map.map(time.monotonic(), float(msg.timestamp))
                msg.timestamp = mapped
                if step is not None:
                    self._count("clock_steps")
                    log.warning("%s: the wall clock stepped by %+.3f s; CAN times follow it",
                                self.name, step.step_s)  # fmt: skip
            if msg.is_error_frame:
                self._count("error_frames")
                self._health.error(f"CAN error frame (id 0x{msg.arbitration_id:X})")
            if self._raw_sink is not None:  # recording raw frames: built only then
                self._offer_raw(
                    "can",
                    float(msg.timestamp) + float(self.decoder.clock_offset_s),
                    {
                        "id": msg.arbitration_id,
                        "data": bytes(msg.data),
                        "is_extended_id": bool(msg.is_extended_id),
                        "is_error_frame": bool(msg.is_error_frame),
                        "channel": str(self.config.channel),
                    },
                )
            with self._lock:
                out = self.decoder.feed(msg)
                outcome = self.decoder.last_outcome
            if outcome != "ignored":
                self._health.data(outcome in ("ok", "gap"))
            if out is not None:
                self._deliver_bounded(sink, out)  # coalesced while the consumer is behind


# -- replaying logs ----------------------------------------------------------------------------

CANDUMP_SUFFIXES = (".log",)
OTHER_SUFFIXES = (".asc", ".blf", ".csv", ".db", ".mf4", ".trc")


@dataclass
class LogReadResult:
    """What reading a log file produced besides the frames."""

    unreadable: int = 0
    """Records (lines, for candump) that could not be parsed."""
    error: str | None = None
    """Why a binary or structured log stopped early, if it did."""


def _log_suffix(path: Path) -> tuple[str, bool]:
    suffixes = [s.lower() for s in path.suffixes]
    if suffixes and suffixes[-1] == ".gz":
        return (suffixes[-2] if len(suffixes) >= 2 else ""), True
    return (suffixes[-1] if suffixes else ""), False


def read_can_log(path: Path, result: LogReadResult) -> Iterator[can.Message]:
    """Frames of a recorded log, read by python-can; unreadable records are counted, not raised.

    candump files (``.log``, optionally ``.gz``) are checked and read line by line
    (``drivers.candump``): one damaged line costs one line, a damaged ``.gz`` keeps the frames
    before the damage; other formats are read with ``can.LogReader`` and stop at the first bad
    record (``result.error`` says where).
    """
    suffix, gz = _log_suffix(path)
    if suffix in CANDUMP_SUFFIXES:  # checked line by line, bounded (drivers/candump.py)
        yield from read_candump(path, gz, result)
        return
    count = 0
    try:
        reader = can.LogReader(str(path))
    except Exception as exc:  # a reader that cannot even start is a wrong file type
        raise UserError(f"{path}: cannot read as {suffix or 'a CAN log'}: {exc}") from exc
    try:
        for msg in reader:
            count += 1
            yield msg
    except Exception as exc:  # corrupt binary / structured log: stop and say where
        result.unreadable += 1
        result.error = f"stopped after {count} frames: {type(exc).__name__}: {exc}"
    finally:
        stop = getattr(reader, "stop", None)
        if callable(stop):
            stop()


@dataclass
class ReplaySummary:
    """The figures ``guidance odometry`` prints."""

    log: str
    profile: str
    frames: int
    decoded: int
    rejected: int
    rejected_by_reason: dict[str, int]
    ignored: int
    increments: int
    unreadable: int
    duration_s: float
    distance_m: float
    left_m: float
    right_m: float
    integrated_s: float
    gap_s: float
    max_speed_mps: float
    front_fallback: int
    read_error: str | None = None

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


def replay_log(
    path: Path | str, profile: VehicleProfile | str, *, max_gap_s: float = MAX_GAP_S
) -> ReplaySummary:
    """Run a recorded CAN log through ``WheelSpeedDecoder``; not a CAN log -> ``UserError``."""
    path = Path(path)
    prof = get_profile(profile) if isinstance(profile, str) else profile
    if not path.exists():
        raise UserError(f"{path}: no such file")
    if not path.is_file():
        raise UserError(f"{path}: not a file")
    suffix, _ = _log_suffix(path)
    if suffix not in CANDUMP_SUFFIXES + OTHER_SUFFIXES:
        raise UserError(
            f"{path}: unknown CAN log format {suffix or '(no suffix)'!r}; python-can reads "
            f"{', '.join(CANDUMP_SUFFIXES + OTHER_SUFFIXES)} (candump -L is .log), optionally .gz"
        )
    decoder = WheelSpeedDecoder(prof, max_gap_s=max_gap_s)
    result = LogReadResult()
    try:
        for msg in read_can_log(path, result):
            decoder.feed(msg)
    except OSError as exc:  # unreadable file, bad gzip stream
        raise UserError(f"{path}: {exc.strerror or exc}") from exc
    if decoder.frames == 0 and (result.unreadable or result.error):
        raise UserError(
            f"{path}: no CAN frames could be read ({result.unreadable} unreadable records"
            f"{'; ' + result.error if result.error else ''}); is it a {suffix} CAN log?"
        )
    reasons = {r: decoder.rejected_by_reason[r] for r in REJECT_REASONS}
    return ReplaySummary(
        log=str(path),
        profile=prof.name,
        frames=decoder.frames,
        decoded=decoder.decoded,
        rejected=decoder.rejected,
        rejected_by_reason=reasons,
        ignored=decoder.ignored,
        increments=decoder.emitted,
        unreadable=result.unreadable,
        duration_s=decoder.duration_s,
        distance_m=decoder.distance_m,
        left_m=decoder.left_m,
        right_m=decoder.right_m,
        integrated_s=decoder.integrated_s,
        gap_s=decoder.gap_s,
        max_speed_mps=decoder.max_speed_seen_mps,
        front_fallback=decoder.front_fallback,
        read_error=result.error,
    )
