"""One loader for the config's TOML tables: a table into a dataclass, typed by the dataclass itself.

``from_table(TelemetryConfig, table, "telemetry", base_dir)`` reads each field of the dataclass
from the key of the same name, checks the value against the field's type hint
(``typing.get_type_hints``: bool, int, float, str, ``Path``, ``Optional``, unions, ``Literal``,
enums, ``tuple[X, ...]``, ``tuple[X, Y]``, lists, tables and nested dataclasses) and builds the
dataclass, so its ``__post_init__`` checks run too. A missing key keeps the field's default.

Every problem is one ``UserError`` line in one format, naming the table and the key and saying
what was expected: ``[telemetry] fifo_size must be an integer, not '32'``,
``[telemetry.tls] root_ca_certificate is required``, ``[recording] unknown key(s): dir (known:
...)``. A bool is never an integer or a number (TOML's ``true`` is not 1); an integer is a
number. The config file's own name is added once, by ``guidance.app.config.load_config``.

What a type does not say is a ``Rule``, written once in the field's metadata next to its
default (``field(default=1.0, metadata=rule(positive=True))``) or, for a dataclass this module
may not annotate, in ``from_table(..., rules={"name": Rule(...)})``: a range, a set of choices,
a path (a relative one is taken from ``base_dir``, the config file's folder; a default is left
as it is), the most items a list or table may hold, ``read=False`` for a field the program sets
(not offered in the config file, but recorded), ``degrees`` for an angle the file gives in
degrees, and ``table``/``key`` for a field of a dataclass that the config file spreads over
its tables (``PipelineConfig.units`` is ``[navigation] units``).

The same rules read the config file, the recording's session record and the checkpoint's
identity: ``from_table(..., record=True)`` reads every field by its own name (``read=False``
ones included) and holds a number no rule bounds to ``RECORD_MAX`` (a file from outside).

Pure data validation: no I/O, nothing imported from the app, so ``guidance.app``,
``guidance.telemetry``, ``guidance.recording`` and ``hal_sim`` all share it (docs/layout.md).
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import math
import re
import types
import typing
from collections.abc import Collection, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, TypeVar

from guidance.errors import UserError

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

T = TypeVar("T", bound="DataclassInstance")

RULE = "guidance.config_tables.rule"
"""The key of a ``Rule`` in a dataclass field's metadata."""


@dataclass(frozen=True, slots=True)
class Rule:
    """How a field is read beyond its type."""

    lo: float | None = None
    hi: float | None = None
    positive: bool = False
    """> 0."""
    choices: tuple[object, ...] = ()
    path: bool = False
    """A file or folder name: a relative one is taken from the config file's folder."""
    read: bool = True
    """False: not a key of the config file (the program sets it, e.g. ``origin_lat_lon_deg``,
    or keeps it fixed); a record (``record=True``) still carries and reads it."""
    max_items: int | None = None
    """A list or table of at most this many items (None: ``RECORD_MAX_ITEMS`` in a record)."""
    degrees: bool = False
    """An angle in radians (``<stem>_rad``) that the config file gives in degrees
    (``<stem>_deg``)."""
    table: str = ""
    """For a dataclass spread over the config file's tables: the table offering this field."""
    key: str = ""
    """Its key there, when not the field's name (``[compass] unusable_after_s``)."""
    group: str = ""
    """A set of fields that belong together (the estimator's ``car`` model)."""


def rule(
    *,
    lo: float | None = None,
    hi: float | None = None,
    positive: bool = False,
    choices: tuple[object, ...] = (),
    path: bool = False,
    read: bool = True,
    max_items: int | None = None,
    degrees: bool = False,
    table: str = "",
    key: str = "",
    group: str = "",
) -> dict[str, Rule]:
    """Field metadata for ``from_table``: ``field(default=0.5, metadata=rule(lo=0, hi=1))``."""
    r = Rule(lo, hi, positive, tuple(choices), path, read, max_items, degrees, table, key, group)
    return {RULE: r}


def rule_of(cls: type, name: str) -> Rule:
    """The ``Rule`` of ``cls``'s field ``name`` (a field with none: no rule)."""
    f = next(f for f in dataclasses.fields(cls) if f.name == name)
    r: Rule = f.metadata.get(RULE, Rule())
    return r


