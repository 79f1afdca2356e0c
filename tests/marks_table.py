"""The `MISSES` marks table shared by the re-measuring scripts (agreement_marks.py,
robustness_marks.py): render it as the test module spells it and write it in place."""

from __future__ import annotations

import re
import sys
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

MARKS = re.compile(r"(# --- marks: begin[^\n]*\n).*?(\n# --- marks: end)", re.S)


def render(annotation: str, misses: Mapping[Any, str],
           order: Callable[[Any], Any]) -> str:
    """`MISSES: <annotation> = {...}` with one key and its measured value per entry."""
    lines = [f"MISSES: {annotation} = {{"]
    for key in sorted(misses, key=order):
        lines.append(f"    {key!r}:")
        lines.append(f"        {misses[key]!r},")
    lines.append("}")
    return "\n".join(lines)


def write(path: Path, table: str, count: int) -> int:
    """Replace the table between the '# --- marks: begin/end' lines of `path`; exit code."""
    text = path.read_text(encoding="utf-8")
    if not MARKS.search(text):
        print(f"{path}: the '# --- marks: begin/end' lines are missing", file=sys.stderr)
        return 2
    path.write_text(MARKS.sub(lambda m: m.group(1) + table + m.group(2), text),
                    encoding="utf-8")
    print(f"wrote {count} marks into {path}", file=sys.stderr)
    return 0
