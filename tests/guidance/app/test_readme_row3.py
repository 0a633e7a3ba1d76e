"""README row 3 as a user runs it: ``guidance run --config config/sim-landmarks.toml`` in a
terminal (a tmux pane of fixed size) shows the car's operator screen (the banner, the rows)
while the simulated car drives, and answers the co-driver's keys (issue 24, item 4).

It runs from ``sim_landmarks_home`` (a copy of the config whose landmark database is built
once, on first use, and shared with ``test_car_landmarks.py``), so nothing is written into
the repository."""

from __future__ import annotations

import os
import re
import sys
from pathlib import Path

from tmux_pane import TmuxPane, needs_tmux

CLOCK = r"\d\d:\d\d:\d\d"
HEADER = "╭─ guidance  vehicle simlm1"
ROW3 = ["guidance", "run", "--config", "config/sim-landmarks.toml"]


def _target(screen: str) -> str | None:
    m = re.search(r"TARGET\s+(.+?)\s*│", screen)
    return m.group(1) if m else None


@needs_tmux
def test_readme_row_3_shows_the_operator_screen_and_answers_keys(
    sim_landmarks_home: Path,
) -> None:
    first_use = not (sim_landmarks_home / "out" / "sim-landmarks" / "landmarks.sqlite").exists()
    venv_bin = str(Path(sys.executable).parent)  # `guidance` is the installed console script
    path = f"{venv_bin}{os.pathsep}{os.environ.get('PATH', '')}"
    pane = TmuxPane(ROW3, cwd=sim_landmarks_home, width=100, height=40, name="row3",
                    env={"PATH": path})  # fmt: skip
    try:
        # first use builds the landmark database (about a minute) before the screen starts
        # (the rows fill in once the devices run)
        screen = pane.wait_for(lambda s: "│ INPUT" in s or "EXITED" in s, timeout_s=600.0)
        whole = pane.scrollback()
        assert "│ INPUT" in screen and "EXITED" not in screen, whole
        assert "guidance run" in whole and re.search(r"vehicle\s+simlm1", whole), whole
        assert re.search(r"drive\s+simulated city, seed 3, 1 x real time", whole), whole
        assert re.search(r"co-driver\s+simulated co-driver .*\+ keyboard", whole), whole
        for row in ("NEXT", "TARGET", "HEADING", "POSITION", "KEYS"):
            assert re.search(rf"│ {row}\s", screen), screen
        if first_use:  # said before the screen, and still there above it
            built = whole.find("landmark database built in")
            assert 0 <= whole.find("first use: building the landmark database") < built, whole
            assert built < whole.find("guidance run"), whole

        pane.send_keys("?")  # help at once
        helped = pane.wait_for(lambda s: "commands: ? or help" in s)
        assert re.search(rf"TYPING\s+{CLOCK} typing: \?_", helped), helped
        assert re.search(rf"KEY\s+{CLOCK} exits ahead: l s r", helped), helped
        pane.send_keys("*", "Enter")  # repeat the last instruction
        answered = pane.wait_for(lambda s: "ok: repeating: " in s or "nothing to repeat" in s)
        assert re.search(rf"{CLOCK} ok: (repeating: |nothing to repeat yet)", answered), answered

        first = _target(answered)  # the screen follows the car as it drives
        moved = pane.wait_for(lambda s: _target(s) not in (None, first), timeout_s=30.0)
        assert _target(moved) not in (None, first), moved
        assert pane.scrollback().count(HEADER) == 1, pane.scrollback()  # no stale copy

        pane.send_keys("C-c")  # the drive ends with its summary
        final = pane.wait_for(lambda s: "EXITED" in s, timeout_s=60.0)
        assert re.search(r"(STOPPED|ARRIVED): drove \d", final), final
        assert "EXITED 0" in final and "Traceback" not in pane.scrollback(), pane.scrollback()
    finally:
        pane.close()


def test_readme_row_3_prints_plain_lines_when_stdout_is_not_a_terminal(
    sim_landmarks_home: Path,
) -> None:
    """stdout a pipe (a log, the journal): the banner and one line per event, no escape codes;
    SIGINT ends the drive with its summary."""
    import signal
    import subprocess

    venv_bin = Path(sys.executable).parent
    proc = subprocess.Popen([str(venv_bin / "guidance"), *ROW3[1:]], cwd=sim_landmarks_home,
                            stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)  # fmt: skip
    lines: list[str] = []
    try:
        assert proc.stdout is not None
        for line in proc.stdout:  # until the first prompt (the drive is under way)
            lines.append(line)
            if re.match(rf"guidance: {CLOCK} prompt: ", line):
                break
        proc.send_signal(signal.SIGINT)
        rest, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    out = "".join(lines) + rest
    assert proc.returncode == 0, err[-2000:]
    assert re.search(r"^guidance: vehicle\s+simlm1$", out, re.M), out
    assert re.search(r"^guidance: co-driver\s+simulated co-driver .*no keys", out, re.M), out
    assert re.search(rf"^guidance: {CLOCK} prompt: ", out, re.M), out
    assert re.search(r"^(STOPPED|ARRIVED): drove \d", out, re.M), out
    assert "\x1b" not in out and "Traceback" not in err, out + err
