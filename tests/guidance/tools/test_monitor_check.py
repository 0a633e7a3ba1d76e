"""The monitor's fast schema check says valid exactly when jsonschema does.

``monitor_check._compile`` turns each output schema into one predicate (the monitor checks every
message it folds: 10,000 a second at 1,000 cars, which jsonschema's 300 us a state could not
do). These tests hold it to ``Draft7Validator.is_valid`` on real messages, on every leaf of them
replaced by values of each JSON type, and on random JSON objects built from the schemas' own
field names.
"""

from __future__ import annotations

import copy
import json
import random
from collections.abc import Iterator
from typing import Any

import pytest

from guidance.core.messages import Ellipse, EstimateState, Target
from guidance.outputs.messages import encode, state_message
from guidance.tools.monitor_check import SCHEMAS, _fast, _validator, message_problem

REPLACEMENTS: list[Any] = [None, True, False, 0, -3, 2.0, 1.5, -1e3, 95.0, "x", "goal", [], {},
                           [1.0], [[1.0, None]], {"x_m": 1.0}, {"a": "b"}]  # fmt: skip


def real_state() -> dict[str, Any]:
    cov = ((4.0, 0.1, 0.0), (0.1, 2.0, 0.0), (0.0, 0.0, 0.01))
    st_ = EstimateState(1.0, 3.0, 5.0, 0.5, cov, Ellipse(4.1, 2.8, 0.3, 8.2), False, True)
    msg = state_message(
        st_, vehicle_id="car1", seq=7, speed_mps=8.0, goal=(10.0, 20.0),
        target=Target(300.0, 100.0, "goal", None), origin_lat_lon_deg=(48.85, 2.35),
    )  # fmt: skip
    return dict(json.loads(encode(msg)))


def paths(value: Any, prefix: tuple[Any, ...] = ()) -> Iterator[tuple[Any, ...]]:
    yield prefix
    if isinstance(value, dict):
        for k, v in value.items():
            yield from paths(v, (*prefix, k))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            yield from paths(v, (*prefix, i))


def replaced(msg: dict[str, Any], path: tuple[Any, ...], new: Any) -> dict[str, Any]:
    out = copy.deepcopy(msg)
    node: Any = out
    for p in path[:-1]:
        node = node[p]
    node[path[-1]] = new
    return out


def agree(kind: str, msg: Any) -> None:
    fast = _fast(kind)
    assert fast is not None
    assert fast(msg) == _validator(kind).is_valid(msg), (kind, msg)


def test_every_schema_compiles_and_a_real_state_is_valid() -> None:
    assert all(_fast(k) is not None for k in SCHEMAS)
    msg = real_state()
    assert _fast("state")(msg) is True  # type: ignore[misc]
    assert message_problem("state", msg) is None


def test_every_leaf_of_a_state_replaced_by_each_json_type() -> None:
    msg = real_state()
    n = 0
    for path in paths(msg):
        if not path:
            continue
        for new in REPLACEMENTS:
            agree("state", replaced(msg, path, new))
            n += 1
    assert n > 500


def _names(schema: Any) -> set[str]:
    out: set[str] = set()
    if isinstance(schema, dict):
        for k, v in schema.items():
            if k == "properties":
                out |= set(v)
            out |= _names(v)
    elif isinstance(schema, list):
        for v in schema:
            out |= _names(v)
    return out


NAMES = sorted(set().union(*(_names(s) for s in SCHEMAS.values())))

# -- random JSON objects, drawn by a seeded generator ---------------------------------------------
# (issue 40: the hypothesis strategies these replace spent about 30 ms of CPU drawing each
# object, 200 s of the suite for 3,600 of them; this draws the same shapes, from the same
# leaves and keys with the same size limits, in well under a millisecond, so the tests check
# several times more objects in a fraction of the time. Each case's seed is in its message.)
SMALL: list[Any] = [None, True, False, 0, 1, -1, 200, -200, 0.0, -0.0, 0.5, 200.0, -200.0,
                    "goal", "landmark", "x", ""]  # fmt: skip
"""The leaves' edge values, drawn a third of the time (as hypothesis favours them)."""
BEYOND: list[Any] = [float("nan"), float("inf"), -float("inf"), 2e9, -2e9, 2e15, 10**16,
                     -(10**400), 10**400, 1e9, 1e15, "y" * 4097, "y" * 4096]  # fmt: skip
"""Values beyond (and at) the monitor's limits."""
ODD_KEYS = ["a_m", "b", "k" * 4097, "x_m"]


