"""Property and fuzz tests (hypothesis) of the two files the car reads at start: the TOML
configuration (``guidance.app.config.load_config``, what ``guidance run --config`` calls) and the
landmark database (``landmark_db.store.open_db``, read-only, what the recogniser opens).

The property for both: every input either loads, or raises the project's own error
(``UserError``; ``LandmarkDbError`` for the database) with a one-line message that names the
problem: for the config, the offending table or key. Never another exception type. Nothing
non-finite gets through: a NaN or infinite number anywhere in a TOML file is rejected with its
key named, a loaded ``AppConfig`` holds only finite numbers, and gated candidates and landmark
fixes from an opened database have finite coordinates.

Inputs per run (``N_*`` below, derandomized so CI sees the same inputs every time), about 30 s
on two cores: about 4,500 config files (1,500 mutations of the shipped config/sim.toml and
config/tahoe.toml, all 255 ways of putting nan/inf/-inf at one of their numeric keys, 1,200
damaged TOML texts, 1,500 random byte strings) and 16,500 database files (4,800 of random
bytes, 7,200 truncations, 4,200 with flipped bytes, 300 corrupted through SQL), plus the real
``guidance run --config BAD.toml`` as a process for four bad files.
"""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import datetime as dt
import math
import re
import sqlite3
import subprocess
import sys
import tomllib
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st
from reliability_helpers import REPO

from guidance.app.config import AppConfig, load_config
from guidance.core.messages import CameraFrame
from guidance.errors import UserError
from hal_sim.sim_camera import SIM_ORIGIN, facade
from landmark_db.features import OrbConfig
from landmark_db.recognise import Recogniser
from landmark_db.store import LandmarkDbError, create_db, open_db, query_gate

N_CONFIG_MUTATED = 1500  # files: a shipped config with 1 to 4 mutations
N_CONFIG_NONFINITE = 250  # files: every numeric key of the bases set to nan, inf, -inf (all)
N_CONFIG_TEXT = 1200  # files: damaged TOML text
N_CONFIG_BYTES = 1500  # files: random bytes or text
N_DB_BYTES = 4800  # files: random bytes (8 per hypothesis example)
N_DB_TRUNCATED = 7200  # files: the valid file truncated (12 per example)
N_DB_FLIPS = 4200  # files: the valid file with 1 to 8 bytes flipped (6 per example)
N_DB_SQL = 300  # SQL-level corruptions, each opened, queried and run through the recogniser
FUZZ = settings(
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much],
    derandomize=True,  # the same inputs every run: CI is deterministic
    database=None,
)


def _one_line(exc: BaseException) -> str:
    msg = str(exc)
    assert msg and len(msg.splitlines()) == 1 and msg == msg.splitlines()[0], repr(msg)
    assert "Traceback" not in msg
    return msg


def _non_finite(obj: object, where: str = "", seen: set[int] | None = None) -> list[str]:
    """Where ``obj`` (a config object tree) holds a NaN or an infinity."""
    seen = set() if seen is None else seen
    if isinstance(obj, bool | int | str | bytes | type(None) | dt.date | dt.time | Path):
        return []
    if isinstance(obj, float | np.floating):
        return [] if math.isfinite(obj) else [where]
    if id(obj) in seen:
        return []
    seen.add(id(obj))
    out: list[str] = []
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        for f in dataclasses.fields(obj):
            out += _non_finite(getattr(obj, f.name), f"{where}.{f.name}", seen)
    elif isinstance(obj, Mapping):
        for k, v in obj.items():
            out += _non_finite(v, f"{where}[{k!r}]", seen)
    elif isinstance(obj, list | tuple | set | frozenset):
        for i, v in enumerate(obj):
            out += _non_finite(v, f"{where}[{i}]", seen)
    elif isinstance(obj, np.ndarray) and obj.dtype.kind == "f":
        return [] if np.isfinite(obj).all() else [where]
    return out


