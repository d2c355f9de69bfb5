"""JSON Lines files (drives, runs): read with line numbers, write atomically."""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from navsvc.errors import TraceError


@dataclass(frozen=True)
class Line:
    """One line of a JSON Lines file: its number, and the value or why it is not JSON."""

    number: int
    value: Any = None
    error: str | None = None


def iter_lines(path: Path) -> Iterator[Line]:
    """Each non-blank line, parsed; a line that is not JSON carries its error."""
    try:
        handle = path.open(encoding="utf-8")
    except OSError as exc:
        raise TraceError(f"{path}: cannot read ({exc.strerror})") from None
    with handle:
        try:
            for number, text in enumerate(handle, start=1):
                if not text.strip():
                    continue
                try:
                    yield Line(number, json.loads(text))
                except json.JSONDecodeError as exc:
                    yield Line(number, error=f"not JSON ({exc.msg} at column {exc.colno})")
        except UnicodeDecodeError:
            raise TraceError(f"{path}: not a UTF-8 text file") from None


def read_records(path: Path) -> list[dict[str, Any]]:
    """Every line as a JSON object; raise TraceError naming the file and line otherwise."""
    records = []
    for line in iter_lines(path):
        if line.error is not None:
            raise TraceError(f"{path}:{line.number}: {line.error}")
        if not isinstance(line.value, dict):
            raise TraceError(f"{path}:{line.number}: expected a JSON object")
        records.append(line.value)
    return records


def write_records(path: Path, records: Iterable[dict[str, Any]]) -> int:
    """Write records as JSON Lines via a temporary file (no partial file on failure)."""
    path = Path(path)
    if path.is_dir():
        raise TraceError(f"{path}: is a directory")
    directory = path.parent if str(path.parent) else Path(".")
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=directory)
    except OSError as exc:
        raise TraceError(f"{path}: cannot write ({exc.strerror})") from None
    count = 0
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as out:
            for record in records:
                out.write(json.dumps(record, separators=(",", ":")) + "\n")
                count += 1
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return count
