"""`streamkey eval`: the tables of Halit 2010, ch. 4, for every clip of a folder, vs uniform.

Every registered offline method (`methods.OFFLINE_METHODS`) is picked up automatically:

- Equal counts (Halit Table 4.1 shape): every method that takes a `count` is forced to the
  keyframe count of the saliency method's reconstruction on each clip (its keys plus the first
  and last captured frames, which every reconstruction has), and scored next to saliency.
- Natural counts: every method that runs without a `count` (all but uniform and decimate), at
  its own defaults (saliency, speed minima, simplification at its default tolerance, ISODATA,
  Hermite curve fitting, whose count is keys per channel and whose error is that of its own
  per-channel reconstruction).

Each row carries E (Halit eq. 4.1, over the skeleton's joints, not End Sites), E / body
height^2, PSNR (eq. 4.2) and E / E_uniform, uniform sampling at the same keyframe count
(curve fitting has none: its keys are per channel). Each table ends with a summary per method:
median and geometric mean of E / E_uniform and the number of clips where it beats uniform.
"""

from __future__ import annotations

import csv
import inspect
import math
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from .batch import FileResult, load_motion, per_file
from .errors import StreamkeyError
from .evaluate import Evaluator, Scores
from .features import Features, compute_features
from .methods import OFFLINE_METHODS, offline_method
from .motion import Motion

__all__ = ["evaluate_clip", "evaluate_files", "equal_count_methods", "natural_methods",
           "summarise"]

REFERENCE = "uniform"
NO_UNIFORM = ("curvefit",)  # keys per channel: no pose count to compare uniform at


def _params(name: str) -> Mapping[str, inspect.Parameter]:
    return inspect.signature(offline_method(name)).parameters


def equal_count_methods() -> list[str]:
    """Saliency, then every registered method that takes a `count`, uniform last."""
    counted = [m for m in OFFLINE_METHODS if m not in ("saliency", REFERENCE)
               and "count" in _params(m)]
    return ["saliency", *counted, REFERENCE]


def natural_methods() -> list[str]:
    """Every registered method that runs at its own defaults (no required `count`)."""
    return [m for m in OFFLINE_METHODS if m != REFERENCE
            and not ("count" in _params(m)
                     and _params(m)["count"].default is inspect.Parameter.empty)]


def _run(name: str, motion: Motion, features: Features, **kwargs: Any) -> Any:
    if "features" in _params(name):
        kwargs["features"] = features
    return offline_method(name)(motion, **kwargs)


def _with_ratio(scores: Scores, uniform: Scores | None) -> dict[str, Any]:
    ratio = None if uniform is None else (
        scores.error / uniform.error if uniform.error > 0 else (1.0 if scores.error == 0
                                                                  else math.inf))
    return {"scores": scores, "ratio": ratio}


def evaluate_clip(path: Path) -> dict[str, Any]:
    """Scores of one clip: equal-count rows and natural-count rows, each with E / E_uniform."""
    motion = load_motion(path)
    features = compute_features(motion)
    ev = Evaluator(motion)
    uniform: dict[int, Scores] = {}

    def against_uniform(scores: Scores) -> dict[str, Any]:
        if scores.count not in uniform:
            uniform[scores.count] = ev.score(offline_method(REFERENCE)(motion, scores.count))
        return _with_ratio(scores, uniform[scores.count])

    natural: dict[str, Any] = {}
    for name in natural_methods():
        keys = _run(name, motion, features)
        if name in NO_UNIFORM:
            natural[name] = _with_ratio(_curvefit_scores(motion, keys, ev), None)
        else:
            natural[name] = against_uniform(ev.score(keys))
    count = max(natural["saliency"]["scores"].count, 2)  # counted methods keep both ends
    equal = {"saliency": natural["saliency"]}
    for name in equal_count_methods()[1:]:
        equal[name] = against_uniform(ev.score(_run(name, motion, features, count=count)))
    return {"clip": path.name, "frames": motion.n_frames - motion.first_frame,
            "keyframes": count, "equal": equal, "natural": natural}


