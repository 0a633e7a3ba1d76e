"""Telemetry messages checked once, where the monitors fold them (``FleetView.apply``: the
live table, ``--json`` and the web page), against the published JSON Schemas
(one per row of the output table, ``guidance.outputs.kinds.OUTPUTS``)
and against limits no real message comes near: every number finite and at most 1e15 (a
distance at most 1e9 m), text at most 4096 characters, at most 20,000 values and 32 levels.

A message that fails is counted and shown as a bad message; nothing of it reaches a display,
so no ``ellipse`` given as a list, health ``inputs`` as a list or ``x_m`` of 10^400 can end
the monitor, and no NaN, infinity or 400-digit number is ever drawn. The state's schema also
says what the web page needs to draw a point: coordinates in pairs (``lat_deg`` only with
``lon_deg``, a goal's ``x_m`` only with its ``y_m``), an origin with both, in range; a state
the check passes is one the page can draw (tests/guidance/tools/test_web_page_states.py).

Each schema is compiled once into a plain predicate (``_compile``); jsonschema runs only on a
message the predicate refuses, to say why (or to find it valid after all).
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Mapping
from functools import cache
from typing import Any

from guidance.outputs.kinds import OUTPUTS

MAX_NUMBER = 1e15
"""Any number in a message (times, sequence numbers, counters)."""
MAX_DISTANCE_M = 1e9
"""A value whose key ends in ``_m`` (the estimator itself stays within 1e7 m)."""
MAX_TEXT = 4096
MAX_VALUES = 20_000
MAX_DEPTH = 32
PROBLEM_CHARS = 120
"""A problem's description is cut to this length (it may quote the message)."""

SCHEMAS: dict[str, dict[str, Any]] = {k.name: k.schema for k in OUTPUTS}


Check = Callable[[Any], bool]
_TYPES: dict[str, tuple[type, ...]] = {
    "object": (dict,),
    "array": (list,),
    "string": (str,),
    "boolean": (bool,),
    "null": (type(None),),
    "number": (int, float),
    "integer": (int,),
}
"""JSON types as the exact Python types ``json.loads`` makes (``type(True)`` is not ``int``)."""
_NOTES = frozenset(("$schema", "title", "description"))
_FAST_KEYWORDS = frozenset(("$schema", "title", "description", "type", "properties", "required",
                            "items", "enum", "minimum", "maximum", "additionalProperties",
                            "allOf", "if", "then"))  # fmt: skip


def _leaf(schema: Mapping[str, Any]) -> frozenset[type] | None:
    """A schema that only names types (``{"type": ["number", "null"]}``) as the set of them,
    tested inline by its parent; None for any other (``integer`` too: 2.0 is one)."""
    if set(schema) - _NOTES != {"type"}:
        return None
    names = [schema["type"]] if isinstance(schema["type"], str) else schema["type"]
    if "integer" in names and "number" not in names:
        return None
    return frozenset(t for n in names for t in _TYPES[n])


def _compile(schema: Mapping[str, Any]) -> Check:
    """``schema`` (the subset of draft 7 the output schemas use) as one predicate that says
    True only for an instance ``Draft7Validator(schema)`` finds valid (tests/guidance/tools/
    test_monitor_check.py compares them), 10 times faster than it (a state: 26 us, not 300):
    the monitor checks every message it folds, 10,000 a second for 1,000 cars. It may say
    False for a valid instance made of other types than ``json.loads`` makes (a dict
    subclass): the caller then asks jsonschema. A keyword outside the subset raises
    ``ValueError``."""
    unknown = set(schema) - _FAST_KEYWORDS
    if unknown or ("then" in schema) != ("if" in schema):
        raise ValueError(f"schema keywords outside the fast subset: {sorted(unknown)}")
    names = schema.get("type")
    names = [names] if isinstance(names, str) else names
    types = None if names is None else frozenset(t for n in names for t in _TYPES[n])
    integral_float = names is not None and "integer" in names and "number" not in names
    enum = list(schema["enum"]) if "enum" in schema else None
    low, high = schema.get("minimum"), schema.get("maximum")
    required = list(schema.get("required", ()))
    props = {k: _leaf(sub) or _compile(sub) for k, sub in schema.get("properties", {}).items()}
    extra = None
    if "additionalProperties" in schema:
        extra = _leaf(schema["additionalProperties"]) or _compile(schema["additionalProperties"])
    members = bool(props) or extra is not None
    items = _leaf(schema["items"]) or _compile(schema["items"]) if "items" in schema else None
    all_of = [_compile(sub) for sub in schema.get("allOf", ())]
    cond = _compile(schema["if"]) if "if" in schema else None
    then = _compile(schema["then"]) if "then" in schema else None

    def check(v: Any) -> bool:
        t = type(v)
        if (
            types is not None
            and t not in types
            and not (integral_float and t is float and v.is_integer())
        ):
            return False
        if enum is not None and not any(type(o) is t and o == v for o in enum):
            return False
        if t is int or t is float:
            if (low is not None and v < low) or (high is not None and v > high):
                return False
        elif t is dict:
            for name in required:
                if name not in v:
                    return False
            if members:
                for k, item in v.items():
                    c = props.get(k, extra)
                    if c is None:
                        continue
                    if type(c) is frozenset:  # a leaf: a type test, no call
                        if type(item) not in c:
                            return False
                    elif not c(item):  # type: ignore[operator]
                        return False
        elif t is list and items is not None:
            if type(items) is frozenset:
                for item in v:
                    if type(item) not in items:
                        return False
            else:
                for item in v:
                    if not items(item):  # type: ignore[operator]
                        return False
        for sub in all_of:
            if not sub(v):
                return False
        return cond is None or then is None or not cond(v) or then(v)

    return check