# -- the config ------------------------------------------------------------------------------------
def _shipped() -> dict[str, dict[str, Any]]:
    tahoe = tomllib.loads((REPO / "config" / "tahoe.toml").read_text())
    sim = tomllib.loads((REPO / "config" / "sim.toml").read_text())
    sim["goal"] = {"x_m": 1500.0, "y_m": -800.0}  # the simulator draws one; `run` needs it
    local = copy.deepcopy(tahoe)  # local metres, no lat/lon: declination given, a camera on
    local["start"] = {"x_m": 0.0, "y_m": 0.0, "heading_deg": 90.0}
    local["goal"] = {"x_m": 900.0, "y_m": 400.0}
    local["compass"]["declination_deg"] = -11.5
    local["compass"]["date"] = dt.date(2026, 5, 1)
    local["camera"]["enabled"] = True
    local["landmarks"] = [
        {"id": 1, "name": "church", "x_m": 120.0, "y_m": 40.0},
        {"id": 2, "name": "mill", "x_m": 600.0, "y_m": 380.0},
    ]
    geo = copy.deepcopy(tahoe)
    geo["landmarks"] = [{"id": 7, "name": "clock tower", "lat_deg": 42.45, "lon_deg": -76.49}]
    geo["health"] = {"silence_periods": 4.0, "min_timeout_s": 1.5, "max_reject_fraction": 0.4}
    geo["loop"] = {"tick_hz": 25, "state_rate_hz": 10.0, "max_lag_s": 0.4}
    return {"tahoe": tahoe, "sim": sim, "local": local, "geo": geo}


SHIPPED = _shipped()
BASES = sorted(SHIPPED)

_BARE = re.compile(r"[A-Za-z0-9_-]+")
_TOML_ESCAPES = {'"': '\\"', "\\": "\\\\", "\b": "\\b", "\t": "\\t", "\n": "\\n", "\f": "\\f"}


def toml_str(s: str) -> str:
    """A TOML basic string (any text; control characters and DEL escaped)."""
    out = []
    for ch in s:
        if ch in _TOML_ESCAPES:
            out.append(_TOML_ESCAPES[ch])
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\u{ord(ch):04x}")
        else:
            out.append(ch)
    return '"' + "".join(out) + '"'


def toml_value(v: object) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return "nan" if math.isnan(v) else repr(v)  # repr: inf, -inf, 1e+300, -0.0 are TOML
    if isinstance(v, str):
        return toml_str(v)
    if isinstance(v, dt.date | dt.time):
        return v.isoformat()
    if isinstance(v, list):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if isinstance(v, Mapping):
        return "{ " + ", ".join(f"{toml_str(k)} = {toml_value(x)}" for k, x in v.items()) + " }"
    raise TypeError(type(v))


def toml_dumps(doc: Mapping[str, object]) -> str:
    """Tables as ``[name]`` sections (so damaged text still looks like a config file)."""
    lines = []
    for key, value in doc.items():
        if not isinstance(value, Mapping):
            lines.append(f"{toml_str(key)} = {toml_value(value)}")
    for key, value in doc.items():
        if isinstance(value, Mapping):
            lines.append(f"\n[{key if _BARE.fullmatch(key) else toml_str(key)}]")
            lines += [f"{toml_str(k)} = {toml_value(x)}" for k, x in value.items()]
    return "\n".join(lines) + "\n"


def test_the_toml_writer_round_trips_the_shipped_configs() -> None:
    for doc in SHIPPED.values():
        assert tomllib.loads(toml_dumps(doc)) == doc


def test_the_fuzzed_bases_load(tmp_path: Path) -> None:
    for name, doc in SHIPPED.items():
        path = tmp_path / f"{name}.toml"
        path.write_text(toml_dumps(doc))
        cfg = load_config(path)
        assert not _non_finite(cfg), name


NON_FINITE = [math.nan, math.inf, -math.inf]
NUMBERS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(-(2**70), 2**70),
    st.sampled_from([*NON_FINITE, 1e308, -1e308, 5e-324, 0.0, -0.0, 10**400, -(10**400), 0, -1]),
)
SCALARS = st.one_of(
    NUMBERS,
    st.booleans(),
    st.text(max_size=12),
    st.sampled_from(["", "nan", "inf", "1e999", "can", "virtual", "opencv", "none", "../x\n"]),
    st.dates(),
    st.times(),
)
VALUES = st.one_of(
    SCALARS,
    st.lists(SCALARS, max_size=3),
    st.dictionaries(
        st.text(max_size=8), st.one_of(SCALARS, st.lists(SCALARS, max_size=2)), max_size=3
    ),
)
KEYS = st.one_of(
    st.text(max_size=12),
    st.sampled_from(["enabled", "backend", "id", "x_m", "lat_deg", "path", "mode", "nan"]),
)

