"""Point numba's on-disk cache at a folder keyed by the compiled sources.

numba invalidates a cached function when its own file changes, but not when a
function it calls in another file changes: an edit to ``guidance.model`` could
leave a stale compiled ``hal_sim.engine`` behind. Keying the cache folder by a
hash of every compiled module (and the numba version) rules that out. A
``NUMBA_CACHE_DIR`` set by the user wins.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import sys
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

_ROOT = Path(__file__).resolve().parent.parent
COMPILED_SOURCES = (
    "guidance/core/model.py",
    "guidance/core/law.py",
    "hal_sim/params.py",
    "hal_sim/world.py",
    "hal_sim/ekf.py",
    "hal_sim/engine.py",
)


def configure() -> None:
    if "NUMBA_CACHE_DIR" in os.environ:
        return
    h = hashlib.sha256()
    with contextlib.suppress(PackageNotFoundError):  # numba is a dependency
        h.update(version("numba").encode())
    h.update(sys.version.encode())
    for rel in COMPILED_SOURCES:
        try:
            h.update((_ROOT / rel).read_bytes())
        except OSError:
            h.update(rel.encode())
    base = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
    os.environ["NUMBA_CACHE_DIR"] = str(base / "urban-guidance" / f"numba-{h.hexdigest()[:16]}")
