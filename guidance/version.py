"""The version of the ``urban-guidance`` distribution, for ``--version`` and recordings.

From the installed distribution's metadata; in a source tree that was never installed,
from ``pyproject.toml`` beside the packages; "unknown" if neither can be read.
"""

from __future__ import annotations

import importlib.metadata
import tomllib
from pathlib import Path

DISTRIBUTION = "urban-guidance"
_PYPROJECT = Path(__file__).resolve().parents[1] / "pyproject.toml"


def version(pyproject: Path = _PYPROJECT) -> str:
    """``urban-guidance``'s version, e.g. "0.1.0"."""
    try:
        return importlib.metadata.version(DISTRIBUTION)
    except importlib.metadata.PackageNotFoundError:
        pass
    try:
        with pyproject.open("rb") as f:
            return str(tomllib.load(f)["project"]["version"])
    except (OSError, KeyError, TypeError, tomllib.TOMLDecodeError):
        return "unknown"


def version_text(prog: str) -> str:
    """What ``PROG --version`` prints: "guidance 0.1.0"."""
    return f"{prog} {version()}"
