"""Shared output for benchmarks: a table on stdout and a JSON file under bench/results/."""

from __future__ import annotations

import argparse
import json
import platform
import statistics
from collections.abc import Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

RESULTS = Path(__file__).resolve().parent / "results"


def drives_parser(doc: str) -> argparse.ArgumentParser:
    """The options of the simulated-drive evaluations."""
    parser = argparse.ArgumentParser(description=doc.split("\n")[0])
    parser.add_argument("--map", type=Path, default=RESULTS.parent.parent / "maps" / "monaco.db",
                        help="road-graph database (default maps/monaco.db)")
    parser.add_argument("--drives", type=int, default=10, help="drives, seeds 1..N")
    parser.add_argument("--duration", type=float, default=600.0, help="seconds per drive")
    parser.add_argument("--workers", type=int, default=2, help="processes")
    return parser


def median_us(seconds: Sequence[float]) -> float:
    return statistics.median(seconds) * 1e6


def print_table(title: str, headers: Sequence[str], rows: Sequence[Sequence[Any]]) -> None:
    cells = [[_fmt(c) for c in row] for row in rows]
    widths = [max(len(h), *(len(r[i]) for r in cells)) for i, h in enumerate(headers)]
    print(f"\n{title}")
    print("  ".join(h.ljust(w) for h, w in zip(headers, widths)))
    print("  ".join("-" * w for w in widths))
    for row in cells:
        print("  ".join(c.ljust(w) for c, w in zip(row, widths)))


def write_json(name: str, data: dict[str, Any]) -> Path:
    RESULTS.mkdir(parents=True, exist_ok=True)
    path = RESULTS / f"{name}.json"
    meta = {"when_utc": datetime.now(UTC).isoformat(timespec="seconds"),
            "python": platform.python_version(), "machine": platform.machine()}
    path.write_text(json.dumps({"meta": meta, **data}, indent=2))
    print(f"\nwrote {path}")
    return path


def _fmt(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.3g}" if abs(value) < 100 else f"{value:.0f}"
    return str(value)
