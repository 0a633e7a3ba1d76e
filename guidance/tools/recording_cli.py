"""``guidance recording repair IN OUT``: a damaged or cut-short recording made readable by any
MCAP tool (``guidance.recording.repair``)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from guidance.recording.repair import damage_text, repair


def register(sub: Any) -> None:
    p = sub.add_parser("recording", help="recording files: repair one cut short by a crash")
    verbs = p.add_subparsers(dest="verb", metavar="VERB", required=True)
    r = verbs.add_parser(
        "repair",
        help="write a complete MCAP file from a damaged or cut-short one",
        description=(
            "Read IN as `guidance replay` does (chunk CRCs checked, damage skipped) and write "
            "every complete message, channel, schema and metadata into OUT, a finished MCAP "
            "file the standard mcap reader, Foxglove and other tools open. IN is not changed."
        ),
    )
    r.add_argument("input", type=Path, metavar="IN", help="the damaged recording (.mcap)")
    r.add_argument("output", type=Path, metavar="OUT", help="the repaired copy (a new file)")
    r.set_defaults(func=_cli_repair)


def _cli_repair(args: argparse.Namespace) -> int:
    res = repair(args.input, args.output)
    lost = damage_text(res.damage)
    if res.orphans:
        lost = ", ".join(filter(None, [lost, f"{res.orphans} messages of lost channels"]))
    sys.stdout.write(
        f"wrote {args.output}: {res.messages} messages on {res.channels} channels"
        f" (left behind: {lost or 'nothing'})\n"
    )
    return 0