def _leaf(rng: random.Random, hostile: bool) -> Any:
    """A JSON leaf: null, a boolean, an integer or a float in [-200, 200], a short string; with
    ``hostile``, a value beyond the limits one time in three."""
    if hostile and rng.random() < 1 / 3:
        return rng.choice(BEYOND)
    if rng.random() < 1 / 3:
        return rng.choice(SMALL)
    kind = rng.randrange(5)
    if kind == 0:
        return None
    if kind == 1:
        return rng.random() < 0.5
    if kind == 2:
        return rng.randint(-200, 200)
    if kind == 3:
        return rng.uniform(-200.0, 200.0)
    return rng.choice(["goal", "landmark", "x", ""])


def _value(rng: random.Random, left: list[int], hostile: bool, depth: int = 1) -> Any:
    """A leaf, or a list (up to 4) or object (up to 6 keys) of values, at most ``left[0]``
    leaves in all (the strategies' ``max_leaves``), nested up to 7 deep (the objects are 1 to
    7 levels deep, as hypothesis drew them; the depth limit has its own test below)."""
    if left[0] <= 0 or depth >= 7 or rng.random() < 0.15 + 0.13 * depth:
        left[0] -= 1
        return _leaf(rng, hostile)
    if rng.random() < 0.5:
        return [_value(rng, left, hostile, depth + 1) for _ in range(rng.randint(0, 4))]
    return {_key(rng, hostile): _value(rng, left, hostile, depth + 1)
            for _ in range(rng.randint(0, 6))}  # fmt: skip


def _key(rng: random.Random, hostile: bool) -> str:
    return rng.choice(ODD_KEYS) if hostile and rng.random() < 0.2 else rng.choice(NAMES)


def random_object(seed: int, *, hostile: bool) -> dict[str, Any]:
    """An object of up to 12 (``hostile``: 10) members whose values are random JSON of up to 30
    (40) leaves: the schemas' own field names, or with ``hostile`` values beyond the limits and
    keys the schemas do not have."""
    rng = random.Random(seed)
    size, leaves = (10, 40) if hostile else (12, 30)
    return {_key(rng, hostile): _value(rng, [leaves], hostile)
            for _ in range(rng.randint(0, size))}  # fmt: skip


OBJECTS_PER_KIND = 1500
"""Per schema (7 schemas): 5 times the 300 each that hypothesis drew."""


@pytest.mark.parametrize("kind", sorted(SCHEMAS))
def test_random_objects_of_the_schemas_names(kind: str) -> None:
    fast = _fast(kind)
    assert fast is not None
    validator, valid = _validator(kind), 0
    for seed in range(OBJECTS_PER_KIND):
        body = random_object(seed, hostile=False)
        ok = validator.is_valid(body)
        assert fast(body) == ok, (kind, seed, body)
        valid += ok
    assert valid < OBJECTS_PER_KIND  # random objects are rarely whole messages: both answers


# -- the limits' fast walk says "within" exactly when the full walk finds nothing --------------
HOSTILE_OBJECTS = 6000
"""Four times the 1,500 hypothesis drew."""


def test_the_fast_walk_of_the_limits_agrees_with_the_full_one() -> None:
    from guidance.tools.monitor_check import MAX_VALUES, _values_problem, _within

    within = 0
    for seed in range(HOSTILE_OBJECTS):
        body = random_object(seed, hostile=True)
        fast = _within(body, "", 0, [MAX_VALUES - 1])
        assert fast == (_values_problem(body) is None), (seed, body)
        within += fast
    # both answers, each often: the walks are compared where they can differ
    assert 0.1 * HOSTILE_OBJECTS < within < 0.9 * HOSTILE_OBJECTS, within


def test_the_fast_walk_at_the_depth_and_count_limits() -> None:
    from guidance.tools.monitor_check import MAX_DEPTH, MAX_VALUES, _values_problem, _within

    for depth in (MAX_DEPTH - 1, MAX_DEPTH, MAX_DEPTH + 1):
        body: Any = 1.0
        for _ in range(depth):
            body = [body]
        body = {"a": body}
        assert _within(body, "", 0, [MAX_VALUES - 1]) == (_values_problem(body) is None), depth
    for n in (MAX_VALUES - 2, MAX_VALUES - 1, MAX_VALUES):
        body = {"a": [0] * n}
        assert _within(body, "", 0, [MAX_VALUES - 1]) == (_values_problem(body) is None), n
    assert not _within({"a": float("nan")}, "", 0, [MAX_VALUES - 1])
