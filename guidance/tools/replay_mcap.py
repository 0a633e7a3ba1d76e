"""The MCAP side of ``guidance replay``: a recording's inputs back as pipeline messages, and the
outputs it recorded, every record checked at the boundary (``guidance.core.codec`` for the
inputs, ``replay_session`` for the session and the outputs); damaged records are described and
left out, damaged chunks counted (``guidance.recording.scan``), never a crash.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from guidance.core.codec import TOPICS
from guidance.core.messages import TurnCompleted
from guidance.errors import UserError
from guidance.tools.replay_session import well_formed_output

if TYPE_CHECKING:
    from guidance.core.pipeline import Input
    from guidance.recording.reader import Reader
    from guidance.recording.scan import Damage
    from guidance.tools.replay_can import CarCanDecoders

PROCESSED_TOPICS = tuple(dict.fromkeys(TOPICS.values()))
"""Every processed-input topic, from the codec's one table: a new input type is replayed."""


# ----------------------------------------------------------------------------- MCAP


def message_from_record(topic: str, data: Mapping[str, Any]) -> Input | None:
    """One recorded input back as the message the pipeline took (``guidance.core.codec``).

    Turns the pipeline's own detector reported are left out: replay re-derives them."""
    from guidance.core.codec import from_record

    msg = from_record(topic, data)
    if isinstance(msg, TurnCompleted) and msg.source == "detected":
        return None
    return msg


def _decoded(topic: str, data: Mapping[str, Any], skipped: list[str]) -> Input | None:
    """``message_from_record``, counting a damaged record instead of failing the replay."""
    from guidance.core.codec import CodecError

    try:
        return message_from_record(topic, data)
    except CodecError as exc:
        skipped.append(str(exc))
        return None


def skipped_messages(reader: Reader, bad: list[str]) -> None:
    """Add the messages ``reader`` skipped (no JSON object, nested too deep, a time of 10^400)
    to ``bad``, one entry each, so a replay counts and names them as damaged records."""
    bad.extend(reader.skipped_why)
    bad.extend(["a message that is no usable JSON"] * (reader.skipped - len(reader.skipped_why)))


RAW_TOPICS = (
    "/can",
    "/nmea",
    *(t for t in PROCESSED_TOPICS if t not in ("/odometry", "/compass", "/yaw_rate")),
)
"""With ``raw``: the CAN frames and NMEA lines instead of the odometry, yaw rates and compass
readings they gave."""


def mcap_inputs(
    path: str | Path | list[Path],
    *,
    raw: bool = False,
    profile: str | None = None,
    skipped: list[str] | None = None,
    damage: Damage | None = None,
) -> tuple[dict[str, Any], Iterator[Input]]:
    """The session record and the recorded inputs (in processing order) of a recording.

    ``raw=True`` decodes the raw ``/can`` frames and ``/nmea`` lines again with the car's
    decoders (``profile``, else the one the session was recorded with, ``can_profile``, else
    ``gm_global_a``; ``replay_can.CarCanDecoders``: the yaw rate too when the session's
    car turns by its gyro, ``[vehicle] yaw_source`` "gyro" or "both") and compass parser
    instead of taking the decoded ``/odometry``, ``/yaw_rate`` and ``/compass`` the app
    recorded: the drivers' decoding is then part of what is replayed.
    Records that do not decode are left out and described in ``skipped``; chunks and records
    the file's damage made unreadable are counted in ``damage`` once the inputs are read.
    """
    bad: list[str] = skipped if skipped is not None else []
    from guidance.recording.reader import Reader

    session_reader = Reader(path, topics=["/session"], log_time_order=False)
    sessions = list(session_reader)
    if not sessions:
        where = path if isinstance(path, str | Path) else ", ".join(Path(p).name for p in path)
        why = f": {session_reader.skipped_why[0]}" if session_reader.skipped_why else ""
        raise UserError(
            f"{where}: no readable /session record (damaged, or not recorded by guidance run/sim)"
            f"{why}"
        )
    session = sessions[0].data

    def read(topics: tuple[str, ...]) -> Iterator[Any]:
        reader = Reader(path, topics=topics, log_time_order=False)
        yield from reader
        skipped_messages(reader, bad)
        if damage is not None:
            for key in ("bad_chunks", "bad_records", "skipped_bytes", "truncated_files"):
                setattr(damage, key, getattr(damage, key) + getattr(reader.damage, key))
            for note in reader.damage.notes:
                damage.note(note)

    def inputs() -> Iterator[Input]:
        for rec in read(PROCESSED_TOPICS):
            msg = _decoded(rec.topic, rec.data, bad)
            if msg is not None:
                yield msg

    def raw_inputs(decoder: CarCanDecoders) -> Iterator[Input]:
        from drivers.compass import NmeaCompassParser

        parser = NmeaCompassParser()
        for rec in read(RAW_TOPICS):
            d = rec.data
            if rec.topic in ("/can", "/nmea"):
                out = _raw_input(rec.topic, d, decoder, parser, bad)
                if out is not None:
                    yield out
            else:
                msg = _decoded(rec.topic, d, bad)
                if msg is not None:
                    yield msg

    if not raw:
        return session, inputs()
    from guidance.tools.replay_can import CarCanDecoders
    from guidance.tools.replay_session import pipeline_config_from_session

    gyro = pipeline_config_from_session(session).estimator.gyro is not None
    return session, raw_inputs(CarCanDecoders(profile or session_profile(session), yaw_rate=gyro))


