"""`streamkey bench --agreement`: the online keyframers against the offline methods at the
default settings of both sides, per clip and per session, written to
results/bench_agreement.{json,md}.

Clips: every BVH and AMC file of the data folder (or `--clips`). Sessions: the takes of each
subject back to back (`streamkey.sessions`; or the subjects named by `--sessions`, `none` for
clips only). Per method: key counts, F1 within ±4 frames of 120 Hz, online/offline key-count
ratio, optimal's E over the E of the offline optimum with as many keys and, on sessions, F1
and the count ratio after the first 10 s. The whole set (35 clips, 7 sessions, about 97,000
frames) costs about 2-3 CPU-minutes.

The README's agreement table is this module's `readme_block`:

    .venv/bin/python -P -m streamkey.bench.agreement results/bench_agreement.json
"""

from __future__ import annotations

import json
import math
import platform
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import UsageError
from .robustness import finite_json

__all__ = ["main", "measure", "summarise", "markdown", "readme_block", "write_results"]

Say = Callable[[str], None]


def _clip_paths(data: Path, names: str | None) -> list[Path]:
    """Every .bvh and .amc file of `data`, or the comma-separated `names`."""
    from .robustness import pick_clips

    if names:
        return pick_clips(data, names)
    if not data.is_dir():
        raise UsageError("bench --agreement needs the CMU clips: --data DIR (default "
                         "../shared/data/cmu) or --clips FILES")
    paths = sorted(p for p in data.iterdir() if p.suffix.lower() in (".bvh", ".amc"))
    if not paths:
        raise UsageError(f"bench --agreement: no .bvh or .amc clips in {data}")
    return paths


def _subjects(text: str | None) -> list[str] | None:
    """None (every subject), [] (`none`) or the named subjects."""
    if text is None:
        return None
    if text.strip().lower() == "none":
        return []
    return [s.strip() for s in text.split(",") if s.strip()]


def measure(paths: Sequence[Path], data: Path, subjects: list[str] | None,
            say: Say = lambda s: None) -> list[dict[str, Any]]:
    """Rows of `agreement.default_agreement` for every clip, then every session; rows so
    far ride on a `KeyboardInterrupt` as `.rows`."""
    from ..agreement import WARMUP_S, default_agreement
    from ..amc import read_motion
    from ..sessions import read_sessions

    rows: list[dict[str, Any]] = []
    t0 = time.perf_counter()
    try:
        for i, path in enumerate(paths, 1):
            motion = read_motion(path)
            motion.name = path.name
            rows += default_agreement(motion)
            say(f"bench agreement: clip [{i}/{len(paths)}] {path.name} "
                f"{time.perf_counter() - t0:.0f} s")
        sessions = [] if subjects == [] else read_sessions(data, subjects)
        for i, session in enumerate(sessions, 1):
            rows += default_agreement(session.motion, kind="session", after_s=WARMUP_S)
            say(f"bench agreement: session [{i}/{len(sessions)}] {session.name} "
                f"({session.seconds:.0f} s, {len(session.takes)} takes) "
                f"{time.perf_counter() - t0:.0f} s")
    except KeyboardInterrupt as stop:
        stop.rows = rows  # type: ignore[attr-defined]
        raise
    return rows


