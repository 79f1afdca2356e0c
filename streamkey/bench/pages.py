"""docs/results.md, rendered from the bench output files under results/ (no hand-copied figure).

The page's prose is the template `streamkey/bench/results.md.in`; every `{{field}}` in it is
filled from a file the benches write. `tests/test_results_pages.py` renders the page from the
committed files and fails when it differs from the committed docs/results.md, and checks that
the template holds no figure of its own.

Regenerate, from the repository root (clips in ../shared/data/cmu). Costs on this project's
2-core VM: CPU time of the bench alone (wall time grows with the machine's other work; a
fresh checkout first compiles the numba kernels, several minutes under load); the last two
only on a quiet machine, since they measure time:

    .venv/bin/streamkey eval ../shared/data/cmu -o results/eval   # ~1 CPU-min
    .venv/bin/streamkey bench --agreement -o results             # 2-3 CPU-min
    .venv/bin/streamkey bench --robustness -o results            # ~4-6 CPU-min
    .venv/bin/streamkey bench --online -o results                # ~11 CPU-min (1-hour stream)
    .venv/bin/streamkey bench --perf -o results                  # ~13 min wall, quiet machine
    .venv/bin/streamkey bench --latency -o results               # ~5 min wall, quiet machine
    .venv/bin/python -P -m streamkey.bench.pages                 # writes docs/results.md

`python -P -m streamkey.bench.pages --check` renders without writing and exits 1 when the
committed page is stale.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import re
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from ..errors import UsageError

__all__ = ["FIELD", "TEMPLATE", "fields", "main", "render"]

ROOT = Path(__file__).resolve().parents[2]
TEMPLATE = Path(__file__).with_name("results.md.in")
FIELD = re.compile(r"\{\{\s*([a-z_]+\.[a-z0-9_]+)\s*\}\}")

# Which command writes each file (named in the error when one is missing).
WRITERS = {"eval/summary.csv": "streamkey eval ../shared/data/cmu -o results/eval",
           "eval/equal_count.csv": "streamkey eval ../shared/data/cmu -o results/eval",
           "bench_agreement.json": "streamkey bench --agreement -o results",
           "bench_robustness.json": "streamkey bench --robustness -o results",
           "bench_perf.json": "streamkey bench --perf -o results",
           "bench_latency.json": "streamkey bench --latency -o results",
           "bench_online.json": "streamkey bench --online -o results"}

# Clips shown as example rows of the equal-count table (the rest are in results/eval/).
EXAMPLE_CLIPS = ("02_07.bvh", "05_06.bvh", "07_01.bvh", "09_12.bvh", "131_03.bvh",
                 "35_01.amc", "49_18.amc")


def _read(results: Path, name: str) -> Path:
    path = results / name
    if not path.is_file():
        raise UsageError(f"{path}: missing; write it with `{WRITERS.get(name, 'the benches')}`")
    return path


def _json(results: Path, name: str) -> dict[str, Any]:
    path = _read(results, name)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as err:
        raise UsageError(f"{path}: line {err.lineno}: not JSON ({err.msg})") from None
    if not isinstance(data, dict):
        raise UsageError(f"{path}: expected a JSON object")
    if data.get("partial"):
        raise UsageError(f"{path}: a partial run (interrupted); run the bench again")
    return data


def _csv(results: Path, name: str) -> list[dict[str, str]]:
    with open(_read(results, name), newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def _g(x: Any, digits: int = 3) -> str:
    """`digits` significant digits, no exponent for ordinary magnitudes."""
    if x is None or x == "":
        return "–"
    v = float(x)
    if not math.isfinite(v):
        return "–"
    return f"{v:.{digits}g}"


def _f(x: Any, decimals: int = 2) -> str:
    """Fixed decimals, thousands separated."""
    if x is None or x == "":
        return "–"
    v = float(x)
    return f"{v:,.{decimals}f}" if math.isfinite(v) else "–"


def _int(x: Any) -> str:
    return f"{int(x):,}"


def _date(x: Any) -> str:
    """The date part of a bench's time stamp ("2026-12-03 15:31:26" -> "on 2026-12-03")."""
    return f"on {str(x).split()[0]}" if x else "at an unrecorded date"


