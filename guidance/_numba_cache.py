"""Point numba's on-disk cache at a folder keyed by the compiled sources.

numba invalidates a cached function when its own file changes, but not when a
function it calls in another file changes: an edit to ``guidance.core.model``
could leave a stale compiled caller in another package behind. Keying the cache
folder by a hash of every compiled source (and the numba and Python versions)
rules that out. A ``NUMBA_CACHE_DIR`` set by the user wins.

Each package declares its own compiled sources: a ``NUMBA_SOURCES`` tuple of
file names, relative to the package, in its ``__init__.py`` (every module with
``@njit`` functions and every module whose constants they compile in). They are
read from the packages installed with this one without importing them: the
folder must be set before the first compiled function is defined, whichever
package is imported first. ``tests/test_layers.py`` checks that every
``@njit`` module, and what it imports from the project, is declared.
"""

from __future__ import annotations

import ast
import contextlib
import hashlib
import os
import sys
from importlib.metadata import PackageNotFoundError, distribution, version
from pathlib import Path

_ROOT = Path(__file__).resolve().parent.parent
_DISTRIBUTION = "urban-guidance"


def _packages() -> list[Path]:
    """This project's top-level package folders: the distribution's, or in a checkout that is
    not installed, the package folders next to ``guidance``."""
    with contextlib.suppress(PackageNotFoundError):
        names = (distribution(_DISTRIBUTION).read_text("top_level.txt") or "").split()
        if names:
            return [_ROOT / name for name in sorted(names)]
    return sorted(d for d in _ROOT.iterdir() if (d / "__init__.py").is_file())


def _declared(init: Path) -> tuple[str, ...]:
    """The ``NUMBA_SOURCES`` assigned in a package's ``__init__.py``, read without importing."""
    text = init.read_text(encoding="utf-8")
    if "NUMBA_SOURCES" not in text:
        return ()
    for node in ast.parse(text).body:
        if isinstance(node, ast.Assign) and any(
            isinstance(t, ast.Name) and t.id == "NUMBA_SOURCES" for t in node.targets
        ):
            return tuple(str(name) for name in ast.literal_eval(node.value))
    return ()


def compiled_sources() -> list[Path]:
    """Every file some package of this project declares in its ``NUMBA_SOURCES``."""
    return [
        init.parent / name
        for package in _packages()
        for init in sorted(package.rglob("__init__.py"))
        for name in _declared(init)
    ]


def configure() -> None:
    if "NUMBA_CACHE_DIR" in os.environ:
        return
    h = hashlib.sha256()
    with contextlib.suppress(PackageNotFoundError):  # numba is a dependency
        h.update(version("numba").encode())
    h.update(sys.version.encode())
    for path in compiled_sources():
        h.update(path.relative_to(_ROOT).as_posix().encode())
        with contextlib.suppress(OSError):
            h.update(path.read_bytes())
    base = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
    os.environ["NUMBA_CACHE_DIR"] = str(base / "urban-guidance" / f"numba-{h.hexdigest()[:16]}")