Path_ = tuple[str | int, ...]


def _paths(node: object, prefix: Path_ = ()) -> Iterator[Path_]:
    """Every table, key and array element of a document, depth first."""
    items: Any = (
        node.items() if isinstance(node, Mapping) else enumerate(node) if isinstance(node, list)
        else ()
    )  # fmt: skip
    for k, v in items:
        yield (*prefix, k)
        yield from _paths(v, (*prefix, k))


def _numeric_paths(doc: object) -> list[Path_]:
    out = []
    for p in _paths(doc):
        v = _at(doc, p)
        if isinstance(v, int | float) and not isinstance(v, bool):
            out.append(p)
    return out


def _at(doc: Any, path: Path_) -> Any:
    for k in path:
        doc = doc[k]
    return doc


def _mutate(doc: dict[str, Any], op: str, pick: int, key: str, value: object) -> list[str]:
    """Apply one mutation in place; returns the names (tables, keys) it touched."""
    paths = list(_paths(doc))
    if not paths:
        doc[key] = value
        return [key]
    path = paths[pick % len(paths)]
    parent, last = _at(doc, path[:-1]), path[-1]
    names = [str(k) for k in path if isinstance(k, str)]
    if op == "delete":
        del parent[last]
    elif op == "replace":
        parent[last] = value
    else:  # add an unknown key to the table at (or holding) path
        target = parent[last] if isinstance(parent[last], dict) else parent
        if isinstance(target, list):
            target.append(value)
        else:
            target[key] = value
            names.append(key)
    return names


MUTATION = st.tuples(
    st.sampled_from(["delete", "replace", "replace", "add"]),
    st.integers(0, 10_000),
    KEYS,
    VALUES,
)


def _load(path: Path, text: str | bytes) -> AppConfig | UserError:
    if isinstance(text, str):
        path.write_text(text, encoding="utf-8")
    else:
        path.write_bytes(text)
    try:
        cfg = load_config(path)
    except UserError as exc:
        _one_line(exc)
        return exc
    assert isinstance(cfg, AppConfig)
    assert not _non_finite(cfg), f"non-finite values accepted: {_non_finite(cfg)}"
    return cfg


def _doc_non_finite(doc: object) -> list[Path_]:
    return [p for p in _paths(doc) if isinstance(v := _at(doc, p), float) and not math.isfinite(v)]


def _names(path: Path_) -> set[str]:
    """How a message may name a key: bare, or quoted (repr) when it has odd characters."""
    out = set()
    for k in path:
        if isinstance(k, str):
            out |= {k, repr(k)}
    return out


