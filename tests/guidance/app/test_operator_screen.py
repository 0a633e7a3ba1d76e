"""The operator screen of ``guidance run`` and the co-driver input as the car runs it.

* the pure fold (``OperatorView``) on a real ``Pipeline``'s outputs;
* ``run_car`` as systemd runs it (stdin at /dev/null, plain lines on a non-terminal stdout) with
  the co-driver's keypad records arriving on the configured input device (a FIFO): they reach
  the navigator, every key is acknowledged, a different exit taken is shown and spoken;
* the warning (log, screen, voice) when there is no co-driver input;
* the live screen in a real terminal (a tmux pane), captured while a simulated drive runs.
"""

from __future__ import annotations

import asyncio
import io
import logging
import math
import os
import re
import shlex
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager
from pathlib import Path

import pytest
from evdev import ecodes
from screen_drive import drive_config
from tmux_pane import TmuxPane, needs_tmux

from drivers.evdev_keys import key_press_records
from guidance.app.operator_view import OperatorView, compass_deg, uncertainty_text
from guidance.app.run import co_driver_problem, run_car, stdin_problem
from guidance.app.screen import OperatorScreen, render_rows
from guidance.core.localize.estimator import EstimatorConfig
from guidance.core.messages import (
    HeadingFix,
    Health,
    IntersectionScene,
    TurnCompleted,
    WheelOdometry,
)
from guidance.core.pipeline import Pipeline, PipelineConfig
from guidance.core.plan import chance
from guidance.core.plan.navigator import Method, NavigatorConfig
from hal_sim.sim_can import SimCanWheels
from hal_sim.sim_compass import SimCompassPty

ROOT = Path(__file__).resolve().parents[3]
KP = {str(d): getattr(ecodes, f"KEY_KP{d}") for d in range(10)}
CLOCK = r"\d\d:\d\d:\d\d"
NO_INPUT = "Warning: no co-driver input. Intersections cannot be reported."


@pytest.fixture(autouse=True)
def no_leaks(leak_check: Callable[..., AbstractContextManager[None]]) -> Iterator[None]:
    with leak_check(grace_s=3.0, ignore_threads=("asyncio_",), ptys=False):
        yield


def keys(text: str) -> bytes:
    return key_press_records([ecodes.KEY_KPENTER if c == "\n" else KP[c] for c in text])


# ----------------------------------------------------------------------------- the pure fold


def test_view_of_a_drive_next_instruction_uncertainty_heading_exit_and_prompts() -> None:
    p = Pipeline(
        PipelineConfig(
            estimator=EstimatorConfig(compass_two_sigma_deg=20.0),
            navigator=NavigatorConfig(method=Method.STRAIGHT_TO_GOAL),
            start_xy_m=(0.0, 0.0),
            goal_xy_m=(0.0, 1000.0),
            start_heading_rad=0.0,
            state_period_s=0.5,
        )
    )
    view = OperatorView(vehicle_id="v1")
    wall = 1_800_000_000.0
    for k in range(40):  # 40 m east
        t = 0.1 * (k + 1)
        msg = WheelOdometry(t, 1.0, 1.0)
        view.apply(msg, p.feed(msg), wall + t)
        view.apply(None, p.feed(HeadingFix(t, 0.0)), wall + t)
    scene = IntersectionScene(4.1, (math.pi / 2, 0.0, -math.pi / 2), None, ("l", "s", "r"))
    view.apply(scene, p.feed(scene), wall + 4.1)
    view.set_live(
        inputs=p.statuses(4.1),
        target=p.target(),
        heading_known=p.estimate.heading_known,
        speed_mps=p.estimate.speed_mps,
        co_driver="keypad /dev/x: connected",
        co_driver_ok=True,
    )
    rows = {label: text for label, text, _ in reversed(view.rows())}  # first of each label
    assert rows["NEXT"] == "Turn left, at the next intersection (distance unknown)"
    assert re.fullmatch(r"goal: 1\.0 km, bearing 35\d deg \(N\)", rows["TARGET"])
    assert rows["HEADING"].startswith("090 deg E (clockwise from north)")
    assert re.fullmatch(
        r"position good to about \d+ m \(2-sigma major axis \d+ m\)", rows["POSITION"]
    )
    # the chance row is the pipeline's own value, as the table gives it for this car
    assert p.planner.chance.value is not None and p.planner.chance.value > 0.5
    assert rows["CHANCE"] == (
        f"{chance.shown(p.planner.chance.value)} chance of reaching the goal from here "
        "(simulated cars like this one)"
    )
    assert chance.shown(p.planner.chance.value) in view.status_line()
    prompt = time.strftime("%H:%M:%S", time.localtime(wall + 4.1))
    assert rows["PROMPT"] == f"{prompt} At the next intersection, turn left"  # wall clock
    turn = TurnCompleted(5.0, -math.pi / 2, source="co-driver")  # the driver went right
    view.apply(turn, p.feed(turn), wall + 5.0)
    rows_list = view.rows()
    exit_rows = [(text, style) for label, text, style in rows_list if label == "EXIT"]
    assert exit_rows == [
        (
            f"{time.strftime('%H:%M:%S', time.localtime(wall + 5.0))} DIFFERENT EXIT TAKEN: "
            "advised turn left, took turn right (co-driver)",
            "warn",
        )
    ]
    assert dict((lab, t) for lab, t, _ in rows_list)["NEXT"].startswith("waiting for the next")
    assert ("INPUT", "co-driver keypad /dev/x: connected", "ok") in rows_list
    assert "next: waiting for the next intersection" in view.status_line()