def _curvefit_scores(motion: Any, keys: Any, ev: Evaluator) -> Scores:
    """Curve fitting keys channels, not poses: score its own Hermite reconstruction, and count
    mean keys per channel, as Önder et al. report them (the union covers most frames)."""
    from .methods import curvefit

    rec = curvefit.reconstruct(motion, keys)
    e = ev.error_e(rec)
    return Scores(round(float(keys.info["mean_keys_per_channel"])), e,
                  e / ev.body_height**2, ev.psnr(rec))


def _fmt(x: float | None, digits: int = 4) -> str:
    if x is None:
        return "n/a"
    return "inf" if math.isinf(x) else f"{x:.{digits}g}"


def summarise(rows: list[dict[str, Any]], table: str, methods: list[str]
              ) -> list[dict[str, Any]]:
    """Per method: median and geometric mean of E / E_uniform, clips beating uniform."""
    out = []
    for m in methods:
        ratios = [r[table][m]["ratio"] for r in rows if r[table][m]["ratio"] is not None]
        if m == REFERENCE or not ratios:
            continue
        finite = [x for x in ratios if 0 < x < math.inf]
        out.append({"method": m, "clips": len(ratios),
                    "median": float(np.median(ratios)),
                    "geomean": float(np.exp(np.mean(np.log(finite)))) if finite else math.nan,
                    "beats": sum(x < 1.0 for x in ratios)})
    return out


def _summary_md(summary: list[dict[str, Any]]) -> list[str]:
    return ["", "Against uniform sampling at the same keyframe count (E / E_uniform < 1 beats "
            "uniform):", "", "| method | clips | median E/E_uniform | geometric mean | "
            "clips beating uniform |", "|---|---:|---:|---:|---:|",
            *[f"| {s['method']} | {s['clips']} | {s['median']:.3f} | {s['geomean']:.3f} | "
              f"{s['beats']} of {s['clips']} |" for s in summary]]


E_HEADER = ("E: thesis eq. 4.1, mean over captured frames and the skeleton's joints (ROOT and "
            "JOINT, not End Sites) of the squared root-relative position error, CMU length "
            "units^2; the first and last captured frames are keys of every reconstruction "
            "(slerp). E/h^2: divided by body height squared (x 1e6). PSNR: eq. 4.2, dB "
            "(MAX = 360 deg; each reconstructed rotation as its Euler triple nearest the "
            "original). E/E_u: E over uniform sampling's E at the same keyframe count.")


def _write_table(rows: list[dict[str, Any]], out: Path, table: str, methods: list[str],
                 title: list[str]) -> list[Path]:
    cols = [f"{m} keys" for m in methods] if table == "natural" else []
    head = ["clip", "frames"] + ([] if cols else ["keys"])
    md = [*title, "", E_HEADER, "",
          "| " + " | ".join(head + cols + [f"E {m}" for m in methods]
                            + [f"E/h^2 {m}" for m in methods] + [f"PSNR {m}" for m in methods]
                            + [f"E/E_u {m}" for m in methods if m != REFERENCE]) + " |",
          "|" + "---|" * (len(head) + len(cols) + 4 * len(methods) - (REFERENCE in methods))]
    csv_rows = []
    for r in rows:
        s = r[table]
        md.append("| " + " | ".join(
            [r["clip"], str(r["frames"])]
            + ([str(s[m]["scores"].count) for m in methods] if cols else [str(r["keyframes"])])
            + [_fmt(s[m]["scores"].error) for m in methods]
            + [_fmt(s[m]["scores"].error_normalised * 1e6) for m in methods]
            + [_fmt(s[m]["scores"].psnr) for m in methods]
            + [_fmt(s[m]["ratio"], 3) for m in methods if m != REFERENCE]) + " |")
        for m in methods:
            sc = s[m]["scores"]
            csv_rows.append([r["clip"], r["frames"], r["keyframes"], m, sc.count, sc.error,
                             sc.error_normalised, sc.psnr,
                             "" if s[m]["ratio"] is None else s[m]["ratio"]])
    md += _summary_md(summarise(rows, table, methods))
    name = "equal_count" if table == "equal" else "natural_count"
    md_path, csv_path = out / f"{name}.md", out / f"{name}.csv"
    md_path.write_text("\n".join(md) + "\n" + (_wins(rows, methods) if table == "equal" else ""),
                       encoding="utf-8", errors="surrogateescape")
    _write_csv(csv_path, csv_rows)
    return [md_path, csv_path]


