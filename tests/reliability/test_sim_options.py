"""``guidance sim`` on hostile options and stopped by a signal (issue 14, item 13).

Options are checked before anything starts: one ``error:`` line and exit 2, in well under a
second (before: accepted, a crash, a drive that never ends, or a failure after the whole drive).
A drive stopped with SIGTERM or Ctrl-C (SIGINT) ends with its summary and a complete recording
that the standard MCAP reader opens (summary and footer written).
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader
from reliability_helpers import REPO, wait_until

from guidance.tools.cli import main

BAD = {
    "--seed -1": "--seed must be an integer",
    "--seed 1180591620717411303424": "--seed must be an integer",
    "--density inf": "--density must be a finite number",
    "--density nan": "--density must be a finite number",
    "--duration nan": "--duration must be a finite number",
    "--duration inf": "--duration must be a finite number",
    "--speed 1e-300": "--speed must be a finite number",
    "--speed inf": "--speed must be a finite number",
    "--decision-distance nan": "--decision-distance must be a finite number",
    "--camera -1": "--camera must be a finite number",
    "--camera inf": "--camera must be a finite number",
    "--detection-rate nan": "--detection-rate must be a finite number",
    "--can-silent 5:inf": "--can-silent duration must be a finite number",
    "--out /etc/passwd": "--out /etc/passwd: exists and is not a folder",
}


@pytest.mark.parametrize("option", list(BAD))
def test_hostile_sim_options_fail_with_one_line_before_anything_starts(
    option: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["sim", "--no-voice", "--no-telemetry", "--no-png", *option.split()]
    if "--out" not in option:
        argv += ["--out", str(tmp_path / "out")]
    t0 = time.monotonic()
    rc = main(argv)
    err = capsys.readouterr().err
    assert rc == 2, err
    assert err.strip().splitlines() == [err.strip()] and BAD[option] in err
    assert "internal error" not in err
    assert time.monotonic() - t0 < 5.0  # no drive ran
    assert not (tmp_path / "out" / "recordings").exists()


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_a_sim_stopped_by_a_signal_ends_with_its_summary_and_a_complete_recording(
    tmp_path: Path, sig: signal.Signals
) -> None:
    out = tmp_path / "out"
    proc = subprocess.Popen(
        [sys.executable, "-m", "guidance.tools.cli", "sim", "--seed", "7", "--no-voice",
         "--no-telemetry", "--no-png", "--speed", "5", "--out", str(out)],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )  # fmt: skip
    try:
        rec = out / "recordings"
        wait_until(lambda: any(rec.glob("*.mcap")), 60.0, "the recording to start")
        time.sleep(3.0)  # a few simulated seconds recorded
        proc.send_signal(sig)
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, stderr
    assert "STOPPED: drove" in stdout, stdout
    assert "recording:" in stdout
    (path,) = rec.glob("*.mcap")
    with path.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()  # the standard reader: needs summary and footer
        assert summary is not None and summary.statistics is not None
        topics = {ch.topic for _, ch, _ in reader.iter_messages()}
    assert {"/session", "/odometry", "/state"} <= topics