def like(cls: type, name: str, **changes: Any) -> dict[str, Rule]:
    """Field metadata with the rule of ``cls``'s field ``name`` (``changes`` applied): a
    table that offers the same setting under its own dataclass reads it by the same rule
    (``[vehicle] track_m`` is ``EstimatorConfig.track_m``)."""
    return {RULE: dataclasses.replace(rule_of(cls, name), **changes)}


def file_keys(cls: type, part: str | None = None) -> tuple[str, ...]:
    """The keys the config file offers for ``cls`` (with ``part``: those in that table)."""
    return tuple(
        file_key(f.name, r)
        for f in dataclasses.fields(cls)
        if (r := rule_of(cls, f.name)).read and (part is None or r.table == part)
    )


def names_where(cls: type, **match: object) -> tuple[str, ...]:
    """``cls``'s field names whose rule matches, e.g. ``names_where(EstimatorConfig,
    group="car")`` or ``names_where(PipelineConfig, table="compass")``."""
    return tuple(
        f.name
        for f in dataclasses.fields(cls)
        if all(getattr(rule_of(cls, f.name), k) == v for k, v in match.items())
    )


def file_key(name: str, r: Rule) -> str:
    """The key the config file gives a field by: ``key``, ``<stem>_deg`` or its name."""
    if r.key:
        return r.key
    if r.degrees:
        return name.removesuffix("_rad") + "_deg"
    return name


RECORD_MAX = 1e9
"""A record's number that no rule bounds is at most this large (a session record or a
checkpoint is a file from outside: 1e308 is damage, not a setting)."""
RECORD_MAX_ITEMS = 64
"""A record's list or table that no rule sizes holds at most this many items."""


BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")


def key_name(key: object) -> str:
    """A key as a message shows it: bare, or quoted when it has odd characters (one line)."""
    return key if isinstance(key, str) and BARE_KEY.fullmatch(key) else repr(key)


def _show(value: object) -> str:
    """A value in a message: its repr, cut short (a message stays one short line)."""
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def prefixed(where: str, message: str) -> str:
    """``[where] message``, unless the message already names the table."""
    return message if message.startswith(f"[{where}") else f"[{where}] {message}"


# ----------------------------------------------------------------------------- the loader


@dataclass(frozen=True, slots=True)
class _Field:
    name: str
    hint: Any
    rule: Rule
    required: bool


@functools.cache
def _fields(cls: type) -> tuple[_Field, ...]:
    hints = typing.get_type_hints(cls)
    return tuple(
        _Field(
            f.name,
            hints[f.name],
            f.metadata.get(RULE, Rule()),
            f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING,
        )
        for f in dataclasses.fields(cls)
        if f.init
    )


def from_table(
    cls: type[T],
    table: object,
    where: str,
    base_dir: Path | None = None,
    *,
    rules: Mapping[str, Rule] | None = None,
    base: T | None = None,
    record: bool = False,
    part: str | None = None,
    others: Collection[str] = (),
) -> T:
    """The dataclass ``cls`` read from the TOML table ``[where]``; ``UserError`` names the key.

    ``base_dir`` is the config file's folder (relative paths are taken from it; None: left
    as they are). ``rules`` overrides the fields' own ``Rule`` by field name. ``base``: start
    from this instance instead of the defaults (``dataclasses.replace``), e.g. options that
    the command line already set. ``record``: a record the program wrote (every field by its
    own name, numbers within ``RECORD_MAX``). ``part``: read only the fields whose rule names
    this table (the rest keep ``base``'s values). ``others``: keys of this table that another
    reader takes (listed as known, not read here).
    """
    if not isinstance(table, Mapping):
        raise UserError(f"[{where}] must be a table, not {_show(table)}")
    fields = _fields(cls)
    if rules:
        names = {f.name for f in fields}
        if not set(rules) <= names:
            raise TypeError(f"rules for no field of {cls.__name__}: {set(rules) - names}")
        fields = tuple(dataclasses.replace(f, rule=rules.get(f.name, f.rule)) for f in fields)
    if part is not None:
        fields = tuple(f for f in fields if f.rule.table == part)
    keys = {
        f.name: f.name if record else file_key(f.name, f.rule)
        for f in fields
        if record or f.rule.read
    }
    known = sorted({*keys.values(), *others})
    unknown = sorted((k for k in table if k not in known), key=str)
    if unknown:
        raise UserError(
            f"[{where}] unknown key(s): {', '.join(map(key_name, unknown))} "
            f"(known: {', '.join(known)})"
        )
    kwargs: dict[str, Any] = {}
    for f in fields:
        k = keys.get(f.name)
        if k is not None and k in table:
            value = _read(table[k], f.hint, f.rule, where, k, base_dir, record)
            if f.rule.degrees and not record and value is not None:
                value = math.radians(value)
            kwargs[f.name] = value
        elif f.required and k is not None and base is None:
            raise UserError(f"[{where}] {k} is required")
    try:
        return cls(**kwargs) if base is None else dataclasses.replace(base, **kwargs)
    except (UserError, TypeError, ValueError) as exc:  # the dataclass's own checks
        raise UserError(prefixed(where, str(exc))) from None