def summarise(rows: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Per kind (clip, session) and method: median and worst F1, the key-ratio range, the
    worst E ratio and, for sessions, the worst F1 after 10 s."""
    out = []
    for kind in ("clip", "session"):
        for method in dict.fromkeys(str(r["method"]) for r in rows):
            mine = [r for r in rows if r["kind"] == kind and r["method"] == method]
            if not mine:
                continue
            f1 = [float(r["f1"]) for r in mine]
            ratio = [float(r["count_ratio"]) for r in mine]
            low = int(np.argmin(f1))
            entry: dict[str, Any] = {
                "kind": kind, "method": method, "n": len(mine),
                "f1_median": float(np.median(f1)), "f1_worst": f1[low],
                "f1_worst_name": mine[low]["name"], "ratio_min": min(ratio),
                "ratio_max": max(ratio), "e_ratio_worst": None, "e_ratio_worst_name": "",
                "f1_after_median": None, "f1_after_worst": None, "f1_after_worst_name": ""}
            e = [(float(r["e_ratio"]), str(r["name"])) for r in mine if r["e_ratio"] is not None]
            if e:
                entry["e_ratio_worst"], entry["e_ratio_worst_name"] = max(e)
            after = [(float(r["f1_after"]), str(r["name"])) for r in mine
                     if r["f1_after"] is not None]
            if after:
                entry["f1_after_median"] = float(np.median([a for a, _ in after]))
                entry["f1_after_worst"], entry["f1_after_worst_name"] = min(after)
            out.append(entry)
    return out


def _cell(x: object, digits: int = 3) -> str:
    if x is None:
        return "–"
    return f"{x:.{digits}f}" if isinstance(x, float) and math.isfinite(x) else str(x)


def readme_block(summary: Sequence[Mapping[str, Any]]) -> str:
    """The README's agreement table: one row per method and kind."""
    lines = ["| method | corpus | median F1 | worst F1 | key ratio | worst E ratio | "
             "F1 after 10 s (median, worst) |",
             "|---|---|---:|---|---|---|---|"]
    for s in summary:
        corpus = f"{s['n']} {'clips' if s['kind'] == 'clip' else 'sessions'}"
        e = ("–" if s["e_ratio_worst"] is None
             else f"{_cell(s['e_ratio_worst'])} ({s['e_ratio_worst_name']})")
        after = ("–" if s["f1_after_worst"] is None else
                 f"{_cell(s['f1_after_median'])}, {_cell(s['f1_after_worst'])} "
                 f"({s['f1_after_worst_name']})")
        lines.append(f"| {s['method']} | {corpus} | {_cell(s['f1_median'])} | "
                     f"{_cell(s['f1_worst'])} ({s['f1_worst_name']}) | "
                     f"{_cell(s['ratio_min'], 2)}-{_cell(s['ratio_max'], 2)} | {e} | {after} |")
    return "\n".join(lines) + "\n"


def markdown(rows: Sequence[Mapping[str, Any]], meta: Mapping[str, Any]) -> str:
    """The summary with its goal checks, then one row per clip or session and method."""
    from ..agreement import goal_cells

    lines = ["# streamkey bench --agreement", "",
             f"{meta['clips']} clips and {meta['sessions']} sessions ({meta['frames']:,} frames) "
             f"from {meta['data']}; {meta['seconds']:.0f} s on {platform.machine()}, "
             f"{platform.python_implementation()} {platform.python_version()}; {meta['date']}.",
             "", "Online (default keyframers on one pipeline, as `extract --online`) against "
             "offline (default methods): F1 within ±4 frames of 120 Hz; key ratio = online "
             "keys / offline keys; E ratio (optimal) = E of the online keys / E of the offline "
             "optimum with as many keys; sessions also after their first 10 s.", "",
             readme_block(summarise(rows)), "## Goal", "",
             "| corpus | method | check | met | measured |", "|---|---|---|---|---|"]
    for (kind, method, check), (met, text) in goal_cells(rows).items():
        lines.append(f"| {kind} | {method} | {check} | {'yes' if met else 'no'} | {text} |")
    lines += ["", "## Every clip and session", "",
              "| name | kind | s | method | offline | online | F1 | key ratio | E ratio | "
              "F1 after 10 s | key ratio after 10 s |", "|---|---|---:|---|---:|---:|---:|"
              "---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['name']} | {r['kind']} | {r['seconds']:.1f} | {r['method']} | "
                     f"{r['offline']} | {r['online']} | {_cell(r['f1'])} | "
                     f"{_cell(r['count_ratio'], 2)} | {_cell(r['e_ratio'])} | "
                     f"{_cell(r['f1_after'])} | {_cell(r['count_ratio_after'], 2)} |")
    return "\n".join(lines) + "\n"


def write_results(rows: Sequence[Mapping[str, Any]], output: Path, meta: Mapping[str, Any]
                  ) -> list[Path]:
    """bench_agreement.json (meta, summary, goal cells, rows) and .md (the tables)."""
    from ..agreement import goal_cells

    output.mkdir(parents=True, exist_ok=True)
    goal = [{"kind": k[0], "method": k[1], "check": k[2], "met": ok, "measured": text}
            for k, (ok, text) in goal_cells(rows).items()]
    js, md = output / "bench_agreement.json", output / "bench_agreement.md"
    js.write_text(json.dumps(finite_json({**meta, "summary": summarise(rows), "goal": goal,
                                      "rows": list(rows)}), indent=1, allow_nan=False) + "\n",
                  encoding="utf-8")
    md.write_text(markdown(rows, meta), encoding="utf-8")
    return [js, md]


def main(data_dir: str | None, clips: str | None, sessions: str | None,
         output_dir: str | None) -> int:
    """`bench --agreement`: measure, write the two files to `output_dir`, list them."""
    from .core import default_data_dir

    def say(line: str) -> None:
        print(line, file=sys.stderr, flush=True)

    data = Path(data_dir) if data_dir else default_data_dir()
    if data is None:
        raise UsageError("bench --agreement needs the CMU clips: --data DIR")
    paths = _clip_paths(data, clips)
    subjects = _subjects(sessions)
    if subjects:  # a wrong name fails now, not after the clips are measured
        from ..sessions import subject_takes

        have = subject_takes(sorted(data.iterdir()))
        missing = [s for s in subjects if s not in have]
        if missing:
            raise UsageError(f"--sessions: no subject {', '.join(missing)} with two or more "
                             f"BVH takes in {data}; have {', '.join(have) or 'none'}")
    say(f"bench agreement: {len(paths)} clips and the sessions, started "
        f"{time.strftime('%H:%M:%S')}")
    t0 = time.perf_counter()
    partial = False
    try:
        rows = measure(paths, data, subjects, say)
    except KeyboardInterrupt as stop:
        rows, partial = getattr(stop, "rows", []), True
    if not rows:
        say("bench agreement: interrupted before the first clip finished; nothing written")
        return 130
    names = {kind: sorted({str(r["name"]) for r in rows if r["kind"] == kind})
             for kind in ("clip", "session")}
    frames = {str(r["name"]): int(r["frames"]) for r in rows}
    meta: dict[str, Any] = {
        "date": time.strftime("%Y-%m-%d %H:%M:%S"), "data": str(data),
        "clips": len(names["clip"]), "sessions": len(names["session"]),
        "clip_names": names["clip"], "session_names": names["session"],
        "frames": sum(frames.values()), "seconds": time.perf_counter() - t0,
        "partial": partial}
    for path in write_results(rows, Path(output_dir or "results"), meta):
        print(f"wrote {path}")
    if partial:
        say("interrupted: the files hold what was measured before Ctrl-C (\"partial\": true)")
        return 130
    return 0


def _readme(argv: Sequence[str]) -> int:
    """Print the README block from a bench_agreement.json."""
    if len(argv) != 1:
        print("usage: python -P -m streamkey.bench.agreement results/bench_agreement.json",
              file=sys.stderr)
        return 2
    result = json.loads(Path(argv[0]).read_text(encoding="utf-8"))
    sys.stdout.write(readme_block(result["summary"]))
    return 0


if __name__ == "__main__":
    sys.exit(_readme(sys.argv[1:]))
