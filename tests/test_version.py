"""``--version`` on the ``guidance`` and ``landmark-db`` commands (and every subcommand)."""

from __future__ import annotations

import importlib.metadata
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from guidance import version as version_module
from landmark_db import cli as landmark_cli

ROOT = Path(__file__).resolve().parents[1]
PYPROJECT_VERSION = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]


def run(*argv: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", *argv], cwd=ROOT, capture_output=True, text=True, timeout=120
    )


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (("guidance.tools.cli", "--version"), "guidance"),
        (("guidance.tools.cli", "monitor", "--version"), "guidance"),
        (("guidance.tools.cli", "study", "--version"), "guidance"),
        (("landmark_db.cli", "--version"), "landmark-db"),
    ],
)
def test_version_flag_prints_the_distribution_version(argv: tuple[str, ...], expected: str) -> None:
    r = run(*argv)
    assert r.returncode == 0, r.stderr
    assert r.stdout == f"{expected} {version_module.version()}\n"
    assert r.stderr == ""


def test_version_comes_from_the_installed_distribution() -> None:
    assert version_module.version() == importlib.metadata.version("urban-guidance")
    assert version_module.version_text("guidance") == f"guidance {version_module.version()}"


def _not_installed(name: str) -> str:
    raise importlib.metadata.PackageNotFoundError(name)


def test_source_tree_falls_back_to_pyproject(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    monkeypatch.setattr(importlib.metadata, "version", _not_installed)
    assert version_module.version() == PYPROJECT_VERSION
    assert landmark_cli._version() == PYPROJECT_VERSION
    other = tmp_path / "pyproject.toml"
    other.write_text('[project]\nname = "urban-guidance"\nversion = "9.8.7"\n')
    assert version_module.version(other) == "9.8.7"
    assert version_module.version(tmp_path / "missing.toml") == "unknown"
    other.write_text("[project]\n")
    assert version_module.version(other) == "unknown"
