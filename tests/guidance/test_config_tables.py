"""``guidance.config_tables.from_table``: one loader for every TOML table that maps onto a
dataclass, typed by the dataclass's own hints, with one error format (docs/app.md,
"Configuration")."""

from __future__ import annotations

import enum
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import pytest

from guidance.config_tables import Rule, expected, from_table, rule
from guidance.errors import UserError


class Colour(enum.Enum):
    RED = "red"
    BLUE = "blue"


@dataclass(frozen=True)
class Inner:
    name: str
    weight_kg: float = 1.0


@dataclass(frozen=True)
class Outer:
    count: int = 3
    ratio: float = 0.5
    on: bool = False
    label: str = "x"
    size_m: tuple[float, float] = (1.0, 2.0)
    names: tuple[str, ...] = ()
    limit: int | None = None
    source: int | str = 0
    kind: Literal["a", "b"] = "a"
    colour: Colour = Colour.RED
    options: Mapping[str, Any] = field(default_factory=dict)
    inner: Inner | None = None
    log: str = field(default="", metadata=rule(path=True))
    folder: Path = Path("default")
    rate_hz: float = field(default=1.0, metadata=rule(positive=True))
    fraction: float = field(default=0.5, metadata=rule(lo=0, hi=1))
    mode: str = field(default="peer", metadata=rule(choices=("peer", "client")))
    origin: tuple[float, float] | None = field(default=None, metadata=rule(read=False))

    def __post_init__(self) -> None:
        if self.count == 13:
            raise UserError("count 13 is unlucky")
        if self.count == 14:
            raise ValueError("count 14 is not allowed either")


def _error(table: object, cls: type = Outer, where: str = "t", **kw: Any) -> str:
    with pytest.raises(UserError) as info:
        from_table(cls, table, where, **kw)
    message = str(info.value)
    assert "\n" not in message
    return message


def test_an_empty_table_is_the_defaults() -> None:
    assert from_table(Outer, {}, "t") == Outer()


def test_every_type_is_read() -> None:
    cfg = from_table(
        Outer,
        {
            "count": 7,
            "ratio": 2,  # an integer is a number
            "on": True,
            "label": "y",
            "size_m": [3, 4.5],
            "names": ["a", "b"],
            "limit": 10,
            "source": "video.mp4",
            "kind": "b",
            "colour": "blue",
            "options": {"fd": True},
            "inner": {"name": "n", "weight_kg": 2},
            "mode": "client",
        },
        "t",
    )
    assert cfg.count == 7 and cfg.ratio == 2.0 and isinstance(cfg.ratio, float)
    assert cfg.on is True and cfg.label == "y" and cfg.limit == 10
    assert cfg.size_m == (3.0, 4.5) and all(isinstance(v, float) for v in cfg.size_m)
    assert cfg.names == ("a", "b") and cfg.source == "video.mp4" and cfg.kind == "b"
    assert cfg.colour is Colour.BLUE and cfg.options == {"fd": True}
    assert cfg.inner == Inner("n", 2.0) and cfg.mode == "client"


@pytest.mark.parametrize(
    ("table", "message"),
    [
        ({"count": "3"}, "[t] count must be an integer, not '3'"),
        ({"count": 2.5}, "[t] count must be an integer, not 2.5"),
        ({"ratio": "half"}, "[t] ratio must be a number, not 'half'"),
        ({"on": 1}, "[t] on must be true or false, not 1"),
        ({"label": 5}, "[t] label must be a string, not 5"),
        ({"limit": "none"}, "[t] limit must be an integer, not 'none'"),
        ({"source": 1.5}, "[t] source must be an integer or a string, not 1.5"),
        ({"kind": "c"}, "[t] kind must be one of a, b, not 'c'"),
        ({"colour": "green"}, "[t] colour must be one of red, blue, not 'green'"),
        ({"options": [1]}, "[t] options must be a table, not [1]"),
        ({"names": "a", "label": []}, "[t] label must be a string, not []"),
        ({"names": ["a", 2]}, "[t] names[1] must be a string, not 2"),
        ({"ratio": math.nan}, "[t] ratio must be finite, not nan"),
    ],
)
def test_a_wrong_type_names_table_key_and_what_was_expected(table: object, message: str) -> None:
    assert _error(table) == message


@pytest.mark.parametrize("key", ["count", "ratio", "limit", "rate_hz"])
def test_a_bool_is_not_a_number(key: str) -> None:
    """TOML's true is not 1: ``count = true`` is a mistake, not one."""
    assert _error({key: True}).startswith(f"[t] {key} must be ")
    assert _error({key: False}).endswith("not False")


