"""Re-measure the invariance goal and print the `MISSES` table of tests/test_robustness.py.

    .venv/bin/python -P tests/robustness_marks.py                  # both scopes, print
    .venv/bin/python -P tests/robustness_marks.py --scope subset   # the 3 clips only
    .venv/bin/python -P tests/robustness_marks.py --write          # rewrite the table in place

Cells that meet the goal are left out (their tests are plain tests); `--write` keeps the
entries of a scope that was not re-measured.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))  # `python -P` does not add the script's folder

import marks_table  # noqa: E402
import test_robustness as T  # noqa: E402

Key = tuple[str, str, str, str, str]


def measure(scopes: list[str]) -> dict[Key, str]:
    """The cells missing the goal on the current code, with what was measured."""
    misses: dict[Key, str] = {}
    for scope in scopes:
        t0 = time.perf_counter()
        cells = T.measured_cells(scope)
        print(f"{scope}: {len(T.SCOPES[scope])} clips, {time.perf_counter() - t0:.0f} s",
              file=sys.stderr, flush=True)
        for cell in T.cells():
            met, measured = cells[cell]
            if not met:
                misses[(scope, *cell)] = measured
    return misses


def render(misses: dict[Key, str]) -> str:
    """The table as the test module spells it."""
    return marks_table.render(
        "dict[tuple[str, str, str, str, str], str]", misses,
        lambda k: (list(T.SCOPES).index(k[0]), T.cells().index(k[1:])))


def main() -> int:
    """Measure, then print the table or write it into tests/test_robustness.py."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scope", choices=[*T.SCOPES, "both"], default="both")
    parser.add_argument("--write", action="store_true", help="rewrite the table in the test")
    args = parser.parse_args()
    scopes = list(T.SCOPES) if args.scope == "both" else [args.scope]
    misses = {k: v for k, v in T.MISSES.items() if k[0] not in scopes}
    misses.update(measure(scopes))
    table = render(misses)
    if not args.write:
        print(table)
        return 0
    return marks_table.write(HERE / "test_robustness.py", table, len(misses))


if __name__ == "__main__":
    sys.exit(main())
