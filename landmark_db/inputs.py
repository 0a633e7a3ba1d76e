"""The files the landmark tools read, opened through the product's one door
(``guidance.files``: a regular file within a size limit, else ``FileRefused``, one line)."""

from __future__ import annotations

import csv
import io
from pathlib import Path
from typing import TextIO

from guidance import files
from guidance.errors import UserError


def read_photo(path: Path) -> bytes:
    """A photo's bytes (at most 64 MiB; a FIFO, a folder or ``/dev/zero`` is refused)."""
    return files.read_bytes(path, "photo")


def open_csv(path: Path, encoding: str = "utf-8") -> TextIO:
    """A CSV file opened as text for the ``csv`` module (at most 16 MiB); the caller closes it."""
    return io.TextIOWrapper(files.open_binary(path, "landmark_csv"), encoding=encoding, newline="")


def read_csv_rows(path: Path) -> list[dict[str, str]]:
    """The rows of a CSV file as dicts by header; a damaged file (a field over the ``csv``
    module's limit, not UTF-8) is ``UserError`` naming it, never a traceback."""
    try:
        with open_csv(path) as fh:
            return list(csv.DictReader(fh))
    except (OSError, csv.Error, UnicodeDecodeError) as exc:
        raise UserError(f"landmark CSV {path}: {exc}") from None
