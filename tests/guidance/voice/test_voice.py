"""Voice: prompt queue, speakers and their fallbacks, real espeak-ng audio, prompt timing."""

from __future__ import annotations

import io
import logging
import math
import shutil
import sys
import threading
import time
import wave
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from guidance.app.ports import Speaker
from guidance.core.messages import Priority
from guidance.core.plan.announce import (
    EARLY_TOO_CLOSE_M,
    announcement_distances_m,
    due_announcements,
)
from guidance.voice import make_speaker
from guidance.voice.queue import PromptQueue
from guidance.voice.speakers import (
    Pyttsx3Speaker,
    SpeechEngineError,
    TextSpeaker,
    check_audio_output,
)
from guidance.voice.wav import Renderer, WavSpeaker

G, INFO, S = Priority.GUIDANCE, Priority.INFO, Priority.SAFETY


class FakeClock:
    """The message clock, set by hand."""

    def __init__(self, now: float = 0.0) -> None:
        self.now = now

    def __call__(self) -> float:
        return self.now


def voice_threads() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name.startswith("voice-") and t.is_alive()]


@pytest.fixture(autouse=True)
def no_leaked_threads() -> Iterator[None]:
    """Every test must close its speakers: no speaking thread outlives it."""
    before = set(voice_threads())
    yield
    deadline = time.monotonic() + 2.0
    while set(voice_threads()) - before and time.monotonic() < deadline:
        time.sleep(0.01)
    leaked = set(voice_threads()) - before
    assert not leaked, f"leaked threads: {leaked}"


