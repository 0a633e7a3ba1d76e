"""A command in a tmux pane of fixed size (a real terminal), for the tests that look at what
a user sees: capture the pane (and what scrolled off it), type keys, wait for text."""

from __future__ import annotations

import itertools
import os
import shlex
import shutil
import subprocess
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import pytest

needs_tmux = pytest.mark.skipif(
    shutil.which("tmux") is None, reason="tmux is not installed (.ci/run installs it)"
)


_PANES = itertools.count()


class TmuxPane:
    """``argv`` run in ``cwd`` in a detached tmux session of ``width`` x ``height`` on a
    server of its own; when it ends the pane says ``EXITED <code>`` and stays open."""

    def __init__(
        self,
        argv: Sequence[str],
        *,
        cwd: Path,
        width: int = 100,
        height: int = 40,
        env: dict[str, str] | None = None,
        name: str = "pane",
    ) -> None:
        # a server of its own per pane: one test's server may still be exiting when the next
        # pane starts ("server exited unexpectedly" when two shared a socket name)
        socket = f"guidance-{name}-{os.getpid()}-{next(_PANES)}"
        self.tmux = ["tmux", "-L", socket, "-f", "/dev/null"]
        command = f"cd {shlex.quote(str(cwd))} && {shlex.join(argv)}; echo EXITED $?; sleep 60"
        full_env = {**os.environ, "TERM": "xterm-256color", **(env or {})}
        full_env.pop("TMUX", None)
        for var in ("COLUMNS", "LINES"):  # the pane's size, not the caller's
            full_env.pop(var, None)
        subprocess.run([*self.tmux, "new-session", "-d", "-x", str(width), "-y", str(height),
                        "-s", "t", command], check=True, env=full_env)  # fmt: skip

    def capture(self) -> str:
        """What the pane shows now."""
        return self._capture()

    def scrollback(self) -> str:
        """The pane with everything scrolled off its top."""
        return self._capture("-S", "-")

    def _capture(self, *extra: str) -> str:
        done = subprocess.run([*self.tmux, "capture-pane", "-p", *extra, "-t", "t"],
                              capture_output=True, text=True)  # fmt: skip
        return done.stdout

    def send_keys(self, *keys: str) -> None:
        """Each key as typed (tmux key names: "Enter", "C-c")."""
        for key in keys:
            subprocess.run([*self.tmux, "send-keys", "-t", "t", key], check=True)

    def wait_for(self, predicate: Callable[[str], bool], timeout_s: float = 20.0) -> str:
        """The pane once ``predicate`` holds for it, or as it is after ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        while True:
            screen = self.capture()
            if predicate(screen) or time.monotonic() > deadline:
                return screen
            time.sleep(0.2)

    def close(self) -> None:
        subprocess.run([*self.tmux, "kill-server"], capture_output=True)
