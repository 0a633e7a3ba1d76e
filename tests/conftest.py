"""Fixtures for every test folder: the leak check (threads, virtual CAN buses, ptys).

A folder or module turns it on with an autouse fixture that says what it checks::

    @pytest.fixture(autouse=True)
    def no_leaks(leak_check: Callable[..., AbstractContextManager[None]]) -> Iterator[None]:
        with leak_check(grace_s=2.0):
            yield
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager
from pathlib import Path

import can.interfaces.virtual
import pytest

LeakCheck = Callable[..., AbstractContextManager[None]]


def pty_fds() -> set[str]:
    """Open file descriptors of this process that point at pseudo-terminals."""
    out = set()
    fd_dir = Path("/proc/self/fd")
    for entry in fd_dir.iterdir() if fd_dir.exists() else ():
        try:
            target = os.readlink(entry)
        except OSError:
            continue
        if target.startswith(("/dev/pts/", "/dev/ptmx")):
            out.add(f"{entry.name}->{target}")
    return out


@contextmanager
def _leak_check(
    *,
    grace_s: float = 2.0,
    ignore_threads: tuple[str, ...] = (),
    virtual_can: bool = True,
    ptys: bool = True,
) -> Iterator[None]:
    """Fail when the block leaves a thread running (after ``grace_s`` to finish), a python-can
    virtual bus open (``virtual_can``) or a pty open (``ptys``). Threads whose name starts with
    one of ``ignore_threads`` belong to libraries that keep them for the process."""
    threads = set(threading.enumerate())
    ptys_before = pty_fds() if ptys else set()
    yield
    deadline = time.monotonic() + grace_s
    while True:
        extra = [
            t
            for t in threading.enumerate()
            if t not in threads
            and t.is_alive()
            and not (ignore_threads and t.name.startswith(ignore_threads))
        ]
        if not extra or time.monotonic() > deadline:
            break
        time.sleep(0.01)
    assert not extra, f"leaked threads: {extra}"
    if virtual_can:
        assert not can.interfaces.virtual.channels, (
            f"leaked virtual CAN buses: {list(can.interfaces.virtual.channels)}"
        )
    if ptys:
        leaked = pty_fds() - ptys_before
        assert not leaked, f"leaked pty file descriptors: {leaked}"


@pytest.fixture
def leak_check() -> LeakCheck:
    """``with leak_check(grace_s=..., ignore_threads=..., virtual_can=..., ptys=...)``."""
    return _leak_check


LOOPBACK_ACL = """{
  // Tests only: zenoh access control that lets every session on the test's loopback link
  // watch and set goals (remote goals need an access-control config: issue 23, item 7).
  access_control: {
    enabled: true,
    default_permission: "deny",
    rules: [{
      id: "guidance-all",
      permission: "allow",
      flows: ["ingress", "egress"],
      messages: ["put", "delete", "declare_subscriber", "query", "reply", "declare_queryable",
                 "liveliness_token", "declare_liveliness_subscriber", "liveliness_query"],
      key_exprs: ["guidance/**"],
    }],
    subjects: [{ id: "anyone" }],
    policies: [{ rules: ["guidance-all"], subjects: ["anyone"] }],
  },
}
"""


@pytest.fixture
def loopback_acl(tmp_path: Path) -> str:
    """A zenoh config file whose access control allows everything under ``guidance/``: what
    a car needs before it may enable remote goals in a test."""
    path = tmp_path / "loopback-acl.json5"
    path.write_text(LOOPBACK_ACL)
    return str(path)