@cache
def _fast(kind: str) -> Check | None:
    """The kind's schema (as ``_validator`` checks it) compiled, or None outside the subset."""
    try:
        return _compile({k: v for k, v in SCHEMAS[kind].items() if k != "required"})
    except (ValueError, KeyError, TypeError):
        return None


@cache
def _validator(kind: str) -> Any:
    """The kind's schema without its ``required`` envelope (schema, vehicle_id, seq, t_s):
    the monitor shows what a message has; what it has must be of the published types."""
    from jsonschema import Draft7Validator

    schema = {k: v for k, v in SCHEMAS[kind].items() if k != "required"}
    return Draft7Validator(schema)


def _number_problem(key: str, value: int | float) -> str | None:
    if isinstance(value, float) and not math.isfinite(value):
        return f"{key or 'value'} is not a finite number"
    limit = MAX_DISTANCE_M if key.endswith("_m") else MAX_NUMBER
    if not -limit <= value <= limit:  # big ints compare exactly, no float conversion
        shown = f"{value:.3g}" if isinstance(value, float) else f"{len(str(abs(value)))} digits"
        return f"{_shown_key(key) if key else 'value'} out of range ({shown})"
    return None


_SAFE_KEY = re.compile(r"^[a-z][a-z0-9_]{0,40}$")


def _shown_key(key: str) -> str:
    """A field name fit to show: our own names are lower_snake; anything else (a hostile
    message's keys: "INF", escapes, markup) is not echoed."""
    return key if _SAFE_KEY.match(key) and key not in ("nan", "inf", "infinity") else "a field"


def _values_problem(message: Mapping[str, Any]) -> str | None:
    """The first number, text or size beyond the limits above, or None (iterative: a deep
    message cannot exhaust the stack)."""
    stack: list[tuple[str, Any, int]] = [("", message, 0)]
    seen = 0
    while stack:
        key, value, depth = stack.pop()
        seen += 1
        if seen > MAX_VALUES:
            return f"more than {MAX_VALUES} values"
        if depth > MAX_DEPTH:
            return f"nested deeper than {MAX_DEPTH} levels"
        if isinstance(value, bool) or value is None:
            continue
        if isinstance(value, int | float):
            why = _number_problem(key, value)
            if why is not None:
                return why
        elif isinstance(value, str):
            if len(value) > MAX_TEXT:
                return f"{_shown_key(key) if key else 'text'} longer than {MAX_TEXT} characters"
        elif isinstance(value, Mapping):
            for k, v in value.items():
                if len(str(k)) > MAX_TEXT:
                    return f"a key longer than {MAX_TEXT} characters"
                stack.append((str(k), v, depth + 1))
        elif isinstance(value, list | tuple):
            stack.extend((key, v, depth + 1) for v in value)
        else:
            return f"{_shown_key(key) if key else 'value'} is a {type(value).__name__}"
    return None


def _within(obj: dict[str, Any] | list[Any], key: str, depth: int, left: list[int]) -> bool:
    """True only if ``_values_problem`` finds nothing in ``obj`` (a ``dict`` or ``list`` at
    ``depth``; ``left[0]``: values still allowed): the same limits, tested inline on the exact
    types ``json.loads`` makes, with a call per container, not a stack entry per value (a
    state: 6 us, not 25). Anything else (a subclass, a key that is not text) is False: the
    walk above then says what is wrong, or that nothing is."""
    left[0] -= len(obj)
    if left[0] < 0 or (depth >= MAX_DEPTH and obj):
        return False
    if type(obj) is dict:
        pairs: Any = obj.items()
    else:
        pairs = ((key, v) for v in obj)
    for k, v in pairs:
        if type(k) is not str or len(k) > MAX_TEXT:
            return False
        t = type(v)
        if t is float or t is int:
            limit = MAX_DISTANCE_M if k.endswith("_m") else MAX_NUMBER
            if not -limit <= v <= limit:  # NaN fails too; big ints compare exactly
                return False
        elif t is str:
            if len(v) > MAX_TEXT:
                return False
        elif t is dict or t is list:
            if not _within(v, k, depth + 1, left):
                return False
        elif not (v is None or t is bool):
            return False
    return True


def message_problem(kind: str, message: Mapping[str, Any]) -> str | None:
    """Why a received message cannot be shown, in one short line, or None when it is good."""
    plain = type(message) is dict and _within(message, "", 0, [MAX_VALUES - 1])
    why = None if plain else _values_problem(message)
    if why is None and kind in SCHEMAS:
        fast = _fast(kind)
        if fast is not None and fast(message):
            return None  # valid: jsonschema below only to say why a message is not
        from jsonschema.exceptions import best_match

        error = best_match(_validator(kind).iter_errors(message))
        if error is not None:
            where = "/".join(_shown_key(str(p)) for p in error.absolute_path) or "message"
            # The schema's rule, never the value: a hostile value is not echoed to a display.
            if error.validator == "required":  # the names come from the schema
                missing = [k for k in error.validator_value if k not in error.instance]
                why = f"{where}: {', '.join(missing) or 'a field'} missing"
            else:
                expected = error.validator_value if error.validator == "type" else error.validator
                why = f"{where}: not {expected} (got {type(error.instance).__name__})"
    if why is None:
        return None
    text = " ".join(why.split())
    return text if len(text) <= PROBLEM_CHARS else text[: PROBLEM_CHARS - 3] + "..."