def session_profile(session: Mapping[str, Any]) -> str:
    """The CAN profile a ``/session`` record says the car decoded with (a known profile's
    name, else a ``UserError``), ``gm_global_a`` for a record without one (recorded before
    it was kept)."""
    from drivers.profiles import get_profile

    name = session.get("can_profile")
    if name is None:
        return "gm_global_a"
    if not isinstance(name, str) or len(name) > 100:
        raise UserError("the recording's /session record: can_profile is not a profile name")
    return get_profile(name).name


def _raw_input(
    topic: str, d: Mapping[str, Any], decoder: CarCanDecoders, parser: Any, bad: list[str]
) -> Input | None:
    """A recorded ``/can`` frame or ``/nmea`` line through the car's decoders; a malformed
    record is described in ``bad`` and left out."""
    import can

    t = d.get("t_s")
    if isinstance(t, bool) or not isinstance(t, int | float) or not math.isfinite(t):
        bad.append(f"{topic}: t_s is not a finite number")
        return None
    try:
        if topic == "/can":
            ident, hex_text = d.get("id"), d.get("data_hex")
            if isinstance(ident, bool) or not isinstance(ident, int) or not 0 <= ident < 2**29:
                raise ValueError("id is not a CAN identifier")
            if not isinstance(hex_text, str) or len(hex_text) > 128:
                raise ValueError("data_hex is not hex text")
            frame = can.Message(
                timestamp=float(t),
                arbitration_id=ident,
                data=bytes.fromhex(hex_text),
                is_extended_id=d.get("is_extended_id") is True,
                is_error_frame=d.get("is_error_frame") is True,
            )
            return decoder.feed(frame)
        line = d.get("line")
        if not isinstance(line, str):
            raise ValueError("line is not text")
        return parser.feed_line(line.encode("ascii", "replace"), float(t))
    except (ValueError, TypeError) as exc:
        bad.append(f"{topic}: {exc}")
        return None


def recorded_outputs(
    path: str | Path | list[Path], bad: list[str] | None = None
) -> dict[str, list[dict[str, Any]]]:
    """The decisions and states the recording holds (what the live run computed); a record
    without the numbers the comparison reads is described in ``bad`` and left out."""
    from guidance.recording.reader import Reader

    out: dict[str, list[dict[str, Any]]] = {"/decision": [], "/state": []}
    reader = Reader(path, topics=list(out), log_time_order=False)
    for rec in reader:
        if well_formed_output(rec.topic, rec.data):
            out[rec.topic].append(rec.data)
        elif bad is not None:
            bad.append(f"{rec.topic}: a recorded output without finite numbers")
    if bad is not None:
        skipped_messages(reader, bad)
    return out
