"""`streamkey bench --robustness`: keys of every variant of each shared clip against the clean
take's (`robustness`), offline and online, written to results/bench_robustness.{json,csv,md}.

Clips: every BVH file of the data folder (the takes the invariance goal is measured on), or
the ones named by `--clips`. The whole set (29 clips, 35,684 frames at 120 Hz; 14 variants,
two modes, four methods) costs about 4 CPU-minutes, so there is no subset by default.
"""

from __future__ import annotations

import csv
import json
import math
import platform
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from ..errors import UsageError
from ..motion import Motion

__all__ = ["main", "pick_clips", "run", "write_results"]

Say = Callable[[str], None]


def pick_clips(data: Path | None, names: str | None) -> list[Path]:
    """The clip files: each comma-separated name (a file, or a stem or file name inside
    `data`), or every .bvh file of `data`."""
    if names:
        out = []
        for raw in (n.strip() for n in names.split(",") if n.strip()):
            path = Path(raw)
            if not path.exists() and data is not None:
                path = data / raw if Path(raw).suffix else data / f"{raw}.bvh"
            if not path.exists():
                where = f" (nor in {data})" if data is not None else ""
                raise UsageError(f"--clips: no clip {raw!r}{where}; give a .bvh/.amc file or "
                                 "a clip name such as 02_01")
            out.append(path)
        return out
    if data is None or not data.is_dir():
        raise UsageError("bench --robustness needs the CMU clips: --data DIR (default "
                         "../shared/data/cmu) or --clips FILES")
    paths = sorted(data.glob("*.bvh"))
    if not paths:
        raise UsageError(f"bench --robustness: no .bvh clips in {data}")
    return paths


def _variants(text: str | None) -> tuple[str, ...]:
    from ..robustness import CASES

    if not text:
        return CASES
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    bad = [n for n in names if n not in CASES]
    if bad:
        raise UsageError(f"--variants: unknown {', '.join(map(repr, bad))}; choose from "
                         f"{', '.join(CASES)}")
    return names


def run(paths: Sequence[Path], cases: Sequence[str] | None = None, say: Say = lambda s: None
        ) -> tuple[list[dict[str, object]], list[Motion]]:
    """Measure every clip (`robustness.measure_clip`); rows so far stay in the returned list
    if Ctrl-C stops it (`KeyboardInterrupt` carries them as `.rows`)."""
    from ..amc import read_motion
    from ..robustness import CASES, measure_clip

    rows: list[dict[str, object]] = []
    motions: list[Motion] = []
    try:
        for i, path in enumerate(paths, 1):
            t0 = time.perf_counter()
            motion = read_motion(path)
            rows += measure_clip(motion, cases=cases or CASES)
            motions.append(motion)
            n = motion.n_frames - motion.first_frame
            say(f"bench robustness: [{i}/{len(paths)}] {motion.name} ({n} frames) "
                f"{time.perf_counter() - t0:.1f} s")
    except KeyboardInterrupt as stop:
        stop.rows = rows  # type: ignore[attr-defined]
        raise
    return rows, motions


def finite_json(x: Any) -> Any:
    """`x` with every non-finite float replaced by None (JSON has no NaN or infinity)."""
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {k: finite_json(v) for k, v in x.items()}
    if isinstance(x, list):
        return [finite_json(v) for v in x]
    return x


def _cell(x: object, digits: int = 2) -> str:
    return f"{x:.{digits}f}" if isinstance(x, float) and math.isfinite(x) else str(x)


