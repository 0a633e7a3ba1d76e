"""The CI bar under load: `.ci/run` on a fresh clone with CPU-bound processes beside it.

    .venv/bin/python benchmarks/suite_load.py [--runs 3] [--hogs 2] [--repo .] [--keep DIR]

Each run clones ``--repo`` (its committed HEAD) into a new temporary folder, starts ``--hogs``
processes that spin (``python3 -c 'while 1: pass'``, nice 0), runs ``bash .ci/run`` there and
ends the spinners. Printed per run: the exit status, the wall time against the developers'
30-minute bar, the load average seen (sampled every 15 s: mean and maximum) and the failed
tests' names (pytest's ``FAILED`` lines). The runs' output is kept in ``--keep`` (default: a
temporary folder, named at the start), with each run's JUnit report (``PYTEST_ADDOPTS``) for
``benchmarks/suite_time.py``. The load average counts other work on the machine too:
on a shared machine it is the figure that says how loaded the run was, so it is printed.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

BAR_S = 30 * 60.0


def sample_load(stop: threading.Event, out: list[float]) -> None:
    """The one-minute load average every 15 s until ``stop``."""
    while True:
        out.append(os.getloadavg()[0])
        if stop.wait(15.0):
            return


def one_run(repo: Path, hogs: int, log: Path) -> tuple[int, float, list[float], list[str]]:
    """(exit status, wall s, load samples, FAILED lines) of one fresh-clone ``.ci/run``."""
    with tempfile.TemporaryDirectory(prefix="suite-load-") as tmp:
        clone = Path(tmp) / "clone"
        subprocess.run(["git", "clone", "-q", str(repo), str(clone)], check=True)
        spin = [subprocess.Popen([sys.executable, "-c", "while 1: pass"]) for _ in range(hogs)]
        stop, loads = threading.Event(), list[float]()
        sampler = threading.Thread(target=sample_load, args=(stop, loads), daemon=True)
        sampler.start()
        t0 = time.monotonic()
        try:
            with log.open("w") as f:
                env = {**os.environ, "PYTEST_ADDOPTS": f"--junitxml={log.with_suffix('.xml')}"}
                done = subprocess.run(
                    ["bash", ".ci/run"],
                    cwd=clone,
                    env=env,
                    stdout=f,
                    stderr=subprocess.STDOUT,
                    stdin=subprocess.DEVNULL,
                )
            rc = done.returncode
        finally:
            wall = time.monotonic() - t0
            for p in spin:
                p.kill()
                p.wait()
            stop.set()
            sampler.join()
    failed = [ln.strip() for ln in log.read_text(errors="replace").splitlines()
              if ln.startswith(("FAILED ", "ERROR "))]  # fmt: skip
    return rc, wall, loads, failed


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--hogs", type=int, default=2, help="CPU-bound processes beside each run")
    ap.add_argument("--repo", type=Path, default=Path(__file__).resolve().parents[1])
    ap.add_argument("--keep", type=Path, default=None, help="folder for the runs' output")
    args = ap.parse_args(argv)
    keep = args.keep or Path(tempfile.mkdtemp(prefix="suite-load-logs-"))
    keep.mkdir(parents=True, exist_ok=True)
    head = subprocess.run(["git", "-C", str(args.repo), "rev-parse", "--short", "HEAD"],
                          capture_output=True, text=True).stdout.strip()  # fmt: skip
    print(f"{args.runs} runs of .ci/run on fresh clones of {args.repo} ({head}), "
          f"{args.hogs} CPU-bound processes beside each, {os.cpu_count()} CPUs; logs in {keep}",
          flush=True)  # fmt: skip
    worst = 0
    for k in range(1, args.runs + 1):
        rc, wall, loads, failed = one_run(args.repo, args.hogs, keep / f"run{k}.log")
        mean = sum(loads) / len(loads)
        verdict = "inside" if wall <= BAR_S else "OVER"
        print(f"run {k}: exit {rc}, {wall:6.0f} s wall ({wall / 60:.1f} min, {verdict} the "
              f"30-min bar), load average mean {mean:.1f} max {max(loads):.1f}, "
              f"{len(failed)} failed", flush=True)  # fmt: skip
        for line in failed:
            print(f"    {line}", flush=True)
        worst = max(worst, rc)
    return worst


if __name__ == "__main__":
    sys.exit(main())
