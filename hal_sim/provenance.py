"""What a study ran on and with: commit, tree state, package versions, platform; and the
95 % intervals its figures carry (bootstrap for means, Wilson for proportions).

Every study output records ``provenance()``: the summary JSON in full, the tables and the
figure captions as one line (``caption``). Git is optional: outside a checkout, or without
git on the PATH, the commit is None and the rest is still recorded.
"""

from __future__ import annotations

import platform
import subprocess
import sys
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np

PACKAGES = ("numpy", "numba", "filterpy")
"""The packages whose versions change what a study computes."""
CI_LEVEL = 0.95
WILSON_Z = 1.96
"""Two-sided 95 % normal quantile for the Wilson score interval."""
BOOTSTRAP_RESAMPLES = 2000


def _git(*args: str) -> str | None:
    here = Path(__file__).resolve().parent
    try:
        out = subprocess.run(
            ["git", *args], cwd=here, capture_output=True, text=True, timeout=10, check=True
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip()


def git_state() -> tuple[str | None, bool | None]:
    """(commit, dirty) of the checkout this code runs from; (None, None) without git."""
    commit = _git("rev-parse", "HEAD")
    if not commit:
        return None, None
    status = _git("status", "--porcelain", "--untracked-files=no")
    return commit, None if status is None else bool(status)


def versions() -> dict[str, str | None]:
    out: dict[str, str | None] = {"python": platform.python_version()}
    for name in PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = None
    return out


def provenance() -> dict[str, Any]:
    """Commit, dirty flag, versions and platform, for a study's outputs."""
    commit, dirty = git_state()
    return {
        "commit": commit,
        "dirty": dirty,
        "versions": versions(),
        "platform": platform.platform(),
        "machine": platform.machine(),
        "argv": list(sys.argv),
    }


def caption(prov: dict[str, Any], seed: int, n: int, trials: int) -> str:
    """The one-line provenance a figure caption or a table header carries."""
    commit = prov.get("commit")
    tree = "no git" if commit is None else commit[:10] + (" (dirty)" if prov.get("dirty") else "")
    v = prov.get("versions", {})
    pkgs = ", ".join(f"{k} {v.get(k) or '-'}" for k in PACKAGES)
    return (
        f"commit {tree}; {pkgs}; {prov.get('platform', '?')}; "
        f"seed {seed}; N = {n} ({trials} per condition)"
    )


# ----------------------------------------------------------------------------- intervals
def wilson_interval(
    successes: Any, trials: Any, z: float = WILSON_Z
) -> tuple[np.ndarray, np.ndarray]:
    """Wilson score interval (lower, upper) of a binomial proportion, per element.

    Unlike the normal approximation it stays inside [0, 1] and is not zero-width at
    0 % or 100 %, which matters in bins of a few dozen trials.
    """
    k = np.asarray(successes, dtype=float)
    n = np.asarray(trials, dtype=float)
    p = k / n
    z2 = z * z
    denom = 1.0 + z2 / n
    centre = (p + z2 / (2 * n)) / denom
    half = z * np.sqrt(p * (1 - p) / n + z2 / (4 * n * n)) / denom
    lo = np.where(k <= 0, 0.0, np.clip(centre - half, 0.0, 1.0))
    hi = np.where(k >= n, 1.0, np.clip(centre + half, 0.0, 1.0))
    return lo, hi


def wilson_pair(successes: int, trials: int) -> list[float] | None:
    if trials <= 0:
        return None
    lo, hi = wilson_interval(successes, trials)
    return [float(lo), float(hi)]


def bootstrap_mean(
    values: np.ndarray, seed: int, resamples: int = BOOTSTRAP_RESAMPLES
) -> list[float] | None:
    """Percentile bootstrap 95 % interval of the mean; None with fewer than two values.

    Seeded, so a study's intervals are as reproducible as its results.
    """
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if len(v) < 2:
        return None
    rng = np.random.default_rng([seed, len(v)])
    means = np.empty(resamples)
    for start in range(0, resamples, 250):
        m = min(250, resamples - start)
        means[start : start + m] = v[rng.integers(0, len(v), (m, len(v)))].mean(axis=1)
    a = (1.0 - CI_LEVEL) / 2.0
    lo, hi = np.quantile(means, [a, 1.0 - a])
    return [float(lo), float(hi)]


def inside(value: float, interval: list[float] | None) -> bool | None:
    if interval is None:
        return None
    return interval[0] <= value <= interval[1]