def markdown(summary: Sequence[Mapping[str, object]],
             cells: Mapping[tuple[str, str, str, str], tuple[bool, str]],
             meta: Mapping[str, Any]) -> str:
    """The table: per method, mode and variant over the clips."""
    from ..robustness import GOALS

    g = GOALS
    lines = ["# streamkey bench --robustness", "",
             f"{meta['clips']} clips ({meta['frames']:,} frames at 120 Hz) from {meta['data']}; "
             f"{meta['seconds']:.0f} s on {platform.machine()}, "
             f"{platform.python_implementation()} {platform.python_version()}; {meta['date']}.",
             "",
             "Keys of each variant inside the take, mapped back to clean-take frames, against "
             "the clean take's keys (same mode): F1 within ±4 frames of 120 Hz; key ratio = "
             "variant keys / clean keys; E ratio = E of the clean motion rebuilt from the "
             "variant's keys / from the clean keys; same keys = share of clips whose keys are "
             "the clean keys exactly. Goal (standard variants): "
             f"{' and '.join(g.f1_methods)} F1 mean >= {g.f1_mean:g} and worst >= "
             f"{g.f1_worst:g}; every key ratio in {g.ratio_low:g}-{g.ratio_high:g}; "
             f"{' and '.join(g.e_methods)} E ratio <= {g.e_ratio:.2f}.", "",
             "| method | mode | variant | mean F1 | worst F1 (clip) | key ratio | "
             "worst E ratio (clip) | same keys | goal |",
             "|---|---|---|---:|---|---|---|---:|---|"]
    for s in summary:
        key = (str(s["method"]), str(s["mode"]), str(s["variant"]))
        mine = {c[3]: v for c, v in cells.items() if c[:3] == key}
        goal = ("" if not mine else "met" if all(ok for ok, _ in mine.values())
                else "missed: " + ", ".join(c for c, (ok, _) in mine.items() if not ok))
        lines.append(
            f"| {s['method']} | {s['mode']} | {s['variant']} | {_cell(s['f1_mean'])} | "
            f"{_cell(s['f1_worst'])} ({s['f1_worst_clip']}) | {_cell(s['ratio_min'])}-"
            f"{_cell(s['ratio_max'])} | {_cell(s['e_ratio_worst'])} "
            f"({s['e_ratio_worst_clip']}) | {float(s['identical']):.0%} | {goal} |")  # type: ignore[arg-type]
    return "\n".join(lines) + "\n"


def write_results(rows: Sequence[Mapping[str, object]], output: Path, meta: dict[str, Any]
                  ) -> list[Path]:
    """bench_robustness.json (rows, summary, goal cells), .csv (rows), .md (the table)."""
    from ..robustness import acceptance, summarise

    output.mkdir(parents=True, exist_ok=True)
    summary = summarise(rows)
    cells = acceptance(rows)
    js, cs, md = (output / f"bench_robustness.{s}" for s in ("json", "csv", "md"))
    goal = [{"method": k[0], "mode": k[1], "variant": k[2], "check": k[3], "met": ok,
             "measured": text} for k, (ok, text) in cells.items()]
    js.write_text(json.dumps(finite_json({**meta, "summary": summary, "goal": goal,
                                      "rows": list(rows)}), indent=1, allow_nan=False) + "\n",
                  encoding="utf-8")
    with open(cs, "w", newline="", encoding="utf-8") as fh:
        fields = list(rows[0]) if rows else ["clip"]
        writer = csv.DictWriter(fh, fields)
        writer.writeheader()
        for r in rows:
            writer.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v)
                             for k, v in r.items()})
    md.write_text(markdown(summary, cells, meta), encoding="utf-8")
    return [js, cs, md]


def main(data_dir: str | None, clips: str | None, variants: str | None,
         output_dir: str | None) -> int:
    """`bench --robustness`: measure the clips of `data_dir` (or the comma-separated `clips`)
    on the `variants` (default all), write the three files to `output_dir`, list them."""
    from .core import default_data_dir

    def say(line: str) -> None:
        print(line, file=sys.stderr, flush=True)

    data = Path(data_dir) if data_dir else default_data_dir()
    paths = pick_clips(data, clips)
    cases = _variants(variants)
    output = Path(output_dir or "results")
    say(f"bench robustness: {len(paths)} clips, {len(cases)} variants, started "
        f"{time.strftime('%H:%M:%S')}")
    t0 = time.perf_counter()
    partial = False
    try:
        rows, motions = run(paths, cases, say)
    except KeyboardInterrupt as stop:
        rows, motions, partial = getattr(stop, "rows", []), [], True
    clip_names = sorted({str(r["clip"]) for r in rows})
    meta: dict[str, Any] = {
        "date": time.strftime("%Y-%m-%d %H:%M:%S"), "data": str(data or ""),
        "clips": len(clip_names), "clip_names": clip_names,
        "frames": sum(m.n_frames - m.first_frame for m in motions),
        "variants": list(cases), "seconds": time.perf_counter() - t0, "partial": partial}
    if not rows:
        say("bench robustness: interrupted before the first clip finished; nothing written")
        return 130
    for path in write_results(rows, output, meta):
        print(f"wrote {path}")
    if partial:
        say("interrupted: the files hold the clips measured before Ctrl-C (\"partial\": true)")
        return 130
    return 0
