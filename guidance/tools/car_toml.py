"""Writing the compass deviation card into the car's TOML (``guidance calibrate --write``).

The file is the car's own configuration, so an edit must never leave it broken: it is edited
with tomlkit (comments, order and layout kept; ``[ compass ]``, ``["compass"]``, an inline
``compass = {...}``, dotted ``compass.deviation_deg = ...`` keys and a card spanning several
lines are all the same table to it), the result is parsed again and loaded through the car's
own loader (``guidance.app.config.load_config``) from a temporary file beside the real one,
and only then renamed over it (fsync, ``os.replace``). A symbolic link is followed: the file
it points to is the one rewritten, and the link stays. A read-only file is refused, and the
new file keeps the old one's mode (and owner, for root). Whatever cannot be done is one line
(``UserError``) and the file is left as it was.
"""

from __future__ import annotations

import contextlib
import copy
import os
import re
import stat
import tomllib
from pathlib import Path
from typing import Any

import tomlkit
import tomlkit.items
from tomlkit.exceptions import TOMLKitError

from guidance import files
from guidance.errors import UserError

MAX_CONFIG_BYTES = files.KINDS["config"].max_bytes
"""A car's TOML is a few kB; a larger file is not a config and is not read."""
CARD_COMMENT = "guidance calibrate: A, B, C, D, E"


def _refuse(config: Path, why: str) -> UserError:
    return UserError(f"cannot write the card into {config}: {why}; the file is unchanged")


def _target(config: Path) -> tuple[Path, os.stat_result]:
    """The regular file ``config`` names (through any symbolic links), and its status."""
    try:
        target = config.resolve(strict=True)
        st = target.stat()
    except FileNotFoundError:
        raise _refuse(config, "no such file") from None
    except (OSError, RuntimeError) as exc:  # a loop of symbolic links, a bad path
        why = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        raise _refuse(config, why) from None
    if not stat.S_ISREG(st.st_mode):
        raise _refuse(config, "not a regular file")
    if st.st_size > MAX_CONFIG_BYTES:
        raise _refuse(config, f"larger than {MAX_CONFIG_BYTES >> 20} MiB, not a car's TOML")
    if not st.st_mode & 0o222 or not os.access(target, os.W_OK):
        mode = stat.S_IMODE(st.st_mode)
        raise _refuse(config, f"it is read-only (mode {mode:04o}); make it writable to calibrate")
    return target, st


def _edited(config: Path, text: str, values: list[float]) -> str:
    """The text with ``[compass] deviation_deg`` set to ``values``, checked: it parses, and
    nothing but the card differs from the old document."""
    try:
        old = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise _refuse(config, f"it is not valid TOML ({exc})") from None
    compass_old = old.get("compass", {})
    if not isinstance(compass_old, dict):
        raise _refuse(config, f"compass is a {type(compass_old).__name__}, not a table")
    try:
        doc = tomlkit.parse(text)
        card: Any = doc.get("compass")
        if card is None:
            card = tomlkit.table()
            doc.add(tomlkit.nl())
            doc["compass"] = card
            card = doc["compass"]
        if isinstance(card, tomlkit.items.AoT):
            raise _refuse(config, "compass is an array of tables, not a table")
        floats = [float(v) for v in values]
        current = card.get("deviation_deg")
        if isinstance(current, tomlkit.items.Array) and len(current) == len(floats):
            for i, v in enumerate(floats):  # in place: the layout and comments of the list stay
                current[i] = v
        else:
            card["deviation_deg"] = floats
            item = card.get("deviation_deg")
            if not isinstance(card, tomlkit.items.InlineTable) and not item.trivia.comment:
                item.comment(CARD_COMMENT)
                item.trivia.comment_ws = "  "
        new = tomlkit.dumps(doc)
        if "\r\n" in text and "\n" not in text.replace("\r\n", ""):  # the file's line ends
            new = re.sub(r"(?<!\r)\n", "\r\n", new)
    except (TOMLKitError, ValueError, TypeError, KeyError) as exc:
        raise _refuse(config, f"its layout cannot be edited safely ({exc})") from None
    want = copy.deepcopy(old)
    want.setdefault("compass", {})["deviation_deg"] = floats
    try:
        got = tomllib.loads(new)
    except tomllib.TOMLDecodeError as exc:
        raise _refuse(config, f"the edit would not parse ({exc})") from None
    if got != want:
        raise _refuse(config, "the edit would change more than [compass] deviation_deg")
    return new


def _fsync_dir(folder: Path) -> None:
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def write_card(config: Path, values: list[float]) -> Path:
    """Put ``deviation_deg = values`` into the ``[compass]`` table of ``config`` (see the
    module docstring); returns the file written (``config``'s target when it is a link)."""
    from guidance.app.config import load_config

    target, st = _target(config)
    try:
        text = files.read_bytes(target, "config").decode("utf-8")
    except files.FileRefused as exc:
        raise _refuse(config, exc.why) from None
    except UnicodeDecodeError:
        raise _refuse(config, "it is not UTF-8 text") from None
    new = _edited(config, text, values).encode("utf-8")
    tmp = target.with_name(f".{target.name}.calibrate-{os.getpid()}.tmp")
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except OSError as exc:
        raise _refuse(config, f"no temporary file beside it ({exc.strerror or exc})") from None
    try:
        try:
            os.fchmod(fd, stat.S_IMODE(st.st_mode))
            if os.geteuid() == 0:  # `sudo guidance calibrate`: the service keeps its file
                with contextlib.suppress(OSError):
                    os.fchown(fd, st.st_uid, st.st_gid)
            view = memoryview(new)
            while view:
                view = view[os.write(fd, view) :]
            os.fsync(fd)
        finally:
            os.close(fd)
        try:  # the car's own loader, from beside the real file (relative paths the same)
            cfg = load_config(tmp, require_goal=False)
        except UserError as exc:
            why = str(exc).replace(str(tmp), str(config))
            raise _refuse(config, f"the car would refuse the result ({why})") from None
        if list(cfg.pipeline.compass_deviation_deg) != [float(v) for v in values]:
            raise _refuse(config, "the car would not read the card written")
        os.replace(tmp, target)
    except OSError as exc:
        raise _refuse(config, exc.strerror or str(exc)) from None
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
    _fsync_dir(target.parent)
    return target