def test_a_low_chance_is_flagged_and_none_after_arrival() -> None:
    p = Pipeline(
        PipelineConfig(
            estimator=EstimatorConfig(compass_two_sigma_deg=45.0),
            navigator=NavigatorConfig(method=Method.STRAIGHT_TO_GOAL),
            start_xy_m=(0.0, 0.0),
            goal_xy_m=(9000.0, 0.0),  # far, no landmarks, a poor compass
            start_heading_rad=0.0,
        )
    )
    view = OperatorView(vehicle_id="v1")
    msg = WheelOdometry(0.1, 1.0, 1.0)
    view.apply(msg, p.feed(msg), 1.0)
    row = next(r for r in view.rows() if r[0] == "CHANCE")
    assert row[2] == "warn" and row[1].startswith(chance.shown(p.planner.chance.value))
    assert p.planner.chance.value is not None and p.planner.chance.value < 0.5
    view.arrived = True
    assert not [r for r in view.rows() if r[0] == "CHANCE"]


def test_uncertainty_and_heading_words() -> None:
    assert uncertainty_text(60.0, False, 100.0) == (
        "position good to about 30 m (2-sigma major axis 60 m)"
    )
    assert (
        uncertainty_text(8.0, False, 100.0) == "position good to about 4 m (2-sigma major axis 8 m)"
    )
    assert uncertainty_text(4.0, False, 100.0).startswith("position good to about 2 m")
    for tenths in range(5, 5000, 7):  # the radius, rounded: never above the axis, never 0
        axis = tenths / 10.0
        about = float(uncertainty_text(axis, False, 1e9).split("about ")[1].split(" m")[0])
        step = 1.0 if axis < 20 else 5.0 if axis < 200 else 10.0
        assert 1.0 <= about <= max(1.0, axis) and abs(about - axis / 2) <= step / 2 + 0.5, axis
    assert uncertainty_text(130.0, True, 100.0).startswith("LOST: 2-sigma major axis 130 m")
    assert compass_deg(0.0) == 90.0 and compass_deg(math.pi / 2) == 0.0
    assert compass_deg(-math.pi / 2) == 180.0


def test_unhealthy_input_and_unknown_heading_are_flagged() -> None:
    view = OperatorView()
    odometry = Health("odometry", "silent", False, False, 3.0, rate_hz=0.0, expected_rate_hz=20.0)
    view.set_live(
        inputs={"odometry": odometry},
        target=None, heading_known=False, speed_mps=0.0, co_driver="", co_driver_ok=False,
    )  # fmt: skip
    rows = view.rows()
    assert ("INPUT", "odometry silent 0.0/20 Hz", "bad") in rows
    compass = Health("compass", "starting", True, True, None, rate_hz=0.0, expected_rate_hz=5.0)
    view.set_live(
        inputs={"compass": compass},
        target=None, heading_known=True, speed_mps=0.0, co_driver="", co_driver_ok=False,
    )  # fmt: skip
    assert ("INPUT", "compass starting 0.0/5 Hz", "warn") in view.rows()  # not "ok" yet
    assert rows[0] == (
        "NEXT", "no advice: waiting for a heading (compass or start heading)", "warn"
    )  # fmt: skip