def _read(
    value: Any, hint: Any, r: Rule, where: str, key: str, base_dir: Path | None, record: bool
) -> Any:
    """``value`` as the type ``hint`` says, then checked against the rule ``r`` (and, in a
    record, against ``RECORD_MAX``/``RECORD_MAX_ITEMS`` where the rule says nothing)."""

    def wrong() -> UserError:
        return UserError(f"[{where}] {key} must be {expected(hint)}, not {_show(value)}")

    origin = typing.get_origin(hint)
    if hint is Any or hint is object:
        return value
    if origin is typing.Union or origin is types.UnionType:
        arms = [a for a in typing.get_args(hint) if a is not type(None)]
        if value is None and len(arms) < len(typing.get_args(hint)):
            return None
        if len(arms) == 1:  # Optional[X]: X's own message (a nested table names its key)
            return _read(value, arms[0], r, where, key, base_dir, record)
        for arm in arms:
            try:
                return _read(value, arm, r, where, key, base_dir, record)
            except UserError:
                continue
        raise wrong()
    if hint is list or hint is tuple:
        hint = list[Any] if hint is list else tuple[Any, ...]
        origin = typing.get_origin(hint)
    if origin is tuple or origin is list:
        args = typing.get_args(hint)
        variable = origin is list or (len(args) == 2 and args[1] is Ellipsis)
        if variable and args[0] is str and isinstance(value, str):
            value = [value]  # one string: a list of one
        if not isinstance(value, list | tuple) or (not variable and len(value) != len(args)):
            raise wrong()
        _count(value, r, where, key, record)
        item_hints = [args[0]] * len(value) if variable else list(args)
        items = [
            _read(v, h, r, where, f"{key}[{i}]", base_dir, record)
            for i, (v, h) in enumerate(zip(value, item_hints, strict=True))
        ]
        return tuple(items) if origin is tuple else items
    if origin in (dict, Mapping) or hint in (dict, Mapping):
        if not isinstance(value, Mapping):
            raise wrong()
        _count(value, r, where, key, record)
        args = typing.get_args(hint)
        if len(args) != 2:
            return dict(value)
        return {
            k: _read(v, args[1], r, where, f"{key}.{key_name(k)}", base_dir, record)
            for k, v in value.items()
        }
    if origin is Literal:
        if not any(type(value) is type(c) and value == c for c in typing.get_args(hint)):
            raise wrong()
        return value
    if isinstance(hint, type) and dataclasses.is_dataclass(hint):
        return from_table(hint, value, f"{where}.{key}", base_dir, record=record)
    if isinstance(hint, type) and issubclass(hint, enum.Enum):
        for member in hint:
            if type(value) is type(member.value) and value == member.value:
                return _check(member, r, where, key)
        raise wrong()
    if hint is bool:
        if not isinstance(value, bool):
            raise wrong()
    elif hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise wrong()
        if not -(2**63) <= value < 2**63:
            raise UserError(f"[{where}] {key} must be a 64-bit integer, not {_show(value)}")
    elif hint is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise wrong()
        try:
            value = float(value)
        except OverflowError:
            value = math.inf
        if not math.isfinite(value):
            raise UserError(f"[{where}] {key} must be finite, not {value!r}")
        bounded = r.lo is not None or r.hi is not None
        if record and not bounded and abs(value) > RECORD_MAX:
            raise UserError(f"[{where}] {key} must be within +-{RECORD_MAX:g}, not {value!r}")
    elif hint is str or hint is Path:
        if not isinstance(value, str):
            raise wrong()
        relative = bool(value) and not Path(value).is_absolute()
        if (r.path or hint is Path) and relative and base_dir is not None:
            value = str(base_dir / value)
        if hint is Path:
            value = Path(value)
    # Other types: as given; the dataclass checks them.
    return _check(value, r, where, key)


