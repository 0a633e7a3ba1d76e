"""Where the test suite's time goes: per file and per test, from pytest's JUnit XML.

    .venv/bin/python -m pytest -q -n 2 --dist loadgroup --durations=0 --junitxml=/tmp/a.xml \
        > /tmp/a.log                                         # (as `make test` runs it)
    .venv/bin/python benchmarks/suite_time.py /tmp/a.xml [/tmp/b.xml] [--top 40] [--log /tmp/a.log]

With two reports, the files and tests are printed side by side (first, second, ratio): a
change's effect measured on the same machine, ideally run in turn. The times are wall time
as pytest took them (load from other work counts), so compare runs made under the same load.
A test's time includes its fixtures' set-up; ``--log`` (pytest's ``--durations=0`` output)
adds the set-ups alone, longest first: a module or session fixture's cost shows on the first
test that asked for it. Under pytest-xdist the sum is the workers' time, not the wall time, and
a test run in an ``xdist_group`` is named without its ``@group``.
"""

from __future__ import annotations

import argparse
import re
import sys
import xml.etree.ElementTree as ET
from pathlib import Path


def read(path: Path) -> dict[str, float]:
    """``file::test`` -> seconds, for every test case in a JUnit XML report."""
    out: dict[str, float] = {}
    for case in ET.parse(path).iter("testcase"):
        module = (case.get("classname") or "").replace(".", "/")
        name = re.sub(r"@[\w.-]+$", "", case.get("name") or "")  # xdist_group's suffix
        out[f"{module}.py::{name}"] = float(case.get("time") or 0.0)
    return out


def setups(log: Path) -> dict[str, float]:
    """``file::test`` -> seconds of its set-up, from pytest's ``--durations`` lines."""
    out: dict[str, float] = {}
    for m in re.finditer(r"^([\d.]+)s setup\s+(\S+)$", log.read_text(errors="replace"), re.M):
        out[re.sub(r"@[\w.-]+$", "", m.group(2))] = float(m.group(1))
    return out


def by_file(tests: dict[str, float]) -> dict[str, float]:
    files: dict[str, float] = {}
    for name, s in tests.items():
        key = name.split("::", 1)[0]
        files[key] = files.get(key, 0.0) + s
    return files


def table(rows: dict[str, float], other: dict[str, float] | None, top: int) -> list[str]:
    lines = []
    for name, s in sorted(rows.items(), key=lambda kv: -kv[1])[:top]:
        if other is None:
            lines.append(f"{s:8.1f}  {name}")
        else:
            o = other.get(name)
            ratio = f"{o / s:6.2f}" if o is not None and s > 0 else "     -"
            shown = f"{o:8.1f}" if o is not None else "       -"
            lines.append(f"{s:8.1f}  {shown}  {ratio}  {name}")
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("reports", nargs="+", type=Path, help="one or two JUnit XML reports")
    ap.add_argument("--top", type=int, default=40)
    ap.add_argument("--log", type=Path, help="pytest --durations=0 output: the set-ups alone")
    args = ap.parse_args(argv)
    if len(args.reports) > 2:
        ap.error("at most two reports")
    first = read(args.reports[0])
    second = read(args.reports[1]) if len(args.reports) == 2 else None
    head = "   first    second  ratio" if second is not None else " seconds"
    total = f"total {sum(first.values()):.0f} s over {len(first)} tests"
    if second is not None:
        total += f"; second {sum(second.values()):.0f} s over {len(second)} tests"
    print(total)
    print(f"\nby file\n{head}")
    print("\n".join(table(by_file(first), by_file(second) if second else None, args.top)))
    print(f"\nby test\n{head}")
    print("\n".join(table(first, second, args.top)))
    if args.log is not None:
        print("\nset-up (fixtures) of the first report\n seconds")
        print("\n".join(table(setups(args.log), None, args.top)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