def warnings_from_voice(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [
        r.getMessage()
        for r in caplog.records
        if r.name.startswith("guidance.voice") and r.levelno == logging.WARNING
    ]


# ------------------------------------------------------------------------- queue


def test_queue_speaks_safety_first_then_guidance_then_info_fifo_within_a_tier() -> None:
    q = PromptQueue(clock=FakeClock())
    for text, prio in [("i1", INFO), ("g1", G), ("s1", S), ("g2", G), ("lost", Priority.LOST)]:
        assert q.put(text, prio)
    assert [q.pop().text for _ in range(5)] == ["s1", "lost", "g1", "g2", "i1"]  # type: ignore[union-attr]
    assert q.pop() is None


def test_priority_of_plain_ints_clamps_onto_tiers() -> None:
    assert Priority.LOST is Priority.SAFETY
    assert [Priority.of(p) for p in (-3, 0, 1, 2, 9)] == [INFO, INFO, G, S, S]


def test_identical_pending_text_is_merged_and_refreshed() -> None:
    clock = FakeClock()
    q = PromptQueue(clock=clock)
    assert q.put("Turn left", G, t_s=0.0, max_age_s=5.0)
    assert q.put("In 200 metres, turn right", G, t_s=0.0)
    clock.now = 4.0
    assert q.put("Turn  left", S, t_s=4.0, max_age_s=5.0)  # same text, whitespace aside
    assert len(q) == 2
    assert q.stats()["deduplicated"] == 1
    clock.now = 7.0  # past the first copy's deadline (5 s), within the refreshed one (9 s)
    first = q.pop()
    assert first is not None
    assert (first.text, first.priority, first.t_s) == ("Turn left", S, 4.0)
    assert q.pop() is None  # the other one went stale at t = 5 s
    assert q.stats()["dropped_stale"] == 1


def test_prompts_that_would_be_stale_when_spoken_are_dropped_and_counted() -> None:
    clock = FakeClock(100.0)
    q = PromptQueue(clock=clock, max_age_s={S: 15.0, G: 5.0, INFO: 10.0})
    assert not q.put("already old", G, t_s=90.0)  # 10 s old, limit 5 s
    assert q.put("turn", G, t_s=100.0)
    assert q.put("landmark", INFO, t_s=100.0)
    clock.now = 105.0  # exactly at the guidance deadline: still fresh
    assert q.pop(now_s=105.0).text == "turn"  # type: ignore[union-attr]
    assert q.put("turn again", G, t_s=105.0)
    clock.now = 110.5  # "turn again" is 5.5 s old; the landmark 10.5 s
    assert q.pop() is None
    assert q.stats()["dropped_stale"] == 3


def test_full_queue_drops_the_lowest_priority_oldest() -> None:
    q = PromptQueue(maxsize=3, clock=FakeClock())
    assert q.put("info old", INFO)
    assert q.put("guide", G)
    assert q.put("info new", INFO)
    assert q.put("warn", S)  # full: "info old" goes
    assert q.put("info newest", INFO)  # full: "info new" (older of the two infos) goes
    assert q.put("guide 2", G)  # full: "info newest" goes
    assert not q.put("info late", INFO)  # lowest of all: the new prompt itself is dropped
    assert [p.text for p in q.take_all()] == ["warn", "guide", "guide 2"]
    assert q.stats()["dropped_overflow"] == 4


def test_queue_rejects_bad_input() -> None:
    with pytest.raises(ValueError, match="maxsize"):
        PromptQueue(maxsize=0)
    q = PromptQueue(clock=FakeClock())
    with pytest.raises(ValueError, match="finite"):
        q.put("x", G, t_s=math.nan)
    assert not q.put("   ", G)


def test_queue_is_thread_safe_and_get_wakes_on_put_and_close() -> None:
    q = PromptQueue(maxsize=10_000, clock=FakeClock())
    got: list[str] = []

    def consume() -> None:
        while (p := q.get(timeout_s=5.0)) is not None:
            got.append(p.text)

    consumer = threading.Thread(target=consume, name="voice-test-consumer")
    consumer.start()
    producers = [
        threading.Thread(target=lambda k=k: [q.put(f"p{k}-{i}", G) for i in range(300)])
        for k in range(4)
    ]
    for t in producers:
        t.start()
    for t in producers:
        t.join()
    q.close()
    consumer.join(5.0)
    assert not consumer.is_alive()
    assert sorted(got) == sorted(f"p{k}-{i}" for k in range(4) for i in range(300))
    assert q.stats()["queued"] == q.stats()["popped"] == 1200
    assert not q.put("after close", G)


# ----------------------------------------------------------------------- timing


def test_announcement_distances_follow_organic_maps_and_scale_with_speed() -> None:
    stand = announcement_distances_m(0.0)
    assert (stand.early_m, stand.before_m) == (235.0, 35.0)  # 200 + 35, 35
    city = announcement_distances_m(50 / 3.6)  # 50 km/h
    assert city.before_m == pytest.approx(8 * 50 / 3.6)  # 111 m: 8 s ahead
    assert city.early_m == pytest.approx(30 * 50 / 3.6 + 8 * 50 / 3.6)  # 528 m
    fast = announcement_distances_m(100.0)
    assert (fast.early_m, fast.before_m) == (2150.0, 150.0)  # clamped
    assert announcement_distances_m(-3.0) == stand
    speeds = np.linspace(0, 60, 61)
    early = [announcement_distances_m(v).early_m for v in speeds]
    before = [announcement_distances_m(v).before_m for v in speeds]
    assert np.all(np.diff(early) >= 0) and np.all(np.diff(before) >= 0)


def drive_towards(start_m: float, speed_mps: float, step_m: float = 5.0) -> list[tuple[float, str]]:
    """Approach an intersection, announcing what is due; returns (distance, announcement)."""
    announced: set[str] = set()
    said: list[tuple[float, str]] = []
    d = start_m
    while d >= 0:
        for a in due_announcements(d, speed_mps, announced):
            announced.add(a)
            said.append((d, a))
        d -= step_m
    return said


def test_long_block_gets_an_early_and_a_just_before_announcement() -> None:
    v = 50 / 3.6
    said = drive_towards(900.0, v)
    assert [a for _, a in said] == ["early", "before"]
    assert said[0][0] == pytest.approx(525.0)  # first step inside 528 m
    assert said[1][0] == pytest.approx(110.0)  # first step inside 111 m


def test_short_block_gets_only_the_just_before_announcement() -> None:
    assert [a for _, a in drive_towards(EARLY_TOO_CLOSE_M, 50 / 3.6)] == ["before"]
    assert drive_towards(100.0, 50 / 3.6) == [(100.0, "before")]  # due at once


def test_due_announcements_edge_cases() -> None:
    assert due_announcements(300.0, 10.0, {"early"}) == ()
    assert due_announcements(10.0, 10.0, {"before"}) == ()
    assert due_announcements(-2.0, 10.0, set()) == ("before",)  # rounding past the node
    with pytest.raises(ValueError, match="finite"):
        due_announcements(math.inf, 10.0, set())
    with pytest.raises(ValueError, match="finite"):
        due_announcements(100.0, math.nan, set())


# --------------------------------------------------------- text and the fallbacks


def test_text_speaker_writes_one_line_per_prompt() -> None:
    out = io.StringIO()
    sp: Speaker = TextSpeaker(out, clock=FakeClock(12.5))
    sp.say("Turn left", G)
    sp.say("Position lost", Priority.LOST, t_s=20.0)
    sp.close()
    assert out.getvalue().splitlines() == [
        "[prompt     12.50 s GUIDANCE] Turn left",
        "[prompt     20.00 s SAFETY] Position lost",
    ]


def test_unavailable_engine_falls_back_to_text_with_exactly_one_warning(
    caplog: pytest.LogCaptureFixture,
) -> None:
    out = io.StringIO()
    with caplog.at_level(logging.INFO):
        sp = make_speaker("voice", driver_name="no_such_driver", text_stream=out)
        for text in ("Turn left", "Turn right", "You have arrived at your destination"):
            sp.say(text, G)
        sp.close()
    assert isinstance(sp, TextSpeaker)
    warnings = warnings_from_voice(caplog)
    assert len(warnings) == 1
    assert warnings[0].startswith("no speech engine (")
    assert "no_such_driver" in warnings[0] and "prompts are shown as text" in warnings[0]
    assert len(out.getvalue().splitlines()) == 3


def test_missing_espeak_ng_for_wav_falls_back_to_text_and_writes_no_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """No speech engine at all: no Pico, no espeak-ng command on PATH and no espeakng-loader
    package (an import of each fails, as on a machine without the wheel)."""
    monkeypatch.setenv("PATH", str(tmp_path / "empty"))
    monkeypatch.setitem(sys.modules, "espeakng_loader", None)
    monkeypatch.setitem(sys.modules, "py_nanotts", None)  # nor Pico
    wav = tmp_path / "prompts.wav"
    sp = make_speaker("wav", wav, text_stream=io.StringIO())
    sp.close()
    assert isinstance(sp, TextSpeaker)
    [warning] = warnings_from_voice(caplog)
    assert "espeak-ng not found" in warning and "is not written" in warning
    assert not wav.exists()


def test_missing_aplay_is_a_clear_reason(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PATH", str(tmp_path))
    with pytest.raises(SpeechEngineError, match="aplay not found"):
        check_audio_output()


def test_make_speaker_rejects_bad_requests() -> None:
    assert isinstance(make_speaker("text"), TextSpeaker)
    with pytest.raises(ValueError, match="unknown speaker kind"):
        make_speaker("loud")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="needs wav_path"):
        make_speaker("wav")


# ---------------------------------------------------------------------- pyttsx3


class FakeEngine:
    """Stands in for pyttsx3.Engine: records, optionally blocks or fails on the n-th prompt."""

    def __init__(self, fail_on: int | None = None, gate: threading.Event | None = None) -> None:
        self.spoken: list[str] = []
        self.fail_on = fail_on
        self.gate = gate
        self._text = ""

    def say(self, text: str) -> None:
        self._text = text

    def runAndWait(self) -> None:
        if self.gate is not None:
            self.gate.wait(60.0)
        if self.fail_on is not None and len(self.spoken) + 1 == self.fail_on:
            raise RuntimeError("espeak died")
        self.spoken.append(self._text)


def test_pyttsx3_speaker_speaks_on_its_own_thread_highest_priority_first() -> None:
    gate = threading.Event()
    engine = FakeEngine(gate=gate)
    sp = Pyttsx3Speaker(engine_factory=lambda: engine, clock=FakeClock())
    sp.say("first", G)
    deadline = time.monotonic() + 30.0
    while sp.stats()["popped"] < 1 and time.monotonic() < deadline:
        time.sleep(0.005)
    t0 = time.perf_counter()
    sp.say("landmark", INFO)
    sp.say("warning", S)
    sp.say("warning", S)
    assert time.perf_counter() - t0 < 10.0  # say never waits for speech (gate: 60 s)
    gate.set()
    sp.close()
    assert engine.spoken == ["first", "warning", "landmark"]
    assert sp.stats()["spoken"] == 3 and sp.stats()["deduplicated"] == 1


def test_engine_dying_mid_drive_warns_once_and_continues_as_text(
    caplog: pytest.LogCaptureFixture,
) -> None:
    out = io.StringIO()
    engine = FakeEngine(fail_on=2)
    sp = Pyttsx3Speaker(engine_factory=lambda: engine, clock=FakeClock(), text_stream=out)
    sp.say("one", G)
    sp.say("two", G)
    deadline = time.monotonic() + 2.0
    while not sp.failed and time.monotonic() < deadline:
        time.sleep(0.005)
    sp.say("three", G)
    sp.say("four", S)
    sp.close()
    assert engine.spoken == ["one"]
    assert [line.split("] ")[1] for line in out.getvalue().splitlines()] == ["two", "three", "four"]
    [warning] = warnings_from_voice(caplog)
    assert "speech engine (pyttsx3) failed (RuntimeError: espeak died)" in warning


def test_hung_engine_is_detected_and_prompts_go_to_text(caplog: pytest.LogCaptureFixture) -> None:
    out = io.StringIO()
    gate = threading.Event()
    sp = Pyttsx3Speaker(
        engine_factory=lambda: FakeEngine(gate=gate),
        clock=FakeClock(),
        text_stream=out,
        hang_timeout_s=0.2,
    )
    sp.say("stuck", G)
    deadline = time.monotonic() + 30.0  # the speaking thread has taken it (a loaded machine)
    while sp.stats()["popped"] < 1 and time.monotonic() < deadline:
        time.sleep(0.005)
    time.sleep(0.35)
    sp.say("next", G)
    assert sp.failed
    assert out.getvalue().splitlines()[-1].endswith("] next")
    gate.set()  # let the stuck utterance return so the thread can end
    sp.close()
    assert len(warnings_from_voice(caplog)) == 1


def test_bad_pyttsx3_driver_raises_a_clear_error() -> None:
    with pytest.raises(SpeechEngineError, match="'no_such_driver' did not start"):
        Pyttsx3Speaker("no_such_driver")


def test_real_pyttsx3_espeak_driver_runs_on_the_speaking_thread(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The real pyttsx3 + libespeak-ng synthesis path; aplay hidden so nothing is played."""
    monkeypatch.setenv("PATH", str(tmp_path))
    try:
        sp = Pyttsx3Speaker("espeak", check_audio=False, clock=FakeClock())
    except SpeechEngineError as e:
        pytest.skip(f"pyttsx3's espeak driver is unavailable: {e}")
    sp.say("Turn left", G)
    sp.say("Turn right", G)
    sp.close(timeout_s=10.0)
    assert not sp.failed
    assert sp.stats()["spoken"] == 2


# -------------------------------------------------------------------- WAV output


def tone_renderer(duration_s: float = 2.0, rate: int = 8000) -> Renderer:
    """A fake renderer: every prompt is ``duration_s`` of a 440 Hz tone."""
    n = int(duration_s * rate)
    pcm = (8000 * np.sin(2 * np.pi * 440 * np.arange(n) / rate)).astype("<i2").tobytes()
    return lambda text: (pcm, rate)


def read_wav(path: Path) -> tuple[np.ndarray, int]:
    with wave.open(str(path), "rb") as w:
        assert (w.getnchannels(), w.getsampwidth()) == (1, 2)
        return np.frombuffer(w.readframes(w.getnframes()), dtype="<i2"), w.getframerate()


def rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x.astype(np.float64) ** 2))) if x.size else 0.0


@pytest.mark.skipif(
    shutil.which("espeak-ng") is None, reason="espeak-ng not installed (Debian package espeak-ng)"
)
def test_espeak_ng_records_real_speech_into_one_wav(tmp_path: Path) -> None:
    wav = tmp_path / "prompts.wav"
    sp = make_speaker("wav", wav, clock=FakeClock())
    assert isinstance(sp, WavSpeaker)
    texts = ["In 300 metres, turn left", "Turn left", "Position lost. Stop when safe"]
    for k, text in enumerate(texts):
        sp.say(text, G, t_s=10.0 * k)
    sp.close()
    samples, rate = read_wav(wav)
    duration = samples.size / rate
    assert duration > 0.3
    assert rms(samples) > 500  # int16 full scale is 32767; digital silence is 0
    rec = sp.recorded
    assert [r.text for r in rec] == texts
    assert sp.duration_s == pytest.approx(duration)
    for r in rec:  # every prompt carries speech energy; the gaps are silent
        seg = samples[int(r.offset_s * rate) : int((r.offset_s + r.duration_s) * rate)]
        assert r.duration_s > 0.3 and rms(seg) > 500
    gap = samples[int((rec[0].offset_s + rec[0].duration_s) * rate) : int(rec[1].offset_s * rate)]
    assert gap.size == int(0.5 * rate) and rms(gap) == 0.0
    print(f"WAV: {duration:.2f} s, RMS {rms(samples):.0f}, {rate} Hz, {len(rec)} prompts")


def test_wav_timeline_drops_what_a_real_time_voice_could_not_say_in_time(tmp_path: Path) -> None:
    wav = tmp_path / "p.wav"
    sp = WavSpeaker(wav, renderer=tone_renderer(2.0), gap_s=0.5, clock=FakeClock())
    sp.say("a", G, t_s=0.0)  # spoken 0.0 .. 2.0
    sp.say("b", INFO, t_s=0.5, max_age_s=1.0)  # would start at 2.5: stale, dropped
    sp.say("c", S, t_s=1.0)  # starts at 2.5
    sp.say("d", G, t_s=30.0)  # the voice is idle by then: starts at 30
    sp.close()
    assert [(r.text, r.start_s, r.offset_s) for r in sp.recorded] == [
        ("a", 0.0, 0.0),
        ("c", 2.5, 2.5),
        ("d", 30.0, 5.0),
    ]
    assert sp.stats()["dropped_stale"] == 1
    samples, rate = read_wav(wav)
    assert samples.size / rate == pytest.approx(3 * 2.0 + 2 * 0.5)


def test_renderer_failing_mid_drive_keeps_the_wav_and_goes_to_text(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    good = tone_renderer(1.0)
    calls = 0

    def flaky(text: str) -> tuple[bytes, int]:
        nonlocal calls
        calls += 1
        if calls > 2:  # the probe and the first prompt work
            raise SpeechEngineError("espeak-ng failed: killed")
        return good(text)

    out = io.StringIO()
    wav = tmp_path / "p.wav"
    sp = WavSpeaker(wav, renderer=flaky, clock=FakeClock(), text_stream=out)
    for k, text in enumerate(["one", "two", "three"]):
        sp.say(text, G, t_s=10.0 * k)
    sp.close()
    sp.say("four", G, t_s=40.0)
    assert [r.text for r in sp.recorded] == ["one"]
    assert [line.split("] ")[1] for line in out.getvalue().splitlines()] == [
        "two",
        "three",
        "four",
    ]
    [warning] = warnings_from_voice(caplog)
    assert "espeak-ng failed: killed" in warning and "holds the 1 recorded so far" in warning
    samples, rate = read_wav(wav)
    assert samples.size == rate  # one 1-second prompt, a valid file


def test_close_without_drain_discards_and_accounts_for_every_prompt(tmp_path: Path) -> None:
    sp = WavSpeaker(tmp_path / "p.wav", renderer=tone_renderer(0.5), clock=FakeClock())
    for k in range(6):
        sp.say(f"p{k}", G, t_s=0.0)
    sp.close(drain=False)
    sp.say("late", G, t_s=1.0)
    st = sp.stats()
    assert st["said"] == 7
    assert (
        st["spoken"]
        + st["discarded"]
        + st["dropped_stale"]
        + st["dropped_overflow"]
        + st["discarded_after_close"]
        == 7
    )
    assert st["discarded_after_close"] == 1


def test_bad_prompt_time_is_the_callers_error_not_an_engine_failure(tmp_path: Path) -> None:
    sp = WavSpeaker(tmp_path / "p.wav", renderer=tone_renderer(0.5), clock=FakeClock())
    with pytest.raises(ValueError, match="finite"):
        sp.say("x", G, t_s=math.nan)
    with pytest.raises(ValueError, match="finite"):
        sp.say("x", G, t_s=0.0, max_age_s=-1.0)
    sp.say("fine", G, t_s=0.0)
    sp.close()
    assert not sp.failed and [r.text for r in sp.recorded] == ["fine"]
