"""A warning when a zenoh config still uses the example passwords shipped in config/zenoh/.

config/zenoh/ ships a user/password pair for a car and its monitors (``car-usrpwd-acl.json5``
with ``passwords.example.txt``, ``monitor-usrpwd.json5``). Copied unchanged, anyone who has
read this repository can log in, and as ``operator`` set the car's goal where remote goals are
on (issue 40, a low). So a zenoh config whose ``transport/auth/usrpwd`` names one of those
passwords, itself or in its ``dictionary_file``, is warned about: at start by whatever opens a
session with it (the car, ``guidance monitor``), once per process and file, and by ``guidance
run --check``. It is a warning, not a refusal: a test bench on loopback may keep them. The
password itself is never written anywhere; only the user it belongs to is named.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import zenoh

from guidance import files

log = logging.getLogger(__name__)

EXAMPLE_PASSWORDS = frozenset({"change-me-operator", "change-me-viewer"})
"""The passwords config/zenoh/ ships (``tests/guidance/telemetry/test_example_passwords.py``
checks this against the files there)."""
EXAMPLES = "config/zenoh/passwords.example.txt"

_warned: set[str] = set()


def dictionary_users(path: str | Path) -> dict[str, str]:
    """The ``user:password`` lines of a zenoh password dictionary (other lines are skipped),
    read through the file door (``FileRefused`` for anything but a small regular file)."""
    text = files.read_bytes(path, "zenoh_passwords").decode("utf-8", errors="replace")
    users: dict[str, str] = {}
    for line in text.splitlines():
        user, sep, password = line.partition(":")
        if sep and user:
            users[user] = password
    return users


def example_password_problem(zenoh_config: str) -> str | None:
    """One line when ``zenoh_config`` logs in, or lets users log in, with a password shipped
    in config/zenoh/; None when it does not (or names no usrpwd at all)."""
    if not zenoh_config:
        return None
    try:
        conf = zenoh.Config.from_file(zenoh_config)
        password = json.loads(conf.get_json("transport/auth/usrpwd/password"))
        user = json.loads(conf.get_json("transport/auth/usrpwd/user"))
        dictionary = json.loads(conf.get_json("transport/auth/usrpwd/dictionary_file"))
    except (zenoh.ZError, ValueError):
        return None  # opening the session says what is wrong with the file
    users: list[str] = []
    if isinstance(password, str) and password in EXAMPLE_PASSWORDS:
        users.append(str(user))
    if isinstance(dictionary, str) and dictionary:
        try:
            known = dictionary_users(dictionary)  # a relative path is zenoh's: the cwd's
        except files.FileRefused:
            known = {}  # zenoh reads it itself and says why it cannot
        users += sorted(u for u, p in known.items() if p in EXAMPLE_PASSWORDS)
    if not users:
        return None
    names = ", ".join(repr(u) for u in users)
    return (
        f"zenoh config {zenoh_config}: {names} still {'has' if len(users) == 1 else 'have'} "
        f"the example password of {EXAMPLES}: anyone who has read this repository can log in; "
        "set passwords of your own"
    )


def warn_example_passwords(zenoh_config: str) -> None:
    """Log ``example_password_problem`` at warning level, once per process and file."""
    if not zenoh_config or zenoh_config in _warned:
        return
    _warned.add(zenoh_config)
    problem = example_password_problem(zenoh_config)
    if problem is not None:
        log.warning("%s", problem)