@pytest.fixture(scope="module")
def work(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("fuzz_loaders")


@settings(FUZZ, max_examples=N_CONFIG_MUTATED)
@given(st.sampled_from(BASES), st.lists(MUTATION, min_size=1, max_size=4))
def test_config_loader_on_mutated_shipped_configs(
    work: Path, base: str, mutations: list[tuple[str, int, str, object]]
) -> None:
    doc = copy.deepcopy(SHIPPED[base])
    touched: set[str] = set()
    for op, pick, key, value in mutations:
        touched |= {n for name in _mutate(doc, op, pick, key, value) for n in (name, repr(name))}
    result = _load(work / "car.toml", toml_dumps(doc))
    if isinstance(result, UserError):
        msg = str(result)
        assert any(n in msg for n in touched if n), f"{msg!r} names none of {touched}"
    bad = _doc_non_finite(doc)
    if bad:  # a NaN or infinity anywhere: rejected; when for that, naming a key holding one
        assert isinstance(result, UserError), f"accepted a non-finite value at {bad}"
        if "finite" in str(result):
            assert any(n in str(result) for p in bad for n in _names(p)), (str(result), bad)
        event("config: non-finite, rejected")
    event(f"config: {'rejected' if isinstance(result, UserError) else 'loaded'}")


NON_FINITE_CASES = [
    (base, path, value)
    for base in BASES
    for path in _numeric_paths(SHIPPED[base])
    for value in NON_FINITE
]


def test_config_loader_names_the_key_of_a_nan_or_infinity(work: Path) -> None:
    """Every numeric key of every base, each of nan, inf and -inf: all cases, not a sample."""
    assert len(NON_FINITE_CASES) >= N_CONFIG_NONFINITE
    for base, path, value in NON_FINITE_CASES:
        doc = copy.deepcopy(SHIPPED[base])
        _at(doc, path[:-1])[path[-1]] = value
        result = _load(work / "car.toml", toml_dumps(doc))
        assert isinstance(result, UserError), f"{base}: accepted {value} at {path}"
        msg = str(result)
        key = path[-1] if isinstance(path[-1], str) else path[-2]
        assert "finite" in msg and str(key) in msg and f"[{path[0]}" in msg, (path, msg)


@st.composite
def damaged_text(draw: st.DrawFn) -> str:
    text = toml_dumps(SHIPPED[draw(st.sampled_from(BASES))])
    for _ in range(draw(st.integers(1, 3))):
        i = draw(st.integers(0, len(text)))
        j = draw(st.integers(i, min(len(text), i + 40)))
        text = text[:i] + draw(st.text(max_size=12)) + text[j:]
    return text


@settings(FUZZ, max_examples=N_CONFIG_TEXT)
@given(damaged_text())
def test_config_loader_on_damaged_toml_text(work: Path, text: str) -> None:
    _load(work / "car.toml", text)


@settings(FUZZ, max_examples=N_CONFIG_BYTES)
@given(st.one_of(st.binary(max_size=2000), st.text(max_size=300).map(str.encode)))
def test_config_loader_on_random_bytes(work: Path, blob: bytes) -> None:
    _load(work / "car.toml", blob)


def _bad_configs(folder: Path) -> list[Path]:
    """Clearly invalid files; their devices are harmless anyway (a virtual bus, /dev/null)."""
    safe = copy.deepcopy(SHIPPED["tahoe"])
    safe["odometry"] |= {"interface": "virtual", "channel": "fuzz_never"}
    safe["compass"]["port"] = "/dev/null"
    safe["voice"] = {"backend": "none"}
    safe["telemetry"] = {"enabled": False}
    safe["recording"] = {"directory": str(folder / "rec")}
    safe["checkpoint"] = {"path": ""}
    safe["scene"] = {"keyboard": False}
    cases: dict[str, str | bytes] = {
        "goal_nan": toml_dumps(safe | {"goal": {"lat_deg": math.nan, "lon_deg": -76.47}}),
        "huge_int": toml_dumps(safe | {"vehicle": {"id": "tahoe1", "track_m": 10**30}}),
        "telemetry_list": toml_dumps(safe | {"telemetry": [1, 2]}),
        "random_bytes": bytes(np.random.default_rng(3).integers(0, 256, 5000, dtype=np.uint8)),
    }
    out = []
    for name, content in cases.items():
        p = folder / f"{name}.toml"
        if isinstance(content, bytes):
            p.write_bytes(content)
        else:
            p.write_text(content)
        with pytest.raises(UserError):  # invalid in process too, so the process opens nothing
            load_config(p)
        out.append(p)
    return out


def test_guidance_run_with_a_bad_config_exits_2_with_one_error_line(tmp_path: Path) -> None:
    procs = [
        subprocess.Popen(
            [sys.executable, "-m", "guidance.tools.cli", "run", "--config", str(p)],
            cwd=REPO,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for p in _bad_configs(tmp_path)
    ]
    for proc in procs:
        try:
            out, err = proc.communicate(timeout=60)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        assert proc.returncode == 2, (proc.args, out, err)
        assert "Traceback" not in err and "internal error" not in err, err
        assert err.startswith("guidance run: error: ") and err.count("\n") == 1, err
        assert not out


# -- the landmark database -------------------------------------------------------------------------
LANDMARK_XY = [(0.0, 0.0), (60.0, 0.0), (0.0, 60.0)]
PHOTO_SIZE = (120, 160)  # small JPEG photos, 100 ORB features: a 92 kB file, quick to describe


@dataclasses.dataclass(frozen=True)
class ValidDb:
    path: Path
    data: bytes = dataclasses.field(repr=False)
    photos: list[np.ndarray] = dataclasses.field(repr=False)


@pytest.fixture(scope="module")
def valid_db(tmp_path_factory: pytest.TempPathFactory) -> ValidDb:
    """A small valid database built with the project's API (create_db, add)."""
    path = tmp_path_factory.mktemp("landmarks") / "valid.sqlite"
    photos = [facade(100 + i, size=PHOTO_SIZE) for i in range(len(LANDMARK_XY))]
    db = create_db(path, SIM_ORIGIN, OrbConfig(n_features=100, max_side_px=192))
    for i, ((x, y), photo) in enumerate(zip(LANDMARK_XY, photos, strict=True)):
        db.add(
            f"lm{i}", photo, x_m=x, y_m=y, position_sigma_m=1.0, facing_deg=90.0 * i,
            image_format=".jpg",
        )  # fmt: skip
    db.close()
    with open_db(path) as ro:  # the baseline: valid, queried and recognised
        rec = Recogniser(ro)
        fixes = [rec.process_xy(CameraFrame(t, photos[0]), (0.0, 0.0), COV).fix for t in (0, 1)]
        assert fixes[1] is not None and (fixes[1].x_m, fixes[1].y_m) == (0.0, 0.0)
    return ValidDb(path, path.read_bytes(), photos)


COV = ((25.0, 0.0), (0.0, 25.0))
WIDE_COV = ((2500.0, 0.0), (0.0, 2500.0))


def _write_db(path: Path, data: bytes) -> None:
    for suffix in ("-wal", "-shm", "-journal"):
        Path(f"{path}{suffix}").unlink(missing_ok=True)
    path.write_bytes(data)


def _finite(*values: float | None) -> bool:
    return all(v is None or math.isfinite(v) for v in values)


def _exercise(path: Path, photos: list[np.ndarray] | None = None) -> str:
    """Open read-only; when that works, gate around each landmark (and recognise one)."""
    try:
        db = open_db(path)
    except LandmarkDbError as exc:
        _one_line(exc)
        return "rejected"
    try:
        # A wide gate that holds all three landmarks (the recogniser gates narrowly).
        for c in query_gate(db, (20.0, 20.0), WIDE_COV, 20.0):
            assert _finite(c.x_m, c.y_m, c.distance_m), c
            lm = db.get(c.id)
            if lm is not None:
                assert _finite(lm.x_m, lm.y_m, lm.position_sigma_m, lm.facing_deg), lm
        if photos is not None:
            rec = Recogniser(db)
            for i, photo in enumerate(photos[:2]):
                for t in (10.0 * i, 10.0 * i + 1.0):
                    r = rec.process_xy(CameraFrame(t, photo), LANDMARK_XY[i], COV)
                    if r.fix is not None:
                        assert _finite(r.fix.x_m, r.fix.y_m, r.fix.sigma_m), r.fix
        return "opened"
    except LandmarkDbError as exc:
        _one_line(exc)
        return "failed on use"
    finally:
        db.close()


def test_the_valid_database_opens_and_an_empty_file_does_not(work: Path, valid_db: ValidDb) -> None:
    assert _exercise(valid_db.path, valid_db.photos) == "opened"
    _write_db(work / "empty.sqlite", b"")
    assert _exercise(work / "empty.sqlite") == "rejected"


@settings(FUZZ, max_examples=N_DB_BYTES // 8)
@given(
    st.lists(
        st.one_of(
            st.binary(max_size=4096),
            st.binary(max_size=4096).map(lambda b: b"SQLite format 3\x00" + b),
            st.integers(0, 10_000),  # the valid file's first page, then random bytes
        ),
        min_size=8,
        max_size=8,
    )
)
def test_landmark_db_on_random_bytes(
    work: Path, valid_db: ValidDb, blobs: list[bytes | int]
) -> None:
    rng = np.random.default_rng([b if isinstance(b, int) else len(b) for b in blobs])
    for blob in blobs:
        if isinstance(blob, int):
            blob = valid_db.data[:4096] + rng.bytes(blob)
        _write_db(work / "random.sqlite", blob)
        event(_exercise(work / "random.sqlite"))


@settings(FUZZ, max_examples=N_DB_TRUNCATED // 12)
@given(st.lists(st.integers(0, 10**6), min_size=12, max_size=12))
def test_landmark_db_truncated_anywhere(work: Path, valid_db: ValidDb, cuts: list[int]) -> None:
    for cut in cuts:
        _write_db(work / "truncated.sqlite", valid_db.data[: cut % len(valid_db.data)])
        event(_exercise(work / "truncated.sqlite"))


FLIPS = st.lists(st.integers(0, 2**31), min_size=1, max_size=8)  # offset * 256 + xor mask


@settings(FUZZ, max_examples=N_DB_FLIPS // 6)
@given(st.lists(st.tuples(st.booleans(), FLIPS), min_size=6, max_size=6))
def test_landmark_db_with_flipped_bytes(
    work: Path, valid_db: ValidDb, cases: list[tuple[bool, list[int]]]
) -> None:
    # Anywhere in the file, or in the first two pages (header, schema, small tables).
    for early, flips in cases:
        span = 8192 if early else len(valid_db.data)
        data = bytearray(valid_db.data)
        for flip in flips:
            data[(flip >> 8) % span] ^= (flip & 0xFF) or 0x80
        _write_db(work / "flipped.sqlite", bytes(data))
        event(_exercise(work / "flipped.sqlite"))


TABLES = ["schema_version", "metadata", "landmarks", "photos", "photo_features", "landmark_index"]
"""The tables of a schema v3 file (``landmark_db.schema``)."""
SQL_VALUES = st.one_of(
    st.sampled_from(
        [
            math.inf,
            -math.inf,
            1e308,
            1e39,  # beyond float32: the R*Tree cannot hold it
            -5.0,
            0,
            2**63 - 1,
            "nan",
            "NaN",
            "inf",
            "-inf",
            "1e999",
            "abc",
            "",
            b"\x00\x01",
            None,
        ]
    ),
    st.floats(allow_nan=False),
    st.text(max_size=6),
)
SQL_OPS = st.one_of(
    st.tuples(st.just("drop"), st.sampled_from([*TABLES, "landmark_index_node"])),
    st.tuples(st.just("version"), st.sampled_from([0, 1, 3, -1, 2**62, "2", 2.0, None, b"\x02"])),
    st.tuples(st.just("version_rows"), st.sampled_from(["delete", "duplicate"])),
    st.tuples(
        st.just("meta"),
        st.sampled_from(
            [
                "origin_lat_deg",
                "origin_lon_deg",
                "origin_alt_m",
                "extractor",
            ]
        ),
        st.one_of(
            st.sampled_from(["nan", "inf", "-inf", "1e999", "abc", "", "91", "-181", "5", "1e3"]),
            st.sampled_from(  # extractors: stale (another kind, version, parameters) or bad
                [
                    "rootsift/1:1000@640",
                    "orb/2:100@192",
                    "orb/1:101@192",
                    "orb/1:5@192",
                    "orb/1:100@10",
                    "orb/1:100",
                    "teblid/1:100@192",
                    "orb/1:1e9@192",
                ]
            ),
            st.just("DELETE"),
        ),
    ),
    st.tuples(
        st.just("landmark"),
        st.integers(1, 3),
        st.sampled_from(
            ["lat_deg", "lon_deg", "x_m", "y_m", "facing_deg", "position_sigma_m", "name", "id"]
        ),
        SQL_VALUES,
    ),
    st.tuples(
        st.just("index"),
        st.integers(1, 4),
        st.sampled_from(["min_x", "max_x", "min_y", "max_y", "id"]),
        SQL_VALUES,
    ),
    st.tuples(st.just("delete_row"), st.sampled_from(TABLES[2:]), st.integers(1, 3)),
    st.tuples(
        st.just("features"),
        st.integers(1, 3),
        st.sampled_from(["keypoints", "descriptors", "count", "width", "height", "extractor"]),
        st.one_of(SQL_VALUES, st.binary(max_size=100)),
    ),
    st.tuples(st.just("loosen")),  # landmarks without column types or NOT NULL
    st.tuples(st.just("view"), st.sampled_from(TABLES[:5])),
    st.tuples(st.just("wal")),
)


def _corrupt(conn: sqlite3.Connection, op: tuple[Any, ...]) -> None:
    kind = op[0]
    if kind == "drop":
        conn.execute(f"DROP TABLE {op[1]}")
    elif kind == "version":
        conn.execute("UPDATE schema_version SET version = ?", (op[1],))
    elif kind == "version_rows":
        if op[1] == "delete":
            conn.execute("DELETE FROM schema_version")
        else:
            conn.execute("INSERT INTO schema_version SELECT version FROM schema_version")
    elif kind == "meta":
        if op[2] == "DELETE":
            conn.execute("DELETE FROM metadata WHERE key = ?", (op[1],))
        else:
            conn.execute("UPDATE metadata SET value = ? WHERE key = ?", (op[2], op[1]))
    elif kind == "landmark":
        conn.execute(f"UPDATE landmarks SET {op[2]} = ? WHERE id = ?", (op[3], op[1]))
    elif kind == "index":
        if op[1] == 4:  # a box for no landmark
            conn.execute("INSERT INTO landmark_index VALUES (4, -1e39, 1e39, -1e39, 1e39)")
        conn.execute(f"UPDATE landmark_index SET {op[2]} = ? WHERE id = ?", (op[3], op[1]))
    elif kind == "delete_row":
        col = {"landmarks": "id", "landmark_index": "id", "photo_features": "photo_id"}.get(
            op[1], "landmark_id"
        )
        conn.execute(f"DELETE FROM {op[1]} WHERE {col} = ?", (op[2],))
    elif kind == "features":
        # one photo per landmark in the valid file: photo ids are the landmark ids
        conn.execute(f"UPDATE photo_features SET {op[2]} = ? WHERE photo_id = ?", (op[3], op[1]))
    elif kind == "loosen":
        conn.executescript(
            "ALTER TABLE landmarks RENAME TO old_landmarks;"
            "CREATE TABLE landmarks (id INTEGER PRIMARY KEY, name, lat_deg, lon_deg, x_m, y_m,"
            " facing_deg, position_sigma_m, added_utc, source);"
            "INSERT INTO landmarks SELECT * FROM old_landmarks; DROP TABLE old_landmarks;"
        )
    elif kind == "view":
        conn.executescript(
            f"DROP TABLE {op[1]}; CREATE VIEW {op[1]} AS SELECT 2 AS version, 'k' AS key,"
            " '1' AS value, 1 AS id"
        )
    elif kind == "wal":
        conn.execute("PRAGMA journal_mode = WAL")


@settings(FUZZ, max_examples=N_DB_SQL)
@given(st.lists(SQL_OPS, min_size=1, max_size=4))
def test_landmark_db_with_sql_level_corruption(
    work: Path, valid_db: ValidDb, ops: list[tuple[Any, ...]]
) -> None:
    path = work / "corrupt.sqlite"
    _write_db(path, valid_db.data)
    conn = sqlite3.connect(path, isolation_level=None)
    try:
        for op in ops:
            # The corruption itself may be refused (NOT NULL, R*Tree order): then it is not done.
            with contextlib.suppress(sqlite3.Error):
                _corrupt(conn, op)
    finally:
        conn.close()
    event(_exercise(path, valid_db.photos))
    # The sidecar files of a WAL file: read-only opens must neither need nor leave them.
    assert not Path(f"{path}-journal").exists()


def test_open_landmark_db_rejects_a_non_finite_landmark(work: Path, valid_db: ValidDb) -> None:
    path = work / "nan.sqlite"
    for column, value in (("x_m", "nan"), ("lat_deg", math.inf), ("position_sigma_m", "1e999")):
        _write_db(path, valid_db.data)
        with sqlite3.connect(path) as conn:
            conn.execute(f"UPDATE landmarks SET {column} = ? WHERE id = 2", (value,))
        conn.close()
        with pytest.raises(LandmarkDbError, match=rf"landmark 2.*{column}"):
            open_db(path)
