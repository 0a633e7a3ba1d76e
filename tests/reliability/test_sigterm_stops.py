"""``guidance run`` stopped by SIGTERM, many times, as systemd stops it (issue 23, item 8).

Before: stops ended in SIGABRT ("FATAL: exception not rethrown") after the finished checkpoint
was written, about 6 in 100 on an idle machine, 7 in 30 with a CPU-bound process beside it.
The backtrace of a core dump: the thread zenoh-python runs the telemetry queryable's Python
callback on was killed with ``pthread_exit`` at interpreter finalization (``Py_FinalizeEx``,
in its garbage collection) when it took the GIL to return from zenoh after the session
closed; the pyo3 trampoline's ``catch_unwind`` swallowed that forced unwind and glibc aborted
(``unwind_cleanup`` <- ``__rust_panic_cleanup`` <- ``pyo3::impl_::trampoline`` <-
``python_callback<Query>``). Now closing a session joins its callback threads, and the
program ends with ``os._exit`` once everything is flushed (``guidance.app.run.end_process``).

Each stop is a real process (``sigterm_child.py``: simulated CAN and compass in its process,
Zenoh telemetry, text voice, a recording, checkpoints) stopped at a random time up to 1.5 s
after it said ``READY=1``, with a CPU-bound process beside it (a busy laptop: the callback
thread is slower to end, the race more frequent). 20 stops by default (1.5-3.5 minutes):
the defect ended 7 of 30 stops beside a busy process, so 20 stops miss it with probability
(23/30)**20 = 0.5 % (30 stops: 0.03 %; the suite runs on every change, so a miss does not
last); ``GUIDANCE_SIGTERM_STOPS=100`` for the issue's count.
"""

from __future__ import annotations

import json
import os
import random
import signal
import socket
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from reliability_helpers import closed_port

CHILD = Path(__file__).with_name("sigterm_child.py")
STOPS = int(os.environ.get("GUIDANCE_SIGTERM_STOPS", "20"))


@pytest.fixture
def busy_cpu() -> Iterator[None]:
    """One CPU-bound process (another program on the laptop) for the duration of the test."""
    hog = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        yield
    finally:
        hog.kill()
        hog.wait()


def _one_stop(folder: Path, delay_s: float) -> tuple[int, str]:
    """Start the child, wait for READY=1, SIGTERM it ``delay_s`` later: (exit code, stderr)."""
    notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    notify.bind(str(folder / "notify"))
    notify.settimeout(60.0)
    env = dict(os.environ, NOTIFY_SOCKET=str(folder / "notify"))
    env.pop("WATCHDOG_USEC", None)
    child = subprocess.Popen(
        [sys.executable, str(CHILD), str(folder), str(closed_port())],
        cwd=folder,
        env=env,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    try:
        while b"READY=1" not in notify.recv(4096):
            pass
        notify.settimeout(delay_s)
        try:
            while True:  # keep reading: a full datagram queue would block its watchdog pings
                notify.recv(4096)
        except TimeoutError:
            pass
        child.send_signal(signal.SIGTERM)
        _, err = child.communicate(timeout=30)
    finally:
        notify.close()
        if child.poll() is None:
            child.kill()
            child.communicate()
    return child.returncode, err.decode(errors="replace")


@pytest.mark.slow
@pytest.mark.timeout(30 * STOPS)  # a stop takes 4-10 s on a loaded 2-core machine
def test_every_sigterm_stop_of_guidance_run_exits_0(tmp_path: Path, busy_cpu: None) -> None:
    rng = random.Random(23)
    codes: list[int] = []
    for i in range(STOPS):
        folder = tmp_path / f"stop{i}"
        folder.mkdir()
        code, err = _one_stop(folder, rng.uniform(0.2, 1.5))
        codes.append(code)
        assert code == 0, f"stop {i + 1} of {STOPS}: exit {code}; {err[-800:]}"
        assert "FATAL" not in err and "Traceback" not in err, err[-800:]
        ck = json.loads((folder / "ck.json").read_text())
        assert ck["finished"] is True  # the clean stop's checkpoint, written before the exit
        assert list((folder / "rec").glob("*.mcap")), "no recording"
    assert codes == [0] * STOPS
