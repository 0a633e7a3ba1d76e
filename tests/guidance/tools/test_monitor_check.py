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
from collections.abc import Iterator
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

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
LEAVES = st.one_of(
    st.none(), st.booleans(), st.integers(-200, 200),
    st.floats(-200, 200, allow_nan=False), st.sampled_from(["goal", "landmark", "x", ""]),
)  # fmt: skip
JSON = st.recursive(
    LEAVES,
    lambda inner: st.one_of(
        st.lists(inner, max_size=4), st.dictionaries(st.sampled_from(NAMES), inner, max_size=6)
    ),
    max_leaves=30,
)


@pytest.mark.parametrize("kind", sorted(SCHEMAS))
@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(body=st.dictionaries(st.sampled_from(NAMES), JSON, max_size=12))
def test_random_objects_of_the_schemas_names(kind: str, body: dict[str, Any]) -> None:
    agree(kind, body)


# -- the limits' fast walk says "within" exactly when the full walk finds nothing --------------
BEYOND = st.one_of(
    LEAVES,
    st.sampled_from([float("nan"), float("inf"), -float("inf"), 2e9, -2e9, 2e15, 10**16,
                     -(10**400), 10**400, 1e9, 1e15, "y" * 4097, "y" * 4096]),
)  # fmt: skip
KEYS = st.one_of(st.sampled_from(NAMES), st.sampled_from(["a_m", "b", "k" * 4097, "x_m"]))
HOSTILE = st.recursive(
    BEYOND,
    lambda inner: st.one_of(st.lists(inner, max_size=4), st.dictionaries(KEYS, inner, max_size=6)),
    max_leaves=40,
)


@settings(max_examples=1500, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(body=st.dictionaries(KEYS, HOSTILE, max_size=10))
def test_the_fast_walk_of_the_limits_agrees_with_the_full_one(body: dict[str, Any]) -> None:
    from guidance.tools.monitor_check import MAX_VALUES, _values_problem, _within

    assert _within(body, "", 0, [MAX_VALUES - 1]) == (_values_problem(body) is None), body


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
