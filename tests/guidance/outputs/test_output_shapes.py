"""The output messages' shapes (``guidance.outputs.shapes``) are what the encoders write and what
the JSON Schemas are generated from (``guidance.outputs.schemas``): over many messages of every
kind, built from random values through the output table, each message has exactly its shape's
keys, nested objects included, and validates against the generated schema."""

from __future__ import annotations

import math
import random
import typing
from typing import Any

import jsonschema
import pytest

from guidance.core.messages import (
    Decision,
    Ellipse,
    EstimateState,
    ExitOption,
    ExitTaken,
    Health,
    LandmarkFix,
    Prompt,
    Target,
    TurnCompleted,
)
from guidance.outputs.kinds import (
    OUTPUTS,
    HealthReport,
    LandmarkReport,
    OutputContext,
    OutputKind,
)
from guidance.outputs.messages import LandmarkRejection
from guidance.outputs.schemas import SCHEMAS
from guidance.outputs.shapes import MESSAGE_SHAPES

N = 60
"""Messages per kind."""


def _num(rng: random.Random) -> float:
    """A coordinate-like number, sometimes not finite (the encoders write null for those)."""
    return rng.choice([rng.uniform(-5e3, 5e3), rng.uniform(-1.0, 1.0), math.nan, math.inf])


def _pair(rng: random.Random) -> tuple[float, float]:
    """A point: both coordinates finite or neither (a position is one state; the schema's
    ``POINT_RULES`` refuse one coordinate without the other)."""
    if rng.random() < 0.2:
        return math.nan, math.nan
    return rng.uniform(-5e3, 5e3), rng.uniform(-5e3, 5e3)


def _decision(rng: random.Random) -> Decision:
    options = tuple(
        ExitOption(i, _num(rng), _num(rng), _num(rng), _num(rng), _num(rng))
        for i in range(rng.randint(0, 4))
    )
    kind = rng.choice(["goal", "landmark"])
    return Decision(rng.uniform(0, 1e4), rng.randint(0, 3), _num(rng), _num(rng), options,
                    _num(rng), _num(rng), kind, rng.choice([None, 3]), rng.randint(0, 99),
                    rng.random() < 0.5, "goal", "cost")  # fmt: skip


def _health(rng: random.Random, name: str) -> Health:
    return Health(name, rng.choice(["ok", "silent"]), rng.random() < 0.5, rng.random() < 0.5,
                  age_s=rng.choice([None, rng.uniform(0, 9)]))  # fmt: skip


def _item(kind: OutputKind, rng: random.Random) -> Any:
    t = rng.uniform(0.0, 1e4)
    if kind.name == "state":
        cov = tuple(tuple(_num(rng) for _ in range(3)) for _ in range(3))
        ell = Ellipse(_num(rng), _num(rng), _num(rng), _num(rng))
        return EstimateState(t, *_pair(rng), _num(rng), cov, ell,
                             rng.random() < 0.5, rng.random() < 0.5)  # fmt: skip
    if kind.name == "decision":
        return _decision(rng)
    if kind.name == "prompt":
        return Prompt(t, "Turn left in 50 metres.", rng.randint(0, 3), "turn")
    if kind.name == "landmark":
        fixes = tuple(LandmarkFix(t, i, *_pair(rng), 5.0) for i in range(rng.randint(0, 3)))
        rej = tuple(LandmarkRejection("outside_gate", rng.choice([None, 4])) for _ in range(2))
        return LandmarkReport(t, fixes, rej, rng.choice([None, 7]))
    if kind.name == "health":
        inputs = {n: _health(rng, n) for n in ("odometry", "compass")}
        return HealthReport(t, inputs, {"telemetry": _health(rng, "telemetry"), "loop": {"lag": 1}})
    if kind.name == "turn":
        return TurnCompleted(t, _num(rng), "detected")
    if kind.name == "exit":
        return ExitTaken(t, _decision(rng), rng.randint(0, 3), rng.random() < 0.5, "co-driver")
    raise AssertionError(f"no item for {kind.name}")


def _context(rng: random.Random) -> OutputContext:
    return OutputContext(
        speed_mps=_num(rng),
        target=rng.choice([None, Target(*_pair(rng), "landmark", 3)]),
        goal=rng.choice([None, _pair(rng)]),
        method="hybrid",
        mode="goal",
        chance=rng.choice([None, rng.random()]),
        origin_lat_lon_deg=rng.choice([None, (42.44, -76.50)]),
    )


def _keys_match(value: Any, hint: Any, where: str) -> None:
    """``value`` has exactly the keys of the ``TypedDict`` in ``hint`` (recursively)."""
    while typing.get_origin(hint) in (typing.Annotated, typing.NotRequired):
        hint = typing.get_args(hint)[0]
    args = [a for a in typing.get_args(hint) if a is not type(None)]
    if value is None:
        return
    if typing.get_origin(hint) in (typing.Union, __import__("types").UnionType):
        hint = args[0]
        while typing.get_origin(hint) is typing.Annotated:
            hint = typing.get_args(hint)[0]
    if typing.is_typeddict(hint):
        hints = typing.get_type_hints(hint, include_extras=True)
        assert set(value) == set(hints), f"{where}: {set(value) ^ set(hints)}"
        for k, h in hints.items():
            _keys_match(value[k], h, f"{where}.{k}")
    elif typing.get_origin(hint) is list and isinstance(value, list):
        for i, v in enumerate(value):
            _keys_match(v, typing.get_args(hint)[0], f"{where}[{i}]")
    elif typing.get_origin(hint) is dict and typing.get_args(hint)[1] is not Any:
        for k, v in value.items():
            _keys_match(v, typing.get_args(hint)[1], f"{where}.{k}")


@pytest.mark.parametrize("kind", OUTPUTS, ids=[k.name for k in OUTPUTS])
def test_every_message_is_its_shape_and_validates_against_the_generated_schema(
    kind: OutputKind,
) -> None:
    rng = random.Random(kind.name)
    validator = jsonschema.Draft7Validator(SCHEMAS[kind.name])
    for seq in range(N):
        msg = dict(kind.encode(_item(kind, rng), _context(rng), vehicle_id="car1", seq=seq,
                               wall_time_unix_s=rng.choice([None, 1.7e9])))  # fmt: skip
        _keys_match(msg, MESSAGE_SHAPES[kind.name], kind.name)
        validator.validate(msg)
        assert msg["schema"] == f"guidance.{kind.name}/1" and msg["seq"] == seq


def test_the_schema_holds_what_the_shape_declares_beyond_types() -> None:
    """What the shape's ``doc`` and required keys add reaches the schema, and refuses."""
    rng = random.Random(1)
    state = dict(OUTPUTS[5].encode(_item(OUTPUTS[5], rng), _context(rng), vehicle_id="c", seq=0))
    assert OUTPUTS[5].name == "state"
    validator = jsonschema.Draft7Validator(SCHEMAS["state"])
    for bad in (
        {**state, "chance": 1.5},  # doc(maximum=1)
        {**state, "origin": {"lat_deg": 42.0}},  # the origin's required longitude
        {**state, "x_m": 1.0, "y_m": None},  # POINT_RULES: coordinates in pairs
        {k: v for k, v in state.items() if k != "seq"},  # the envelope's required keys
        {**state, "target": {"x_m": 1.0, "y_m": 2.0, "kind": "shop", "id": None}},  # enum
    ):
        assert not validator.is_valid(bad)