def _table(head: Sequence[str], align: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    lines = ["| " + " | ".join(head) + " |",
             "|" + "|".join("---:" if a == "r" else "---" for a in align) + "|"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def _met(x: Any) -> str:
    return "met" if x else "missed"


def _range(values: Sequence[float], fmt: Callable[[Any], str]) -> str:
    lo, hi = fmt(min(values)), fmt(max(values))
    return lo if lo == hi else f"{lo}–{hi}"


# ----------------------------------------------------------------------------- eval


def _eval_fields(results: Path) -> dict[str, str]:
    rows = _csv(results, "eval/equal_count.csv")
    summary = _csv(results, "eval/summary.csv")
    methods = list(dict.fromkeys(r["method"] for r in rows))
    by_clip: dict[str, dict[str, dict[str, str]]] = {}
    for r in rows:
        by_clip.setdefault(r["clip"], {})[r["method"]] = r
    scored = [m for m in methods if m != "uniform"]
    psnr = [m for m in ("optimal", "uniform") if m in methods]
    head = (["clip", "frames", "keys"] + [f"E {m}" for m in methods]
            + [f"E/E_u {m}" for m in scored] + [f"PSNR {m}" for m in psnr])
    table = []
    for clip in EXAMPLE_CLIPS:
        if clip not in by_clip:
            continue
        mine = by_clip[clip]
        first = next(iter(mine.values()))
        table.append([clip, _int(first["frames"]), _int(first["saliency_keyframes"])]
                     + [_g(mine[m]["E"], 4) for m in methods]
                     + [_g(mine[m]["E_over_uniform"]) for m in scored]
                     + [_f(mine[m]["psnr_db"]) for m in psnr])
    wins: dict[str, int] = {}
    for mine in by_clip.values():
        best = min(mine.values(), key=lambda r: float(r["E"]))["method"]
        wins[best] = wins.get(best, 0) + 1
    count = {"equal": "saliency's", "natural": "its own"}
    summary_rows = [[s["method"], count.get(s["table"], s["table"]),
                     _f(s["median_E_over_uniform"]), _f(s["geomean_E_over_uniform"]),
                     f"{s['clips_beating_uniform']} of {s['clips']}"] for s in summary]
    return {
        "clips": str(len(by_clip)),
        "example_table": _table(head, ["l"] + ["r"] * (len(head) - 1), table),
        "summary_table": _table(["method", "count", "median E/E_u", "geometric mean",
                                 "clips with lower E than uniform"],
                                ["l", "l", "r", "r", "r"], summary_rows),
        "lowest_e": ", ".join(f"{m} on {n}" for m, n in
                              sorted(wins.items(), key=lambda kv: (-kv[1], kv[0])))
                    + f" of {len(by_clip)} clips"}


# ----------------------------------------------------------------------- robustness


def _robustness_fields(results: Path) -> dict[str, str]:
    from ..robustness import CLOCK_STEP_S, GOALS, JITTER_S, STANDARD
    from ..variants import MATCH_TOLERANCE_S

    data = _json(results, "bench_robustness.json")
    cells: dict[tuple[str, str, str], list[tuple[str, bool]]] = {}
    for g in data["goal"]:
        cells.setdefault((g["method"], g["mode"], g["variant"]), []).append(
            (g["check"], bool(g["met"])))
    rows = []
    for s in data["summary"]:
        mine = cells.get((s["method"], s["mode"], s["variant"]), [])
        goal = ("" if not mine else "met" if all(ok for _, ok in mine)
                else "missed: " + ", ".join(c for c, ok in mine if not ok))
        rows.append([s["method"], s["mode"], s["variant"], _f(s["f1_mean"]),
                     f"{_f(s['f1_worst'])} ({s['f1_worst_clip']})",
                     f"{_f(s['ratio_min'])}–{_f(s['ratio_max'])}",
                     f"{_f(s['e_ratio_worst'])} ({s['e_ratio_worst_clip']})",
                     f"{float(s['identical']):.0%}", goal])
    head = ["method", "mode", "variant", "mean F1", "worst F1 (clip)", "key ratio",
            "worst E ratio (clip)", "same keys", "goal"]
    g = GOALS
    goal = (f"{' and '.join(g.f1_methods)} F1 mean ≥ {g.f1_mean:g} and worst ≥ {g.f1_worst:g}; "
            f"every method's key count within {g.ratio_low:g}–{g.ratio_high:g}× on every clip; "
            f"{' and '.join(g.e_methods)} E within {g.e_ratio:.2f}×")
    rate = 120.0
    return {
        "variants": ", ".join(data["variants"]),
        "jitter_ms": f"{JITTER_S * 1000:g}", "clock_step_s": f"{abs(CLOCK_STEP_S):g}",
        "match_frames": f"{MATCH_TOLERANCE_S * rate:g}", "match_rate": f"{rate:g}",
        "date": _date(data.get("date")), "clips": str(data["clips"]),
        "frames": _int(data["frames"]),
        "table": _table(head, ["l", "l", "l", "r", "l", "l", "l", "r", "l"], rows),
        "standard": ", ".join(STANDARD), "goal": goal,
        "cells": str(len(data["goal"])),
        "cells_met": str(sum(bool(c["met"]) for c in data["goal"]))}


# ------------------------------------------------------------------------ agreement


def _agreement_fields(results: Path) -> dict[str, str]:
    from ..agreement import GOALS, MATCH_S, WARMUP_S
    from .agreement import readme_block

    data = _json(results, "bench_agreement.json")
    g = GOALS
    rate = 120.0
    sessions = [float(r["seconds"]) for r in data["rows"] if r["kind"] == "session"]
    goal = (f"median F1 ≥ {g.f1_median:g}, worst ≥ {g.f1_worst:g}, key ratio "
            f"{g.ratio_low:g}–{g.ratio_high:g}, optimal's E ratio ≤ {g.e_ratio:g}, sessions' "
            f"F1 ≥ {g.session_f1_after:g} after their first {WARMUP_S:g} s")
    return {
        "match_frames": f"{MATCH_S * rate:g}", "match_rate": f"{rate:g}",
        "warmup_s": f"{WARMUP_S:g}",
        "session_seconds": _range(sessions, lambda x: f"{x:.0f}") if sessions else "–",
        "date": _date(data.get("date")), "clips": str(data["clips"]),
        "sessions": str(data["sessions"]), "frames": _int(data["frames"]),
        "goal": goal, "cells": str(len(data["goal"])),
        "cells_met": str(sum(bool(c["met"]) for c in data["goal"])),
        "table": readme_block(data["summary"]).rstrip("\n")}


# ----------------------------------------------------------------------------- perf


def _perf_fields(results: Path) -> dict[str, str]:
    data = _json(results, "bench_perf.json")
    rows = data["rows"]
    online = [r for r in rows if "mean_us" in r]
    memory = [r for r in rows if "state_mb" in r]
    offline = [r for r in rows if "exponent" in r]
    loads = [float(r["load_average"]) for r in online if r.get("load_average") is not None]
    sizes = [int(n) for n in data["offline_sizes"]]
    online_rows = [[r["target"], _f(r["mean_us"], 1), _f(r["p50_us"], 1), _f(r["p99_us"], 0),
                    _f(r.get("p999_us"), 0), _f(r["max_us"], 0), _f(r["streams_per_core"], 0),
                    r["goal"], _met(r["met"]), _f(r.get("load_average"))] for r in online]
    memory_rows = [[r["target"].removeprefix("memory "), _f(r["state_mb"], 1),
                    f"{float(r['growth_mb']):+.2f}", r["goal"], _met(r["met"])]
                   for r in memory]
    big = sizes[-1]
    offline_rows = [[r["target"], *(_g(r[f"s@{n}"]) for n in sizes), _g(r[f"first_s@{big}"]),
                     _f(r["exponent"]), r["goal"], _met(r["met"])] for r in offline]

    def k(n: int) -> str:
        return f"{n // 1000}k" if n % 1000 == 0 else _int(n)

    return {
        "date": _date(data.get("date")),
        "load": _range(loads, lambda x: f"{x:.2f}") if loads else "(not recorded)",
        "stream_frames": _int(data["stream_frames"]),
        "memory_frames": _int(data["memory_frames"]),
        "online_table": _table(["target", "mean µs", "p50 µs", "p99 µs", "p99.9 µs",
                                "max µs", "120 Hz streams per core", "goal (µs)", "", "load"],
                               ["l"] + ["r"] * 6 + ["l", "l", "r"], online_rows),
        "memory_table": _table(["keyframer", "state MB", "growth over the second half MB",
                                "goal", ""], ["l", "r", "r", "l", "l"], memory_rows),
        "offline_table": _table(["step", *(f"s at {k(n)}" for n in sizes),
                                 f"first run at {k(big)}", "exponent", "goal", ""],
                                ["l"] + ["r"] * (len(sizes) + 2) + ["l", "l"], offline_rows)}


# -------------------------------------------------------------------------- latency


def _latency_fields(results: Path) -> dict[str, str]:
    data = _json(results, "bench_latency.json")
    rows = data["rows"]
    methods = sorted({key.removesuffix("_p99_ms") for r in rows for key in r
                      if key.endswith("_p99_ms") and not key.startswith(("run_", "target_"))})
    names = {"osc": "OSC", "zmq": "ZeroMQ"}
    out = []
    for r in rows:
        prio = "normal" if r["priority"] == "normal" else "`--realtime`"
        out.append([f"{names.get(r['transport'], r['transport'])}, {prio}",
                    f"{_f(r['load_1min_before'])} → {_f(r['load_1min_after'])}",
                    _int(r["events"]), _f(r["p50_ms"]), f"**{_f(r['p99_ms'])}**",
                    _f(r["max_ms"], 1),
                    " / ".join(_f(r.get(f"{m}_p99_ms")) for m in methods),
                    f"{_f(r['run_summary_p50_ms'])} / {_f(r['run_summary_p99_ms'])}",
                    f"≤ {_g(r['target_p99_ms'])} ms", _met(r["met"])])
    head = ["transport, priority", "load", "events", "p50 ms", "p99 ms", "max ms",
            f"per method p99 ms ({' / '.join(methods)})", "run's own p50 / p99 ms",
            "goal p99", ""]
    rate = float(data["rate_hz"])
    return {
        "date": _date(data.get("date")), "cpus": str(data.get("cpus", "?")),
        "rate": f"{rate:g}", "clip": Path(str(data["clip"])).stem,
        "seconds": f"{int(rows[0]['frames_sent']) / rate:g}" if rows else "–",
        "table": _table(head, ["l", "l"] + ["r"] * 8, out)}


# --------------------------------------------------------------------------- online


def _duration(seconds: float) -> str:
    """"1 h", "3.3 min", "45 s": the stream's length at its capture rate."""
    if seconds >= 3600:
        return f"{seconds / 3600:.3g} h"
    return f"{seconds / 60:.2g} min" if seconds >= 60 else f"{seconds:.2g} s"


def _online_fields(results: Path) -> dict[str, str]:
    data = _json(results, "bench_online.json")
    mem = data["memory"]
    rate = float(mem.get("rate_hz") or data["engine_live"]["rate_hz"])
    methods = mem.get("methods")
    return {
        "date": _date(data.get("date")), "stream_frames": _int(mem["stream_frames"]),
        "duration": _duration(mem["stream_frames"] / rate), "rate": f"{rate:g}",
        "warmup_frames": _int(mem["warmup_frames"]),
        "methods": ", ".join(methods) if methods else "every online keyframer",
        "growth_mb": _f(mem["growth_after_warmup_mb"]),
        "note": "" if mem["stream_frames"] / rate >= 3600 else (
            " This was a shortened run (`bench --online --quick`): the keyframers' windows and "
            "histories were still filling during it, so it is not the growth of a long stream; "
            "`bench --online` streams one hour.")}


SECTIONS: dict[str, Callable[[Path], dict[str, str]]] = {
    "eval": _eval_fields, "robustness": _robustness_fields, "agreement": _agreement_fields,
    "perf": _perf_fields, "latency": _latency_fields, "online": _online_fields}


def fields(results: Path, wanted: Sequence[str] | None = None) -> dict[str, str]:
    """Every template field (`section.name` -> text) from the files under `results`; only
    the sections named in `wanted` (the template's) are read."""
    out: dict[str, str] = {}
    for section in wanted if wanted is not None else SECTIONS:
        if section not in SECTIONS:
            raise UsageError(f"{TEMPLATE}: unknown section {section!r} in a field; known: "
                             + ", ".join(SECTIONS))
        for key, value in SECTIONS[section](results).items():
            out[f"{section}.{key}"] = value
    return out


def render(results: Path, template: str) -> str:
    """The page: `template` with every `{{section.name}}` replaced by its field."""
    wanted = list(dict.fromkeys(m.group(1).split(".")[0] for m in FIELD.finditer(template)))
    values = fields(results, wanted)
    missing = sorted({m.group(1) for m in FIELD.finditer(template)} - set(values))
    if missing:
        raise UsageError(f"{TEMPLATE}: no such field: {', '.join(missing)}")
    return FIELD.sub(lambda m: values[m.group(1)], template)


def main(argv: Sequence[str] | None = None) -> int:
    """Write docs/results.md (or, with --check, exit 1 if it differs from the rendering)."""
    p = argparse.ArgumentParser(prog="python -P -m streamkey.bench.pages",
                                description="render docs/results.md from results/")
    p.add_argument("--results", type=Path, default=ROOT / "results",
                   help="folder of the bench output files (default: the checkout's results/)")
    p.add_argument("-o", "--output", type=Path, default=ROOT / "docs" / "results.md",
                   help="the page to write (default: the checkout's docs/results.md)")
    p.add_argument("--check", action="store_true",
                   help="write nothing; exit 1 when the page differs from the rendering")
    args = p.parse_args(argv)
    try:
        page = render(args.results, TEMPLATE.read_text(encoding="utf-8"))
    except UsageError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    if args.check:
        old = args.output.read_text(encoding="utf-8") if args.output.exists() else ""
        if old != page:
            print(f"{args.output}: stale; regenerate with python -P -m streamkey.bench.pages",
                  file=sys.stderr)
            return 1
        return 0
    args.output.write_text(page, encoding="utf-8")
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