def test_rich_rendering_keeps_typed_text_plain() -> None:
    """Typed text is never read as rich markup; control characters are replaced."""
    from rich.console import Console

    screen = OperatorScreen(OperatorView(), stream=io.StringIO(), live=False)
    screen.ack("[bold]l s r\x1b[2J")
    console = Console(file=io.StringIO(), width=100, record=True)
    with screen.lock:
        console.print(render_rows(screen.view.rows(), "guidance"))
    text = console.export_text()
    assert "[bold]l s r?[2J" in text and "\x1b" not in text


# ----------------------------------------------------------------------------- run_car


def test_stdin_checks() -> None:
    from guidance.app.config import SceneSettings

    with open(os.devnull) as null:
        assert stdin_problem(null) == "stdin is /dev/null (as under systemd)"
        assert "name a keypad" in co_driver_problem(SceneSettings("keyboard"), null)
    r, w = os.pipe()
    with os.fdopen(r) as pipe, os.fdopen(w, "w"):
        assert stdin_problem(pipe) == ""  # lines from a script
    assert co_driver_problem(SceneSettings("evdev", "/dev/input/by-id/nothing"), None) == (
        "input device /dev/input/by-id/nothing not found"
    )
    assert co_driver_problem(SceneSettings("none"), None) == "[scene] input = 'none'"


def _run(cfg: Path, out: io.StringIO, during: Callable[[], object], seconds: float) -> int:
    async def scenario() -> int:
        task = asyncio.create_task(run_car(str(cfg), screen="plain", stdout=out))
        await asyncio.sleep(0.5)
        await asyncio.to_thread(during)
        await asyncio.sleep(seconds)
        os.kill(os.getpid(), signal.SIGTERM)
        return await asyncio.wait_for(task, 10.0)

    return asyncio.run(scenario())


