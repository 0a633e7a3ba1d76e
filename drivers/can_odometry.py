"""CAN wheel odometry: wheel-speed frames -> rear-wheel distance increments (SPEC sections 2, 6).

The decoding (``WheelSpeedDecoder``, pure; the sanity limits) is in ``drivers.can_decode``.

``CanOdometry`` is the ``OdometrySource`` for the car: a python-can bus chosen by configuration
only (``socketcan`` in the car, ``virtual`` in CI), a reader thread, reconnect with backoff.

``replay_log`` runs a recorded log (candump, ASC, BLF... via python-can's readers) through the
same decoder; ``guidance odometry`` prints its summary.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import can

from drivers._reader import ThreadedSource
from drivers.can_decode import MAX_GAP_S, REJECT_REASONS, WheelSpeedDecoder
from drivers.can_yaw import YawRateDecoder
from drivers.candump import read_candump
from drivers.clock import ClockMapper
from drivers.profiles import VehicleProfile, get_profile
from guidance import files
from guidance.core.messages import RawCanFrame, WheelOdometry, YawRate
from guidance.errors import UserError

log = logging.getLogger(__name__)


# -- the live source ---------------------------------------------------------------------------


def can_hint(interface: str, channel: str, exc: BaseException) -> str:
    """The usual fix for a bus that does not open, or "" (errno 97: no SocketCAN in this kernel
    or container; 19 ENODEV: no such interface; 100 ENETDOWN: the interface is down)."""
    errno = getattr(exc, "errno", None)
    if interface != "socketcan":
        return ""
    up = f"sudo ip link set {channel} up type can bitrate 500000"
    if errno == 97:
        return ("this kernel or container has no SocketCAN: load it (sudo modprobe can can_raw) "
                "or run on the car's computer")  # fmt: skip
    if errno == 19:
        return f"no network interface {channel}: plug the CAN adapter in, then {up}"
    if errno == 100:
        return f"{channel} is down: {up}"
    return ""


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
    yaw_rate: bool = False
    """Deliver the stability control's yaw rate too (``YawRate``, decoded by
    ``drivers.can_yaw`` from the signal the profile names): set by the app for a car whose
    ``[vehicle] yaw_source`` is "gyro" or "both"; a profile without the signal is refused."""

    def __post_init__(self) -> None:
        """Reject bad values at start, naming the field (the app prefixes its config section)."""
        if self.profile != AUTO:
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
        if self.yaw_rate and self.profile != AUTO and get_profile(self.profile).yaw_rate is None:
            raise UserError(f"vehicle profile {self.profile!r} names no yaw-rate signal: "
                            '[vehicle] yaw_source "gyro" or "both" needs one')  # fmt: skip


AUTO = "auto"
AUTO_LISTEN_S = 3.0
"""``profile = "auto"``: how long the bus is listened to before the rule is applied (every
message of a car's powertrain bus repeats within a second; the slowest, 1 Hz, three times)."""


def identify_on_bus(config: CanOdometryConfig, listen_s: float = AUTO_LISTEN_S) -> str:
    """The profile of the car on the bus (``drivers.can_identify``), from ``listen_s`` of its
    frames, said in one log line; an unknown or ambiguous car, or no bus, is a ``UserError``."""
    from drivers.can_identify import identify_or_refuse

    kwargs: dict[str, Any] = dict(config.bus_options)
    if config.bitrate is not None:
        kwargs.setdefault("bitrate", config.bitrate)
    try:
        bus = can.Bus(interface=config.interface, channel=config.channel, **kwargs)
    except (can.CanError, OSError, ValueError, ImportError) as exc:
        raise UserError(
            f"profile auto: the bus {config.interface}/{config.channel} must be up at start "
            f"to recognise the car ({type(exc).__name__}: {exc}); or name the profile"
        ) from None
    frames: list[can.Message] = []
    try:
        deadline = time.monotonic() + listen_s
        while (rest := deadline - time.monotonic()) > 0:
            msg = bus.recv(timeout=min(rest, 0.1))
            if msg is not None:
                msg.channel = config.channel
                frames.append(msg)
    finally:
        bus.shutdown()
    found = identify_or_refuse(frames)
    log.warning("CAN profile auto: %s", found.reason)
    return str(found.profile)


class CanOdometry(ThreadedSource[WheelOdometry | YawRate]):
    """``OdometrySource`` on a python-can bus: reader thread, decoder, reconnect with backoff.
    With ``yaw_rate`` it delivers the stability control's ``YawRate`` readings too, from the
    same bus (``drivers.can_yaw``; counted apart: ``yaw_read``, ``yaw_rejected``).

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
        if self.config.profile == AUTO:  # the car from the ids on its bus (can_identify)
            self.config = replace(self.config, profile=identify_on_bus(self.config))
        super().__init__(name, self.config, clock=clock)
        self._clock_map = ClockMapper()
        self.decoder = WheelSpeedDecoder(self.config.profile, max_gap_s=self.config.max_gap_s)
        self.yaw: YawRateDecoder | None = None
        if self.config.yaw_rate:
            self.yaw = YawRateDecoder(self.config.profile)
        self._bus: can.BusABC | None = None
        self._device = f"CAN bus {self.config.interface}/{self.config.channel}"

    # OdometrySource ------------------------------------------------------------------------------

    # internals ---------------------------------------------------------------------------------

    def _source_stats(self) -> dict[str, int]:
        out = {**self.decoder.stats(), "gap_ms": round(self.decoder.gap_s * 1000.0)}
        if self.yaw is not None:  # the gyro's own counts: its health apart from the wheels'
            out["yaw_read"] = self.yaw.frames
            out["yaw_rejected"] = sum(self.yaw.rejected.values())
        return out

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
            self._bus_failed(exc)
        else:
            self._set_connected(True)

    def _on_stop(self) -> None:
        self._close_bus()

    def _open_bus(self) -> can.BusABC:
        cfg = self.config
        kwargs: dict[str, Any] = dict(cfg.bus_options)
        if cfg.bitrate is not None:
            kwargs.setdefault("bitrate", cfg.bitrate)
        if cfg.hardware_filters:
            ids = set(self.decoder.profile.frame_ids)
            if self.yaw is not None:
                ids.add(self.yaw.signal.frame_id)
            kwargs.setdefault(
                "can_filters",
                [{"can_id": fid, "can_mask": 0x7FF, "extended": False} for fid in sorted(ids)],
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
        self._clock_map = ClockMapper()

    def _bus_failed(self, exc: BaseException) -> None:
        """Every failure is counted (``bus_errors``); the loss is logged once, and the status
        flip handed to the status sink, by ``_set_connected`` (like the compass and camera)."""
        cfg = self.config
        self._count("bus_errors")
        hint = can_hint(cfg.interface, cfg.channel, exc)
        self._set_connected(
            False,
            f"{cfg.interface}/{cfg.channel}: {type(exc).__name__}: {exc}"
            + (f" ({hint})" if hint else ""),
        )

    def _merge(
        self, held: WheelOdometry | YawRate, new: WheelOdometry | YawRate
    ) -> WheelOdometry | YawRate | None:
        """Back-pressure: one increment for both (distances summed, the later time). Yaw
        readings are never held (``_deliver_yaw``), so both are increments."""
        if not (isinstance(held, WheelOdometry) and isinstance(new, WheelOdometry)):
            return None  # pragma: no cover - yaw readings are not held
        return WheelOdometry(new.t_s, held.d_left_m + new.d_left_m, held.d_right_m + new.d_right_m)

    def _deliver_yaw(
        self, sink: Callable[[WheelOdometry | YawRate], None], msg: can.Message
    ) -> None:
        """A yaw-rate frame, decoded (``drivers.can_yaw``; refused frames counted there). While
        the consumer is behind, or an increment is held, the reading is dropped (counted,
        ``yaw_dropped_behind``): a reading is a rate, not an amount, and the estimator turns
        a step whose readings stopped by the wheels (``gyro.max_hold_s``), so losing one costs
        a little noise where holding it would reorder it against the distances."""
        assert self.yaw is not None
        with self._lock:
            reading = self.yaw.feed(msg)
        if reading is None:
            return
        if self._held is not None or self._behind():
            self._count("yaw_dropped_behind")
            return
        self._deliver(sink, reading)

    def _run(self, sink: Callable[[WheelOdometry | YawRate], None]) -> None:
        delay = self.config.reconnect_initial_s
        while not self._stop.is_set():
            if self._bus is None:
                if self._stop.wait(delay):
                    break
                delay = self._backoff(delay)
                try:
                    self._bus = self._open_bus()
                except (can.CanError, OSError, ValueError) as exc:
                    self._bus_failed(exc)
                    continue
                self._count("reconnects")
                # open, but not yet proof the bus works (a socketcan interface that is down
                # opens, then fails to read): health stops saying "disconnected", while the
                # driver says the bus is back only at its first frame, so a bus that fails
                # again at once is not logged lost and back on every retry
                self._health.connected(True)
            try:
                msg = self._bus.recv(timeout=self.config.receive_timeout_s)
            except (can.CanError, OSError) as exc:
                self._bus_failed(exc)
                self._close_bus()
                continue
            if msg is None:
                self._health.evaluate()  # notices (and logs) a silence while nothing arrives
                self._deliver_bounded(sink, None)  # what was held while the consumer was behind
                continue
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
            with self._in_order():  # recorded in the order the consumer gets it
                if self._raw_sink is not None:  # recording raw frames: built only then
                    self._offer_raw(
                        RawCanFrame(
                            float(msg.timestamp),
                            msg.arbitration_id,
                            bytes(msg.data),
                            bool(msg.is_extended_id),
                            bool(msg.is_error_frame),
                            str(self.config.channel),
                        )
                    )
                if self.yaw is not None and msg.arbitration_id == self.yaw.signal.frame_id:
                    self._deliver_yaw(sink, msg)
                    continue
                with self._lock:
                    out = self.decoder.feed(msg)
                    outcome = self.decoder.last_outcome
                if outcome != "ignored":
                    self._health.data(outcome in ("ok", "gap"))
                if self._connected is False:  # the first frame since the loss: the bus is back
                    self._set_connected(True)
                    delay = self.config.reconnect_initial_s
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
    files.check(path, "can_log")  # a regular file of a bounded size, or FileRefused
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
    profile_reason: str = ""
    """With ``--profile auto``: which profile the rule chose and why (``can_identify``)."""

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


def replay_log(
    path: Path | str, profile: VehicleProfile | str, *, max_gap_s: float = MAX_GAP_S
) -> ReplaySummary:
    """Run a recorded CAN log through ``WheelSpeedDecoder``; not a CAN log -> ``UserError``."""
    path = Path(path)
    prof = get_profile(profile) if isinstance(profile, str) and profile != "auto" else profile
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
    reason = ""
    if prof == "auto":  # the car from the ids it sent (drivers.can_identify), then replay
        from drivers.can_identify import identify_or_refuse

        try:
            found = identify_or_refuse(read_can_log(path, LogReadResult()))
        except OSError as exc:
            raise UserError(f"{path}: {exc.strerror or exc}") from exc
        prof, reason = get_profile(str(found.profile)), found.reason
    assert isinstance(prof, VehicleProfile)
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
        profile_reason=reason,
    )
