"""Where the shared CMU data lives (../shared/data/cmu), and its manifest."""

from __future__ import annotations

import csv
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "cmu"


def manifest() -> list[dict[str, str]]:
    """Rows of MANIFEST.csv (every shared file)."""
    with open(DATA / "MANIFEST.csv", newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def clips(fmt: str | None = None) -> list[str]:
    """File names of the shared motion clips (BVH and AMC), optionally one format only."""
    rows = [r for r in manifest() if r["format"] != "asf"]
    if fmt:
        rows = [r for r in rows if r["file"].endswith("." + fmt)]
    return [r["file"] for r in rows]