def test_keypad_reaches_the_navigator_under_systemd_conditions(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """stdin is /dev/null and stdout no terminal (the unit); keys come from the device."""
    keypad = tmp_path / "keypad"
    os.mkfifo(keypad)
    fd = os.open(keypad, os.O_RDWR)
    monkeypatch.setattr(sys, "stdin", open(os.devnull))  # noqa: SIM115
    channel = f"screen-plain-{os.getpid()}"
    out = io.StringIO()
    with SimCompassPty(rate_hz=10.0) as pty, SimCanWheels(channel, period_s=0.02) as wheels:
        pty.set_heading(90.0)
        wheels.set_speeds(8.0, 8.0)
        cfg = drive_config(tmp_path, channel=channel, compass_port=pty.port,
                           scene=f'input = "evdev"\ndevice = "{keypad}"')  # fmt: skip
        wheels.start()
        pty.start()

        def type_keys() -> None:
            time.sleep(0.5)
            os.write(fd, keys("486\n"))  # exits left, straight, right: the goal is north
            time.sleep(1.0)
            os.write(fd, keys("06\n"))  # the driver took the right

        try:
            assert _run(cfg, out, type_keys, 1.5) == 0
        finally:
            wheels.stop()
            pty.stop()
            os.close(fd)
            sys.stdin.close()
    text = out.getvalue()
    assert re.search(rf"guidance: co-driver +keypad {keypad}\n", text)  # the banner
    assert re.search(rf"guidance: {CLOCK} typing: key KEY_KP4: 4_\n", text)  # every key
    assert re.search(rf"{CLOCK} key: ok: exits left, straight, right", text)
    assert re.search(rf"{CLOCK} prompt: At the next intersection, turn left", text)
    assert re.search(rf"{CLOCK} key: ok: turned right", text)
    assert re.search(
        rf"{CLOCK} exit: DIFFERENT EXIT TAKEN: advised turn left, took turn right", text
    )
    status = re.findall(rf"{CLOCK} status: (.*)", text)[-1]
    assert "position good to about" in status and "odometry ok" in status
    assert "compass ok" in status and "co-driver keypad" in status
    assert "NO CO-DRIVER INPUT" not in text
    spoken = capsys.readouterr().err
    assert "Different exit taken. Guidance continues from here." in spoken
    assert re.search(rf"{CLOCK} prompt: Different exit taken. Guidance continues", text)


def test_no_co_driver_input_is_said_loudly(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    caplog: pytest.LogCaptureFixture,
) -> None:
    """[scene] input = keyboard under systemd (stdin /dev/null): log, screen and voice, once."""
    monkeypatch.setattr(sys, "stdin", open(os.devnull))  # noqa: SIM115
    channel = f"screen-none-{os.getpid()}"
    out = io.StringIO()
    with SimCompassPty(rate_hz=10.0) as pty, SimCanWheels(channel, period_s=0.02):
        cfg = drive_config(tmp_path, channel=channel, compass_port=pty.port,
                           scene='input = "keyboard"')  # fmt: skip
        with caplog.at_level(logging.WARNING, logger="guidance.app.run"):
            try:
                assert _run(cfg, out, lambda: None, 0.3) == 0
            finally:
                sys.stdin.close()
    warnings = [r.getMessage() for r in caplog.records if "NO CO-DRIVER INPUT" in r.getMessage()]
    assert warnings == [
        "NO CO-DRIVER INPUT: stdin is /dev/null (as under systemd); name a keypad in [scene] "
        "(input = 'evdev', device); intersections cannot be reported"
    ]
    assert "info: NO CO-DRIVER INPUT: stdin is /dev/null" in out.getvalue()
    assert re.search(rf"{CLOCK} prompt: {re.escape(NO_INPUT)}", out.getvalue())  # shown too
    spoken = capsys.readouterr().err
    assert spoken.count(NO_INPUT) == 1
    # a clean stop is no warning, and no raw JSON (issue 24)
    loud = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert not any(m.startswith("stopping") or "{" in m for m in loud), loud


def test_check_says_when_the_input_device_is_missing(tmp_path: Path) -> None:
    missing = "/dev/input/by-id/usb-missing-event-kbd"
    cfg = drive_config(tmp_path, channel="x", compass_port="/dev/null",
                       scene=f'input = "evdev"\ndevice = "{missing}"')  # fmt: skip
    done = subprocess.run(
        [sys.executable, "-m", "guidance.tools.cli", "run", "--config", str(cfg), "--check"],
        capture_output=True, text=True, cwd=ROOT, timeout=120,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert "OK (vehicle screen1" in done.stdout
    assert "[scene] device /dev/input/by-id/usb-missing-event-kbd does not exist" in done.stderr


# ----------------------------------------------------------------------------- a real terminal


class Pane(TmuxPane):
    """``tests/guidance/app/screen_drive.py`` in a tmux pane (a real pty, 100x40)."""

    def __init__(self, directory: Path, co_driver: str) -> None:
        self.dir = directory
        script = (
            f"{shlex.quote(sys.executable)} tests/guidance/app/screen_drive.py "
            f"{shlex.quote(str(directory))} --input {shlex.quote(co_driver)} "
            f"2> {shlex.quote(str(directory / 'stderr.txt'))}"
        )
        super().__init__(["sh", "-c", script], cwd=ROOT, env={"PYTHONPATH": str(ROOT)},
                         name="screen")  # fmt: skip
        deadline = time.monotonic() + 60.0
        while not (directory / "running").exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        assert (directory / "running").exists(), self.capture() + self.stderr()
        time.sleep(1.0)

    def stderr(self) -> str:
        path = self.dir / "stderr.txt"
        return path.read_text() if path.exists() else ""

    def send_keys(self, *keys: str) -> None:
        for key in keys:  # one at a time, as typed
            super().send_keys(key)
            time.sleep(0.05)

    def stop(self) -> str:
        """Ask the drive to stop; the pane after it exited."""
        (self.dir / "stop").touch()
        return self.wait_for(lambda s: "EXITED" in s)


@needs_tmux
def test_live_screen_in_a_real_terminal_shows_instruction_uncertainty_and_health(
    tmp_path: Path,
) -> None:
    """``guidance run`` on simulated devices inside a tmux pane; the keys come from the keypad
    FIFO; the pane's text is captured and checked."""
    keypad = tmp_path / "keypad"
    os.mkfifo(keypad)
    fd = os.open(keypad, os.O_RDWR)
    pane = Pane(tmp_path, "evdev")
    try:
        os.write(fd, keys("486\n"))
        screen = pane.wait_for(
            lambda s: "Turn left, at the next intersection" in s
            and "odometry ok" in s and "compass ok" in s and "position good to" in s
        )  # fmt: skip
        print(screen)  # pytest -s shows the captured screen
        assert (
            "NEXT" in screen and "Turn left, at the next intersection (distance unknown)" in screen
        )
        assert re.search(r"POSITION\s+position good to about \d+ m \(2-sigma major axis", screen)
        assert re.search(r"INPUT\s+compass ok", screen) and "odometry ok" in screen
        assert "co-driver keypad" in screen and "connected" in screen  # (a long path wraps)
        assert re.search(rf"PROMPT\s+{CLOCK} At the next intersection, turn left", screen)
        assert re.search(rf"TYPING\s+{CLOCK} key Enter: '486'", screen)  # the last key
        assert re.search(rf"KEY\s+{CLOCK} ok: exits left, straight, right", screen)
        assert "HEADING" in screen and "deg E (clockwise from north)" in screen
        assert "+ help" in screen  # the keys line
        final = pane.stop()
        assert "EXITED 0" in final, final + pane.stderr()
    finally:
        pane.close()
        os.close(fd)


@needs_tmux
def test_terminal_keyboard_under_the_live_screen_acknowledges_each_key(tmp_path: Path) -> None:
    """[scene] input = "keyboard" on the pane's own terminal: typed keys show on the TYPING
    line as they are typed (no terminal echo under the live view), Enter decides, ? helps."""
    pane = Pane(tmp_path, "keyboard")
    try:
        pane.send_keys("l", "Space", "s")
        typing = pane.wait_for(lambda s: "typing: l s_" in s)
        assert re.search(rf"TYPING\s+{CLOCK} typing: l s_", typing), typing
        pane.send_keys("Space", "r", "Enter")
        decided = pane.wait_for(lambda s: "Turn left, at the next intersection" in s)
        assert re.search(rf"KEY\s+{CLOCK} ok: exits left, straight, right", decided), decided
        pane.send_keys("?")
        helped = pane.wait_for(lambda s: "commands: ? or help" in s)
        assert "turn taken: tl, turned left" in helped, helped
        final = pane.stop()
        assert "EXITED 0" in final, final + pane.stderr()
    finally:
        pane.close()


HEADER = "╭─ guidance  vehicle"


@needs_tmux
def test_keys_typed_where_nothing_reads_them_leave_no_stale_header(tmp_path: Path) -> None:
    """Issue 24: lines typed while nothing reads the terminal key by key (here no co-driver
    input at all; in the car, before the keyboard reader starts) were echoed under the live
    view, and each redraw left a stale copy of the panel's header above it. The live view
    turns the terminal's echo off while it owns it (and back on at the end)."""
    pane = Pane(tmp_path, "none")
    try:
        pane.send_keys("l s r", "Enter", "?", "Enter")
        # a window of redraws (4 a second) in which a stale header would appear
        screen = pane.wait_for(lambda s: pane.scrollback().count(HEADER) > 1, timeout_s=3.0)
        assert pane.scrollback().count(HEADER) == 1, pane.scrollback()
        assert "l s r" not in screen, screen
        final = pane.stop()
        assert "EXITED 0" in final, final + pane.stderr()
    finally:
        pane.close()


# ----------------------------------------------------------------------------- voice keys


def test_repeat_and_mute_keys_act_on_the_real_speaker() -> None:
    """The co-driver's repeat (*) and mute (/) from the input's thread, through ``Operator``
    and ``MutableSpeaker`` around a real TextSpeaker; warnings are spoken while muted."""
    import threading

    from guidance.app.screen import MutableSpeaker, Operator
    from guidance.core.messages import Priority
    from guidance.voice.speakers import TextSpeaker

    speech = io.StringIO()
    speaker = MutableSpeaker(TextSpeaker(speech))
    p = Pipeline(
        PipelineConfig(
            estimator=EstimatorConfig(compass_two_sigma_deg=20.0),
            navigator=NavigatorConfig(method=Method.STRAIGHT_TO_GOAL),
            start_xy_m=(0.0, 0.0),
            goal_xy_m=(0.0, 1000.0),
            start_heading_rad=0.0,
        )
    )
    screen = OperatorScreen(OperatorView(), stream=io.StringIO(), live=False)
    op = Operator(screen, p, speaker=speaker, clock=lambda: 9.0)
    answers: list[str] = []

    async def scenario() -> None:
        op.loop = asyncio.get_running_loop()

        def from_the_keypad_thread(cmd: str) -> None:
            t = threading.Thread(target=lambda: answers.append(op.on_command(cmd)))
            t.start()
            t.join()

        from_the_keypad_thread("repeat")  # nothing said yet
        scene = IntersectionScene(1.0, (math.pi / 2, 0.0), None, ("l", "s"))
        out = p.feed(scene)
        op(scene, out)
        for prompt in out.prompts:
            speaker.say(prompt.text, prompt.priority, prompt.t_s)
        from_the_keypad_thread("repeat")
        await asyncio.sleep(0.05)  # the repeat is said on the loop
        from_the_keypad_thread("mute")
        speaker.say("At the next intersection, bear left", Priority.GUIDANCE, 9.5)
        speaker.say("Warning: odometry is silent", Priority.SAFETY, 9.5)
        from_the_keypad_thread("mute")
        speaker.say("Continue straight", Priority.GUIDANCE, 10.0)

    asyncio.run(scenario())
    assert answers == [
        "nothing to repeat yet",
        "repeating: At the next intersection, turn left",
        "voice muted (warnings still spoken)",
        "voice on",
    ]
    said = speech.getvalue()
    assert said.count("At the next intersection, turn left") == 2  # said, then repeated
    assert "bear left" not in said and speaker.dropped_muted == 1
    assert "Warning: odometry is silent" in said and "Continue straight" in said
    shown = [e.text for e in screen.view.of_kind("prompt", 5)]
    assert shown == ["At the next intersection, turn left"] * 2  # the repeat is shown too


def test_mute_is_shown_on_the_screen_and_the_text_speaker_speaks_into_it(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Issue 24: mute was acknowledged once and then invisible; the text speaker's lines
    ("[prompt 1041.73 s SAFETY] ...") were printed over the live view."""
    from guidance.app.screen import MutableSpeaker, Operator, ScreenTextStream
    from guidance.core.messages import Priority
    from guidance.voice.speakers import TextSpeaker

    text = TextSpeaker()
    speaker = MutableSpeaker(text)
    p = Pipeline(
        PipelineConfig(
            estimator=EstimatorConfig(compass_two_sigma_deg=20.0),
            navigator=NavigatorConfig(method=Method.STRAIGHT_TO_GOAL),
            start_xy_m=(0.0, 0.0), goal_xy_m=(0.0, 1000.0), start_heading_rad=0.0,
        )
    )  # fmt: skip
    screen = OperatorScreen(OperatorView(), stream=io.StringIO(), live=False, wall=lambda: 0.0)
    text.redirect(ScreenTextStream(screen))
    op = Operator(screen, p, speaker=speaker, clock=lambda: 9.0)

    def row(label: str) -> list[tuple[str, str]]:
        return [(t, s) for lab, t, s in screen.view.rows() if lab == label]

    op.refresh()
    assert row("VOICE") == [("on", "")]
    assert op.on_command("mute") == "voice muted (warnings still spoken)"
    assert row("VOICE")[0][0].startswith("MUTED (warnings still spoken)")
    speaker.say("At the next intersection, bear left", Priority.GUIDANCE, 9.5)
    speaker.say("Warning: odometry is silent", Priority.SAFETY, 9.6)
    op.refresh()
    assert row("VOICE") == [
        ("MUTED (warnings still spoken; 1 prompt not spoken): / or mute to turn it on", "warn")
    ]
    assert "voice muted" in screen.view.status_line()
    # the warning was said: on the screen (SAID), not on the terminal
    assert row("SAID") == [("00:00:00 Warning: odometry is silent", "bad")] or row("SAID")[0][
        0
    ].endswith("Warning: odometry is silent")
    assert "[prompt" not in " ".join(t for t, _ in row("SAID"))
    assert capsys.readouterr().err == ""
    op.on_command("mute")
    assert row("VOICE") == [("on", "")]


def test_a_clean_stop_is_one_readable_info_line() -> None:
    from guidance.app.run import stop_line

    line = stop_line({"loop_lag_p50_ms": 0.4, "loop_lag_p99_ms": 2.25, "loop_lag_max_ms": None})
    assert line == "stopped cleanly; event-loop lag p50 0.4 ms, p99 2.2 ms, max -"
    assert "{" not in line