def _wins(rows: list[dict[str, Any]], methods: list[str]) -> str:
    best: dict[str, int] = {}
    for r in rows:
        winner = min(methods, key=lambda m: r["equal"][m]["scores"].error)
        best[winner] = best.get(winner, 0) + 1
    return ("\nLowest E per clip: " + ", ".join(f"{m} {n}" for m, n in sorted(best.items()))
            + f" (of {len(rows)} clips).\n")


def _write_csv(path: Path, rows: list[list[Any]]) -> None:
    with open(path, "w", newline="", encoding="utf-8", errors="surrogateescape") as fh:
        writer = csv.writer(fh)
        writer.writerow(["clip", "frames", "saliency_keyframes", "method", "keyframes", "E",
                         "E_over_h2", "psnr_db", "E_over_uniform"])
        writer.writerows(rows)


def _write_summary(rows: list[dict[str, Any]], out: Path) -> Path:
    path = out / "summary.csv"
    with open(path, "w", newline="", encoding="utf-8", errors="surrogateescape") as fh:
        writer = csv.writer(fh)
        writer.writerow(["table", "method", "clips", "median_E_over_uniform",
                         "geomean_E_over_uniform", "clips_beating_uniform"])
        for table, methods in (("equal", equal_count_methods()), ("natural", natural_methods())):
            for s in summarise(rows, table, methods):
                writer.writerow([table, s["method"], s["clips"], s["median"], s["geomean"],
                                 s["beats"]])
    return path


def evaluate_files(paths: list[Path], out: Path,
                   progress: Callable[[int, int, Path], None] | None = None,
                   errors: list[str] | None = None) -> list[Path]:
    """Evaluate every clip and write the Markdown + CSV tables into `out`.

    A clip that fails is left out of the tables; its error (naming it) goes to `errors`
    and to `out/errors.txt`.
    """
    out.mkdir(parents=True, exist_ok=True)
    rows: list[dict[str, Any]] = []
    errors = [] if errors is None else errors

    def work(path: Path) -> FileResult:
        rows.append(evaluate_clip(path))
        return FileResult(path, None, {})

    errors += [r.error for r in per_file(paths, work, progress) if r.error]
    if not rows:
        raise StreamkeyError("no clip could be evaluated: " + "; ".join(errors))
    written = _write_table(
        rows, out, "equal", equal_count_methods(),
        ["# Equal keyframe counts (thesis Table 4.1 shape)", "",
         "Every method that takes a keyframe count is forced to the count of the saliency "
         "method's reconstruction (its keys plus the first and last captured frames)."])
    written += _write_table(
        rows, out, "natural", natural_methods(),
        ["# Every method at its natural keyframe count", "",
         "Keys: keyframes of the reconstruction (first and last captured frames included); "
         "curvefit keys are mean keys per channel, scored on its own Hermite reconstruction "
         "(no uniform comparison)."])
    written.append(_write_summary(rows, out))
    if errors:
        err_path = out / "errors.txt"
        err_path.write_text("\n".join(errors) + "\n", encoding="utf-8",
                            errors="surrogateescape")
        written.append(err_path)
    return written
