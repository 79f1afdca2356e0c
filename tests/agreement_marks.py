"""Re-measure the online = offline goal and print the `MISSES` table of tests/test_agreement.py.

    .venv/bin/python -P tests/agreement_marks.py            # print the table
    .venv/bin/python -P tests/agreement_marks.py --write    # rewrite the table in place

Cells that meet the goal are left out (their tests are plain tests). One measurement over
every shared clip and session: about 2-3 CPU-minutes.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))  # `python -P` does not add the script's folder

import marks_table  # noqa: E402
import test_agreement as T  # noqa: E402

Key = tuple[str, str, str]


def measure() -> dict[Key, str]:
    """The cells missing the goal on the current code, with what was measured."""
    t0 = time.perf_counter()
    cells = T.measured_cells()
    print(f"measured in {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
    return {cell: cells[cell][1] for cell in T.cells() if not cells[cell][0]}


def render(misses: dict[Key, str]) -> str:
    """The table as the test module spells it."""
    return marks_table.render("dict[tuple[str, str, str], str]", misses, T.cells().index)


def main() -> int:
    """Measure, then print the table or write it into tests/test_agreement.py."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true", help="rewrite the table in the test")
    args = parser.parse_args()
    table = render(measure())
    if not args.write:
        print(table)
        return 0
    return marks_table.write(HERE / "test_agreement.py", table, table.count("\n") // 2)


if __name__ == "__main__":
    sys.exit(main())
