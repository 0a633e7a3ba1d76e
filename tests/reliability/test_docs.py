"""docs/reliability.md names real tests: every `path::name` it cites exists."""

from __future__ import annotations

import re

from reliability_helpers import REPO

DOC = REPO / "docs" / "reliability.md"
REF = re.compile(r"`(tests/[\w/]+\.py)?::(\w+)`")


def test_every_test_the_fault_matrix_cites_exists() -> None:
    text = DOC.read_text()
    last_path = None
    cited = 0
    for m in REF.finditer(text):
        path = m.group(1) or last_path
        assert path is not None, f"{m.group(0)} has no file before it"
        last_path = path
        source = (REPO / path).read_text()
        assert re.search(rf"^(async )?def {m.group(2)}\(", source, re.M), f"{path}::{m.group(2)}"
        cited += 1
    assert cited >= 30
