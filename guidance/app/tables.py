"""TOML table checking: one error format for every key, type and range of the config."""

from __future__ import annotations

import contextlib
import math
import re
from collections.abc import Iterator, Mapping
from typing import Any

from guidance.errors import UserError

"""Device kind -> backend name -> (``module:Class``, ``module:ConfigClass``)."""


# ----------------------------------------------------------------------------- value checks

_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")


def _name(key: object) -> str:
    """A key as a message shows it: bare, or quoted when it has odd characters (one line)."""
    return key if isinstance(key, str) and _BARE_KEY.fullmatch(key) else repr(key)


def _check_document(
    node: object, table: tuple[str, ...] = (), key: tuple[str | int, ...] = ()
) -> None:
    """Checks of the whole document, also where no other check reads (``[sim]``, a disabled
    device): NaN and infinities are rejected (``[goal] lat_deg must be finite, not nan``), as
    are integers beyond 64 bits (TOML's limit; tomllib reads any size) and keys no table has
    (every key here is a bare word; the message stays one line)."""
    huge = isinstance(node, int) and not -(2**63) <= node < 2**63  # TOML: 64-bit integers
    if huge or (isinstance(node, float) and not math.isfinite(node)):
        where = _name(key[0]) + "".join(f"[{i}]" for i in key[1:])
        if table:
            where = f"[{'.'.join(_name(t) for t in table)}] {where}"
        if huge:
            raise UserError(f"{where} is out of range (TOML integers are 64-bit)")
        raise UserError(f"{where} must be finite, not {node!r}")
    if isinstance(node, Mapping):
        inner = (*table, *(str(k) for k in key))
        for k in node:
            if not (isinstance(k, str) and _BARE_KEY.fullmatch(k)):
                if not inner:
                    raise UserError(f"unknown table(s): [{_name(k)}]")
                raise UserError(f"[{'.'.join(map(_name, inner))}] unknown key(s): {_name(k)}")
        for k, v in node.items():
            _check_document(v, inner, (k,))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            _check_document(v, table, (*key, i))


@contextlib.contextmanager
def _in_table(name: str) -> Iterator[None]:
    """A ``UserError`` from a table's own parser names the table (``[telemetry] bad zenoh
    endpoint ''``)."""
    try:
        yield
    except UserError as exc:
        if str(exc).startswith(f"[{name}"):
            raise
        raise UserError(f"[{name}] {exc}") from None


def _table(name: str, data: object) -> dict[str, Any]:
    """A table handed on whole (``[telemetry]``, ``[recording]``), as a new dict."""
    if not isinstance(data, Mapping):
        raise UserError(f"[{name}] must be a table")
    return dict(data)


class _Table:
    """A TOML table being read: typed getters that name the key, and leftover-key detection."""

    def __init__(self, name: str, data: object) -> None:
        if not isinstance(data, Mapping):
            raise UserError(f"[{name}] must be a table")
        self.name = name
        self.data = dict(data)
        self.used: set[str] = set()

    def key(self, key: str) -> str:
        return f"[{self.name}] {key}"

    def has(self, key: str) -> bool:
        return key in self.data

    def get(self, key: str, default: Any = None) -> Any:
        self.used.add(key)
        return self.data.get(key, default)

    def number(
        self,
        key: str,
        default: float | None = None,
        *,
        lo: float | None = None,
        hi: float | None = None,
        positive: bool = False,
    ) -> float | None:
        value = self.get(key, default)
        if value is None:
            return None
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise UserError(f"{self.key(key)} must be a number, not {value!r}")
        v = float(value)
        if not math.isfinite(v):
            raise UserError(f"{self.key(key)} must be finite, not {value!r}")
        if positive and v <= 0:
            raise UserError(f"{self.key(key)} must be > 0, not {value!r}")
        if (lo is not None and v < lo) or (hi is not None and v > hi):
            raise UserError(f"{self.key(key)} must be within [{lo}, {hi}], not {value!r}")
        return v

    def req_number(self, key: str, **kw: Any) -> float:
        if key not in self.data:
            raise UserError(f"{self.key(key)} is required")
        v = self.number(key, **kw)
        assert v is not None
        return v

    def string(self, key: str, default: str | None = None, choices: tuple[str, ...] = ()) -> str:
        value = self.get(key, default)
        if not isinstance(value, str):
            raise UserError(f"{self.key(key)} must be a string, not {value!r}")
        if choices and value not in choices:
            raise UserError(f"{self.key(key)} must be one of {', '.join(choices)}, not {value!r}")
        return value

    def boolean(self, key: str, default: bool) -> bool:
        value = self.get(key, default)
        if not isinstance(value, bool):
            raise UserError(f"{self.key(key)} must be true or false, not {value!r}")
        return value

    def done(self) -> None:
        unknown = sorted(set(self.data) - self.used)
        if unknown:
            raise UserError(f"[{self.name}] unknown key(s): {', '.join(map(_name, unknown))}")


def _check_type(value: Any, annotation: str, where: str) -> Any:
    """Check a TOML value against a driver config field's annotation (simple types only)."""
    parts = [p.strip() for p in annotation.split("|")]
    ok_types: list[type] = []
    for p in parts:
        if p == "None":
            if value is None:
                return value
        elif p == "bool":
            ok_types.append(bool)
        elif p == "int":
            ok_types.append(int)
        elif p == "float":
            ok_types.append(float)
        elif p == "str":
            ok_types.append(str)
        else:
            return value  # mappings and others: the driver validates them
    if isinstance(value, bool) and bool not in ok_types:
        raise UserError(f"{where} must be {annotation}, not {value!r}")
    if isinstance(value, int) and not isinstance(value, bool) and float in ok_types:
        return value if int in ok_types else float(value)
    if not isinstance(value, tuple(ok_types)):
        raise UserError(f"{where} must be {annotation}, not {value!r}")
    return value
