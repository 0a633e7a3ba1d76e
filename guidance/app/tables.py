"""The checks of the app's whole TOML document, before its tables are read (each table is read
into a dataclass by ``guidance.config_tables.from_table``, in the same error format)."""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping
from typing import Any

from guidance.config_tables import BARE_KEY, key_name
from guidance.errors import UserError

# ----------------------------------------------------------------------------- value checks


def check_document(data: Mapping[str, Any], tables: Collection[str]) -> None:
    """The document's values (``_check_values``), then its tables: only ``tables`` known."""
    _check_values(data)
    unknown = sorted(set(data) - set(tables))
    if unknown:
        raise UserError(f"unknown table(s): {', '.join(f'[{key_name(u)}]' for u in unknown)}")


def _check_values(
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
            _check_values(v, inner, (k,))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            _check_values(v, table, (*key, i))