def test_unknown_keys_are_named_with_the_known_ones() -> None:
    message = _error({"cuont": 3, "colour": "red", "bad key": 1})
    assert message.startswith("[t] unknown key(s): 'bad key', cuont (known: colour, count, ")
    assert "origin" not in message  # not a key: the program sets it
    assert _error({"origin": [1.0, 2.0]}).startswith("[t] unknown key(s): origin")


def test_a_nested_dataclass_is_a_table_of_its_own() -> None:
    assert from_table(Outer, {"inner": {"name": "a"}}, "t").inner == Inner("a")
    assert _error({"inner": {}}) == "[t.inner] name is required"
    assert _error({"inner": {"name": "a", "weight_kg": "9"}}) == (
        "[t.inner] weight_kg must be a number, not '9'"
    )
    assert _error({"inner": {"name": "a", "colour": "red"}}) == (
        "[t.inner] unknown key(s): colour (known: name, weight_kg)"
    )
    assert _error({"inner": "a"}) == "[t.inner] must be a table, not 'a'"


def test_a_path_is_relative_to_the_config_files_folder(tmp_path: Path) -> None:
    cfg = from_table(Outer, {"log": "logs/x.log", "folder": "data"}, "t", tmp_path)
    assert cfg.log == str(tmp_path / "logs" / "x.log")
    assert cfg.folder == tmp_path / "data"
    absolute = from_table(Outer, {"log": "/var/log/x", "folder": "/srv"}, "t", tmp_path)
    assert absolute.log == "/var/log/x" and absolute.folder == Path("/srv")
    assert from_table(Outer, {"log": ""}, "t", tmp_path).log == ""  # empty: none
    assert from_table(Outer, {}, "t", tmp_path).folder == Path("default")  # a default: as is
    assert from_table(Outer, {"log": "x.log"}, "t").log == "x.log"  # no folder: as given
    assert from_table(Outer, {"label": "x.log"}, "t", tmp_path).label == "x.log"  # not a path


def test_a_tuple_of_floats() -> None:
    assert from_table(Outer, {"size_m": [1, 2]}, "t").size_m == (1.0, 2.0)
    assert _error({"size_m": [1.0]}) == "[t] size_m must be a list of 2 numbers, not [1.0]"
    assert _error({"size_m": 1.0}) == "[t] size_m must be a list of 2 numbers, not 1.0"
    assert _error({"size_m": [1.0, "2"]}) == "[t] size_m[1] must be a number, not '2'"
    assert _error({"size_m": [1.0, True]}) == "[t] size_m[1] must be a number, not True"


def test_one_string_is_a_list_of_one() -> None:
    """``listen = "tcp/..."`` as well as ``listen = ["tcp/..."]``."""
    assert from_table(Outer, {"names": "a"}, "t").names == ("a",)


def test_rules_say_what_types_do_not() -> None:
    assert _error({"rate_hz": 0}) == "[t] rate_hz must be > 0, not 0.0"
    assert _error({"fraction": 2}) == "[t] fraction must be within [0, 1], not 2.0"
    assert _error({"mode": "router"}) == "[t] mode must be one of peer, client, not 'router'"
    # rules= for a dataclass this module may not annotate: they replace the field's own rule
    rules = {"count": Rule(lo=5), "fraction": Rule(), "label": Rule(read=False)}
    assert _error({"count": 3}, rules=rules) == "[t] count must be >= 5, not 3"
    assert from_table(Outer, {"fraction": 2}, "t", rules=rules).fraction == 2.0
    assert _error({"label": "x"}, rules=rules).startswith("[t] unknown key(s): label")
    with pytest.raises(TypeError, match="no field"):
        from_table(Outer, {}, "t", rules={"nope": Rule()})


def test_the_dataclass_own_checks_name_the_table() -> None:
    assert _error({"count": 13}) == "[t] count 13 is unlucky"
    assert _error({"count": 14}) == "[t] count 14 is not allowed either"


def test_not_a_table() -> None:
    assert _error([1, 2]) == "[t] must be a table, not [1, 2]"


def test_base_keeps_what_the_table_does_not_set() -> None:
    base = Outer(count=9, label="from the command line", origin=(1.0, 2.0))
    cfg = from_table(Outer, {"label": "from the file"}, "t", base=base)
    assert cfg == Outer(count=9, label="from the file", origin=(1.0, 2.0))


