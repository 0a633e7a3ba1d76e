"""The layering rules of docs/layout.md, checked on the source (``ast`` import edges, lazy
imports included) and on what importing a module really loads."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

CORE_FORBIDDEN = (
    "guidance.app",
    "guidance.voice",
    "guidance.telemetry",
    "guidance.recording",
    "guidance.tools",
    "drivers",
    "hal_sim",
    "landmark_db",
    "zenoh",
    "mcap",
    "cv2",
    "pyttsx3",
    "asyncio",
    "threading",
    "serial",
    "can",
)
"""The pure core does no I/O: no shell package, no device library, no threads or event loop."""

GUIDANCE_VOCABULARY = {
    "drivers": (
        "guidance.core.messages",
        "guidance.core.health",
        "guidance.core.co_driver",
        "guidance.errors",
    ),
    "landmark_db": (
        "guidance.core.messages",
        "guidance.core.health",
        "guidance.core.model",
        "guidance.errors",
    ),
}
"""All that ``drivers`` and ``landmark_db`` may import from ``guidance``: the messages and
health vocabulary, plus the pure co-driver line parser the keyboard driver decodes with, and
the shared ellipse/Mahalanobis math the landmark gate uses (one definition of the math)."""

KNOWN_LONG: set[str] = set()
"""Modules still over the limit: none left; the list may only shrink (docs/layout.md)."""


def _imports(path: Path) -> list[tuple[int, str]]:
    """(line, imported module) for every import in a file, at any depth."""
    tree = ast.parse(path.read_text(), filename=str(path))
    out: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            if node.module == "guidance":  # from guidance import x: x is a submodule
                out += [(node.lineno, f"guidance.{a.name}") for a in node.names]
            else:
                out.append((node.lineno, node.module))
    return out


def _under(module: str, prefix: str) -> bool:
    return module == prefix or module.startswith(prefix + ".")


def _violations(package: str, allowed: object) -> list[str]:
    bad = []
    for path in sorted((ROOT / package.replace(".", "/")).rglob("*.py")):
        for line, mod in _imports(path):
            if not allowed(mod):  # type: ignore[operator]
                bad.append(f"{path.relative_to(ROOT)}:{line} imports {mod}")
    return bad


def test_core_is_pure() -> None:
    bad = _violations("guidance.core", lambda m: not any(_under(m, f) for f in CORE_FORBIDDEN))
    assert not bad, "guidance.core must stay pure:\n" + "\n".join(bad)


@pytest.mark.parametrize("package", ["drivers", "landmark_db"])
def test_drivers_and_landmarks_import_only_the_vocabulary(package: str) -> None:
    def allowed(m: str) -> bool:
        return not _under(m, "guidance") or any(_under(m, v) for v in GUIDANCE_VOCABULARY[package])

    bad = _violations(package, allowed)
    assert not bad, f"{package} may import only {GUIDANCE_VOCABULARY[package]}:\n" + "\n".join(bad)


def test_app_reaches_drivers_only_by_name() -> None:
    """``guidance.app`` picks drivers through the BACKENDS strings, never by import."""
    bad = _violations("guidance.app", lambda m: not _under(m, "drivers"))
    assert not bad, "\n".join(bad)


def test_only_tools_import_driver_decoders() -> None:
    for package in ("guidance.core", "guidance.voice", "guidance.telemetry", "guidance.recording"):
        bad = _violations(package, lambda m: not _under(m, "drivers"))
        assert not bad, "\n".join(bad)


@pytest.mark.parametrize(
    "module",
    [
        "guidance.recording",
        "guidance.recording.reader",
        "guidance.tools.replay",
        "guidance.app.config",
        "guidance.core.pipeline",
        "guidance.telemetry.messages",
    ],
)
def test_importing_does_not_load_zenoh(module: str) -> None:
    code = f"import sys, {module}; print('zenoh' in sys.modules)"
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT
    ).stdout.strip()
    assert out == "False", f"import {module} loads zenoh"


def test_no_module_over_600_lines() -> None:
    long = [
        f"{p.relative_to(ROOT)}: {n} lines"
        for pkg in ("guidance", "drivers", "landmark_db", "hal_sim")
        for p in sorted((ROOT / pkg).rglob("*.py"))
        if (n := len(p.read_text().splitlines())) > 600
        and str(p.relative_to(ROOT)) not in KNOWN_LONG
    ]
    assert not long, "split these modules (docs/layout.md):\n" + "\n".join(long)
    shrunk = [m for m in KNOWN_LONG if len((ROOT / m).read_text().splitlines()) <= 600]
    assert not shrunk, f"now short enough, take them off KNOWN_LONG: {shrunk}"


def test_the_numba_cache_key_covers_every_compiled_source() -> None:
    """A moved module must not silently drop out of the cache key (stale compiled code)."""
    from guidance._numba_cache import COMPILED_SOURCES

    missing = [rel for rel in COMPILED_SOURCES if not (ROOT / rel).is_file()]
    assert not missing, f"listed but absent: {missing}"
    compiled = {
        str(p.relative_to(ROOT))
        for pkg in ("guidance", "hal_sim")
        for p in (ROOT / pkg).rglob("*.py")
        if "@njit" in p.read_text()
    }
    assert compiled <= set(COMPILED_SOURCES), compiled - set(COMPILED_SOURCES)
