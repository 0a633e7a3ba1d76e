"""Stale compass data after a stall (issue 14, item 11): the real SerialCompass in a child process
reading a simulated compass on a pty; the child is stopped with SIGSTOP for 3 s while the
compass keeps talking, then continued.

Before: the sentences buffered during the stop were read at once, stamped "now" and handed on as
current headings. Now the reader sees it did not run for longer than ``stall_flush_s`` and
discards what was buffered (counted), so only sentences sent after the stop are delivered.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import threading
import time

from reliability_helpers import REPO, wait_until

from hal_sim.sim_compass import SimCompassPty

CHILD = textwrap.dedent(
    """
    import sys, time
    from drivers.compass import SerialCompass, SerialCompassConfig
    src = SerialCompass(SerialCompassConfig(port=sys.argv[1]))
    def sink(h):
        print(f"H {time.monotonic():.6f} {h.heading_deg:.1f}", flush=True)
    src.start(sink)
    try:
        sys.stdin.readline()  # until the parent closes stdin
    finally:
        src.stop()
        s = src.stats()
        print(f"S {s.get('stale_flushes', 0)} {s.get('stale_bytes', 0)}", flush=True)
    """
)


def test_sentences_buffered_while_the_process_was_stopped_are_discarded_not_fused() -> None:
    with SimCompassPty(rate_hz=10.0) as sim:
        sim.set_heading(90.0)
        sim.start()
        child = subprocess.Popen(
            [sys.executable, "-c", CHILD, sim.port],
            cwd=REPO,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        assert child.stdout is not None and child.stdin is not None
        lines: list[str] = []
        stdout = child.stdout
        reader = threading.Thread(target=lambda: lines.extend(stdout), name="child-out")
        reader.start()
        try:
            wait_until(lambda: sum(ln.startswith("H") for ln in lines) >= 5, 10.0, "headings")
            os.kill(child.pid, signal.SIGSTOP)
            time.sleep(0.2)
            sim.set_heading(180.0)  # what the compass says while nobody reads: 30 sentences
            time.sleep(3.0)
            sim.set_heading(270.0)
            time.sleep(0.15)
            t_cont = time.monotonic()
            os.kill(child.pid, signal.SIGCONT)
            time.sleep(1.5)
        finally:
            os.kill(child.pid, signal.SIGCONT)
            child.stdin.close()
            child.wait(timeout=10)
            reader.join(timeout=5)
    headings = [ln.split() for ln in lines if ln.startswith("H")]
    after = [float(h[2]) for h in headings if float(h[1]) >= t_cont]
    stale = [h for h in after if h == 180.0]
    assert not stale, f"{len(stale)} stale headings delivered as current"
    assert after and set(after) == {270.0}  # fresh sentences flow again at once
    flushes, stale_bytes = next(ln.split()[1:] for ln in lines if ln.startswith("S"))
    assert int(flushes) == 1 and int(stale_bytes) > 20 * 20  # about 30 sentences dropped