def _count(value: Any, r: Rule, where: str, key: str, record: bool) -> None:
    """A list or table within the rule's size (in a record, ``RECORD_MAX_ITEMS`` by default),
    checked before its items are read."""
    cap = r.max_items if r.max_items is not None else RECORD_MAX_ITEMS if record else None
    if cap is not None and len(value) > cap:
        raise UserError(f"[{where}] {key} must hold at most {cap} items, not {len(value)}")


def _check(value: Any, r: Rule, where: str, key: str) -> Any:
    """The rule's choices and range."""
    at = f"[{where}] {key}"
    if r.choices and value not in r.choices:
        names = ", ".join(str(c) for c in r.choices)
        raise UserError(f"{at} must be one of {names}, not {_show(value)}")
    if isinstance(value, int | float) and not isinstance(value, bool):
        if r.positive and not value > 0:
            raise UserError(f"{at} must be > 0, not {value!r}")
        lo, hi = r.lo, r.hi
        if lo is not None and hi is not None and not lo <= value <= hi:
            raise UserError(f"{at} must be within [{lo}, {hi}], not {value!r}")
        if lo is not None and hi is None and not value >= lo:
            raise UserError(f"{at} must be >= {lo}, not {value!r}")
        if hi is not None and lo is None and not value <= hi:
            raise UserError(f"{at} must be <= {hi}, not {value!r}")
    return value


def field_default(cls: type, name: str) -> Any:
    """The default of ``cls``'s field ``name``, where it is written (so another table that
    offers the same setting does not write it again)."""
    f = next(f for f in dataclasses.fields(cls) if f.name == name)
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    if f.default is dataclasses.MISSING:
        raise TypeError(f"{cls.__name__}.{name} has no default")
    return f.default


def plain(obj: Any) -> Any:
    """A dataclass as the plain data ``from_table`` reads back: nested dataclasses as tables,
    enums as their values, tuples as lists (``from_table(type(x), plain(x), ...) == x``)."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: plain(getattr(obj, f.name)) for f in dataclasses.fields(obj) if f.init}
    if isinstance(obj, enum.Enum):
        return obj.value
    if isinstance(obj, Mapping):
        return {str(k): plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [plain(v) for v in obj]
    return obj


# ----------------------------------------------------------------------------- messages

_NAMES: dict[object, tuple[str, str]] = {
    bool: ("true or false", "true/false values"),
    int: ("an integer", "integers"),
    float: ("a number", "numbers"),
    str: ("a string", "strings"),
    Path: ("a path (a string)", "paths"),
}


def expected(hint: Any) -> str:
    """What a value of the type ``hint`` is, in a message's words (``a list of numbers``)."""
    if hint is list or hint is tuple:
        hint = list[Any]
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if hint in _NAMES:
        return _NAMES[hint][0]
    if origin is typing.Union or origin is types.UnionType:
        return " or ".join(expected(a) for a in args if a is not type(None))
    if origin is list or (origin is tuple and len(args) == 2 and args[1] is Ellipsis):
        item = args[0]
        many = _NAMES[item][1] if item in _NAMES else f"{expected(item)} values"
        if item is Any:
            many = "values"
        extra = " (or one string)" if item is str else ""
        return f"a list of {many}{extra}"
    if origin is tuple:
        if len(set(args)) == 1 and args[0] in _NAMES:
            return f"a list of {len(args)} {_NAMES[args[0]][1]}"
        return f"a list [{', '.join(expected(a) for a in args)}]"
    if origin is Literal:
        return "one of " + ", ".join(str(a) for a in args)
    if isinstance(hint, type) and issubclass(hint, enum.Enum):
        return "one of " + ", ".join(str(m.value) for m in hint)
    if origin in (dict, Mapping) or hint in (dict, Mapping):
        return "a table"
    if isinstance(hint, type) and dataclasses.is_dataclass(hint):
        return "a table"
    return getattr(hint, "__name__", str(hint))
