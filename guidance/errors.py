"""Exceptions shared by the packages, and the one check of a number from outside."""

from __future__ import annotations

import math
import re
from collections.abc import Callable


class UserError(Exception):
    """A problem the user can fix (bad file, bad value, missing device): printed as one line."""


_DECIMAL = re.compile(r"[-+]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][-+]?[0-9]+)?")


def number(text: str) -> float:
    """A command-line number (``argparse`` ``type=number``): plain ASCII decimal, finite.
    ``float`` alone takes "nan", "inf", "1e999", "6_00" and Arabic-Indic digits; each of those
    is refused here (argparse says "invalid number value: 'nan'")."""
    t = text.strip()
    if not _DECIMAL.fullmatch(t):
        raise ValueError(text)
    value = float(t)
    if not math.isfinite(value):
        raise ValueError(text)
    return value


def number_in(lo: float, hi: float) -> Callable[[str], float]:
    """``number`` within ``[lo, hi]`` (``--facing`` in degrees: 1e308 is no heading)."""

    def check(text: str) -> float:
        value = number(text)
        if not lo <= value <= hi:
            raise ValueError(text)
        return value

    check.__name__ = f"number in [{lo:g}, {hi:g}]"  # what argparse names in its message
    return check


def _shown(value: object) -> str:
    """A value in a message: its repr, cut short (a message stays one short line)."""
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def checked_number(
    value: object,
    where: str,
    lo: float = -math.inf,
    hi: float = math.inf,
    *,
    lo_open: bool = False,
    error: Callable[[str], Exception] = UserError,
) -> float:
    """The one check of "a finite number within bounds" for values from outside (a session
    record, a checkpoint, a simulator option, a landmark row, a recorded input): ``value`` as a
    float, or ``error`` with one line in one format: ``WHERE must be a number, not 'x'`` /
    ``WHERE must be a finite number >= 0 and <= 1, not nan``. Only numbers pass (a bool is not
    one); an integer too large for a float is out of range, not an overflow."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise error(f"{where} must be a number, not {_shown(value)}")
    try:
        f = float(value)
    except OverflowError:
        f = math.inf if value > 0 else -math.inf
    if math.isfinite(f) and (lo < f if lo_open else lo <= f) and f <= hi:
        return f
    bounds = [f"> {lo:g}" if lo_open else f">= {lo:g}"] if lo > -math.inf else []
    bounds += [f"<= {hi:g}"] if hi < math.inf else []
    within = f" {' and '.join(bounds)}" if bounds else ""
    raise error(f"{where} must be a finite number{within}, not {_shown(value)}")