def test_it_serves_the_simulators_options(tmp_path: Path) -> None:
    """``[sim]`` onto ``hal_sim.drive.DriveOptions`` (how ``options_from_config`` will read it)."""
    from hal_sim.drive import DriveOptions

    rules = {"config": Rule(read=False), "out": Rule(path=True)}
    opts = from_table(
        DriveOptions,
        {"seed": 3, "can_silent": [10, 5], "out": "sim", "speed": 2},
        "sim",
        tmp_path,
        rules=rules,
        base=DriveOptions(method="straight_to_goal"),
    )
    assert opts.seed == 3 and opts.can_silent == (10.0, 5.0) and opts.speed == 2.0
    assert opts.out == str(tmp_path / "sim") and opts.method == "straight_to_goal"
    with pytest.raises(UserError, match=r"^\[sim\] seed must be an integer, not True$"):
        from_table(DriveOptions, {"seed": True}, "sim", rules=rules)
    with pytest.raises(UserError, match=r"^\[sim\] unknown key\(s\): config "):
        from_table(DriveOptions, {"config": "x.toml"}, "sim", rules=rules)


@pytest.mark.parametrize(
    ("hint", "words"),
    [
        (bool, "true or false"),
        (float | None, "a number"),
        (tuple[str, ...], "a list of strings (or one string)"),
        (tuple[float, float], "a list of 2 numbers"),
        (tuple[int, str], "a list [an integer, a string]"),
        (list[Any], "a list of values"),
        (dict[str, Any], "a table"),
        (Inner, "a table"),
        (Literal["x", "y"], "one of x, y"),
    ],
)
def test_expected_in_words(hint: Any, words: str) -> None:
    assert expected(hint) == words


@dataclass(frozen=True)
class Spread:
    """A dataclass the config file spreads over its tables (as ``PipelineConfig``)."""

    turn_rad: float = field(default=1.0, metadata=rule(lo=0.0, degrees=True))
    after_s: float = field(default=20.0, metadata=rule(lo=0.1, table="b", key="after"))
    units: str = field(default="m", metadata=rule(choices=("m", "ft"), table="a"))
    sizes: tuple[float, ...] = field(default=(), metadata=rule(max_items=2))
    fixed: int = field(default=3, metadata=rule(read=False))
    anything: float = 0.0
    table: Mapping[str, float] = field(default_factory=dict)


def test_degrees_part_key_and_others() -> None:
    """``degrees``: offered as ``<stem>_deg``, held in radians; ``part``/``key``: only the
    fields a table offers, by their key there; ``others``: another reader's keys."""
    assert from_table(Spread, {"turn_deg": 90}, "t").turn_rad == pytest.approx(math.pi / 2)
    assert "[t] turn_deg must be >= 0.0, not -1.0" in _error({"turn_deg": -1}, cls=Spread)
    base = Spread()
    got = from_table(Spread, {"after": 5, "x": 1}, "b", part="b", others=("x",), base=base)
    assert got == Spread(after_s=5.0)
    assert "[b] unknown key(s): units (known: after, x)" in _error(
        {"units": "ft"}, cls=Spread, where="b", part="b", others=("x",), base=base
    )
    assert "[t] unknown key(s): fixed" in _error({"fixed": 4}, cls=Spread)


def test_a_record_reads_every_field_and_bounds_what_no_rule_bounds() -> None:
    """``record=True``: every field by its own name (``read=False`` too), a number no rule
    bounds within ``RECORD_MAX``, a list no rule sizes within ``RECORD_MAX_ITEMS``, an integer
    within 64 bits; a rule's ``max_items`` holds in a file too."""
    from guidance.config_tables import RECORD_MAX, RECORD_MAX_ITEMS

    rec = {"turn_rad": 0.5, "after_s": 1.0, "fixed": 7}
    assert from_table(Spread, rec, "r", record=True) == Spread(0.5, 1.0, fixed=7)
    big = {"anything": RECORD_MAX * 2}
    assert "must be within +-1e+09" in _error(big, cls=Spread, record=True)
    assert from_table(Spread, {"anything": RECORD_MAX * 2}, "t").anything == RECORD_MAX * 2
    many = {str(i): 1.0 for i in range(RECORD_MAX_ITEMS + 1)}
    assert f"at most {RECORD_MAX_ITEMS} items" in _error({"table": many}, cls=Spread, record=True)
    assert "[t] sizes must hold at most 2 items, not 3" in _error({"sizes": [1, 2, 3]}, cls=Spread)
    assert "must be a 64-bit integer" in _error({"fixed": 2**64}, cls=Spread, record=True)
    assert "must be finite" in _error({"anything": 10**400}, cls=Spread, record=True)
