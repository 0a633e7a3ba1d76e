"""TOML table checks of the app's config: the whole document, and ``_Table`` for the tables that do
not map 1:1 onto a dataclass (``[start]``/``[goal]`` with lat/lon or x/y, ``[navigation]``,
``[estimator]``, a device's own keys). The tables that do are read by
``guidance.config_tables.from_table``; both use its error format."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from guidance.config_tables import BARE_KEY, key_name
from guidance.errors import UserError

# ----------------------------------------------------------------------------- value checks


def _check_document(
    node: object, table: tuple[str, ...] = (), key: tuple[str | int, ...] = ()
) -> None:
    """Checks of the whole document, also where no other check reads (``[sim]``, a disabled
    device): NaN and infinities are rejected (``[goal] lat_deg must be finite, not nan``), as
    are integers beyond 64 bits (TOML's limit; tomllib reads any size) and keys no table has
    (every key here is a bare word; the message stays one line)."""
    huge = isinstance(node, int) and not -(2**63) <= node < 2**63  # TOML: 64-bit integers
    if huge or (isinstance(node, float) and not math.isfinite(node)):
        where = key_name(key[0]) + "".join(f"[{i}]" for i in key[1:])
        if table:
            where = f"[{'.'.join(key_name(t) for t in table)}] {where}"
        if huge:
            raise UserError(f"{where} is out of range (TOML integers are 64-bit)")
        raise UserError(f"{where} must be finite, not {node!r}")
    if isinstance(node, Mapping):
        inner = (*table, *(str(k) for k in key))
        for k in node:
            if not (isinstance(k, str) and BARE_KEY.fullmatch(k)):
                if not inner:
                    raise UserError(f"unknown table(s): [{key_name(k)}]")
                raise UserError(f"[{'.'.join(map(key_name, inner))}] unknown key(s): {key_name(k)}")
        for k, v in node.items():
            _check_document(v, inner, (k,))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            _check_document(v, table, (*key, i))


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
            raise UserError(f"[{self.name}] unknown key(s): {', '.join(map(key_name, unknown))}")
