"""DBC files from ``opendbc`` (MIT), the library openpilot's car list is built on.

opendbc's wheel ships 58 plain DBC files and the sources of its generated ones (the
``*_generated`` files are concatenations its generator makes: ``generate_all`` returns them in
memory, 15 ms). Nothing is vendored here and nothing is downloaded: the text comes from the
installed package.

cantools (the one library that knows bit layouts here, ``drivers.can_decode``) refuses 31 of
those 94 files as they are, for constructs that say nothing about bit layouts: comments on
signals with no name, value tables of signals that do not exist, numbers written ``.25``, ids
above 11 bits not marked extended, names that start with a digit. ``cantools_text`` removes
comments, value tables and attributes (this project decodes raw numbers; it never shows a
value's name) and mends the rest, and then cantools loads 93 of 94
(``toyota_2017_ref_pt``, a reference file no car uses, has ids above 29 bits).
"""

from __future__ import annotations

import functools
import re
from importlib import resources
from typing import Any

from guidance.errors import UserError

_BO = re.compile(r"^BO_ (\d+) (\w+)(.*)$")
_SG_DIGIT = re.compile(r"^(\s*SG_ )(\d\w*)(.*)$")
_BARE_DECIMAL = re.compile(r"(?<=[(,\[|])(-?)\.(\d)")
_DROPPED = ("CM_", "VAL_ ", "BA_ ", "VAL_TABLE_")


@functools.cache
def _generated() -> dict[str, str]:
    from opendbc.dbc.generator.generator import generate_all

    return dict(generate_all())


def dbc_names() -> tuple[str, ...]:
    """Every DBC opendbc has, generated or plain (names without ``.dbc``)."""
    plain = [
        f.name[:-4] for f in resources.files("opendbc.dbc").iterdir() if f.name.endswith(".dbc")
    ]
    return tuple(sorted({*plain, *_generated()}))


@functools.cache
def dbc_text(name: str) -> str:
    """The DBC's text as opendbc has it; an unknown name is a ``UserError``."""
    name = name.removesuffix(".dbc")
    generated = _generated()
    if name in generated:
        return generated[name]
    path = resources.files("opendbc.dbc") / f"{name}.dbc"
    if not path.is_file():
        raise UserError(f"opendbc has no DBC named {name!r}")
    return path.read_text(encoding="utf-8")


def cantools_text(text: str) -> str:
    """``text`` as cantools loads it (see the module): comments, value tables and attributes
    removed; ``.25`` written ``0.25``; ids above 11 bits marked extended; names that start
    with a digit prefixed. Bit layouts, scales and offsets are unchanged."""
    out: list[str] = []
    open_quote = False
    for line in text.splitlines():
        stripped = line.strip()
        if open_quote:  # inside a dropped statement whose string spans lines
            open_quote = stripped.count('"') % 2 == 0
            continue
        if stripped.startswith(_DROPPED):
            open_quote = stripped.count('"') % 2 == 1
            continue
        m = _BO.match(stripped)
        if m:
            fid, name = int(m.group(1)), m.group(2)
            if 0x7FF < fid < 0x80000000:
                fid |= 0x80000000  # cantools' mark of an extended id
            line = f"BO_ {fid} {'M_' + name if name[0].isdigit() else name}{m.group(3)}"
        m = _SG_DIGIT.match(line)
        if m:
            line = f"{m.group(1)}S_{m.group(2)}{m.group(3)}"
        out.append(_BARE_DECIMAL.sub(r"\g<1>0.\2", line))
    return "\n".join(out) + "\n"


@functools.cache
def load_dbc(name: str) -> Any:
    """The opendbc DBC ``name`` loaded by cantools (once per process), non-strict as some
    files need (overlapping signals in messages no profile reads)."""
    import cantools

    try:
        return cantools.database.load_string(
            cantools_text(dbc_text(name)), database_format="dbc", strict=False
        )
    except UserError:
        raise
    except Exception as exc:
        raise UserError(f"opendbc DBC {name!r} does not load: {exc}") from None


@functools.cache
def message_lengths(name: str) -> dict[int, int]:
    """Frame id -> length in bytes of every message of the DBC, read from its ``BO_`` lines
    (no cantools: fast enough to compare a log with every profile)."""
    out: dict[int, int] = {}
    for line in dbc_text(name).splitlines():
        parts = line.split()
        if len(parts) >= 4 and parts[0] == "BO_" and parts[1].isdigit():
            try:
                out[int(parts[1]) & 0x1FFFFFFF] = int(parts[3])
            except ValueError:
                continue
    return out


@functools.cache
def opendbc_platforms() -> dict[str, tuple[tuple[str, str], ...]]:
    """DBC name -> the opendbc car platforms whose powertrain (or Tesla's "party") bus it
    describes, as (brand, platform) pairs. Imports opendbc's car values (0.3 s)."""
    from opendbc.car.values import PLATFORMS

    out: dict[str, list[tuple[str, str]]] = {}
    for platform_name, platform in PLATFORMS.items():
        brand = type(platform).__module__.split(".")[2]  # opendbc.car.<brand>.values
        for bus, dbc in platform.config.dbc_dict.items():
            if str(getattr(bus, "name", bus)) in ("pt", "party"):
                out.setdefault(dbc, []).append((brand, str(platform_name)))
    return {k: tuple(v) for k, v in out.items()}
