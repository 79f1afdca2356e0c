"""`streamkey eval`: the thesis-style tables for every clip of a folder.

Table 4.1 shape (equal keyframe counts): every counted method (curve simplification, frame
decimation, uniform sampling) is forced to the saliency method's keyframe count on each clip,
and E (thesis eq. 4.1), E / body height^2 and PSNR (eq. 4.2) are reported side by side.
A second table gives every method at its own natural keyframe count (saliency, speed minima,
simplification at its default tolerance, ISODATA, and Hermite curve fitting, whose count is
keys per channel and whose error is that of its own per-channel reconstruction).
"""

from __future__ import annotations

import csv
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

from .amc import read_motion
from .errors import StreamkeyError
from .evaluate import Evaluator, Scores
from .features import compute_features
from .methods import OFFLINE_METHODS, offline_method

__all__ = ["evaluate_clip", "evaluate_files", "EQUAL_COUNT_METHODS", "NATURAL_METHODS"]

EQUAL_COUNT_METHODS = ("saliency", "simplify", "decimate", "uniform", "optimal")
NATURAL_METHODS = ("saliency", "speed", "simplify", "isodata", "curvefit")


def evaluate_clip(path: Path) -> dict[str, Any]:
    """Scores of one clip: equal-count rows and natural-count rows."""
    motion = read_motion(path)
    features = compute_features(motion)
    ev = Evaluator(motion)
    natural: dict[str, Any] = {}
    for name in NATURAL_METHODS:
        if name not in OFFLINE_METHODS:
            continue
        keys = offline_method(name)(motion, features=features)
        natural[name] = _curvefit_scores(motion, keys, ev) if name == "curvefit" else ev.score(keys)
    count = natural["saliency"].count
    equal = {"saliency": natural["saliency"]}
    for name in EQUAL_COUNT_METHODS[1:]:
        fn = offline_method(name)
        keys = (fn(motion, count=count, features=features) if name in ("simplify", "optimal")
                else fn(motion, count=count))
        equal[name] = ev.score(keys)
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


def _fmt(x: float, digits: int = 4) -> str:
    return "inf" if math.isinf(x) else f"{x:.{digits}g}"


def _write_equal(rows: list[dict[str, Any]], out: Path) -> list[Path]:
    methods = EQUAL_COUNT_METHODS
    head = ["clip", "frames", "keyframes"]
    md = ["# Equal keyframe counts (thesis Table 4.1 shape)", "",
          "Every method is forced to the saliency method's keyframe count. E: thesis eq. 4.1 "
          "(mean squared root-relative joint distance, CMU length units^2); E/h^2: divided by "
          "body height squared (x 1e6); PSNR: eq. 4.2, dB (MAX = 360 deg).", "",
          "| " + " | ".join(head + [f"E {m}" for m in methods] + [f"E/h^2 {m}" for m in methods]
                            + [f"PSNR {m}" for m in methods]) + " |",
          "|" + "---|" * (len(head) + 3 * len(methods))]
    csv_rows = []
    for r in rows:
        s = r["equal"]
        md.append("| " + " | ".join(
            [r["clip"], str(r["frames"]), str(r["keyframes"])]
            + [_fmt(s[m].error) for m in methods]
            + [_fmt(s[m].error_normalised * 1e6) for m in methods]
            + [_fmt(s[m].psnr) for m in methods]) + " |")
        for m in methods:
            csv_rows.append([r["clip"], r["frames"], r["keyframes"], m, s[m].count, s[m].error,
                             s[m].error_normalised, s[m].psnr])
    md_path, csv_path = out / "equal_count.md", out / "equal_count.csv"
    md_path.write_text("\n".join(md) + "\n" + _wins(rows), encoding="utf-8")
    _write_csv(csv_path, csv_rows)
    return [md_path, csv_path]


def _wins(rows: list[dict[str, Any]]) -> str:
    best: dict[str, int] = {}
    for r in rows:
        winner = min(EQUAL_COUNT_METHODS, key=lambda m: r["equal"][m].error)
        best[winner] = best.get(winner, 0) + 1
    return ("\nLowest E per clip: " + ", ".join(f"{m} {n}" for m, n in sorted(best.items()))
            + f" (of {len(rows)} clips).\n")


def _write_natural(rows: list[dict[str, Any]], out: Path) -> list[Path]:
    methods = [m for m in NATURAL_METHODS if m in rows[0]["natural"]]
    md = ["# Every method at its natural keyframe count", "",
          "E: thesis eq. 4.1 (CMU length units^2); PSNR: eq. 4.2 (dB). curvefit keys are mean "
          "keys per channel, scored on its own Hermite reconstruction.", "",
          "| clip | frames | " + " | ".join(f"{m} keys | {m} E | {m} PSNR" for m in methods)
          + " |", "|" + "---|" * (2 + 3 * len(methods))]
    csv_rows = []
    for r in rows:
        s = r["natural"]
        md.append("| " + " | ".join([r["clip"], str(r["frames"])] + [
            f"{s[m].count} | {_fmt(s[m].error)} | {_fmt(s[m].psnr)}" for m in methods]) + " |")
        for m in methods:
            csv_rows.append([r["clip"], r["frames"], r["keyframes"], m, s[m].count, s[m].error,
                             s[m].error_normalised, s[m].psnr])
    md_path, csv_path = out / "natural_count.md", out / "natural_count.csv"
    md_path.write_text("\n".join(md) + "\n", encoding="utf-8")
    _write_csv(csv_path, csv_rows)
    return [md_path, csv_path]


def _write_csv(path: Path, rows: list[list[Any]]) -> None:
    with open(path, "w", newline="", encoding="utf-8") as fh:
        writer = csv.writer(fh)
        writer.writerow(["clip", "frames", "saliency_keyframes", "method", "keyframes", "E",
                         "E_over_h2", "psnr_db"])
        writer.writerows(rows)


def evaluate_files(paths: list[Path], out: Path,
                   progress: Callable[[int, int, Path], None] | None = None) -> list[Path]:
    """Evaluate every clip and write the Markdown + CSV tables into `out`."""
    out.mkdir(parents=True, exist_ok=True)
    rows, errors = [], []
    for i, path in enumerate(paths):
        if progress:
            progress(i, len(paths), path)
        try:
            rows.append(evaluate_clip(path))
        except StreamkeyError as exc:
            errors.append(f"{path}: {exc}")
    if not rows:
        raise StreamkeyError("no clip could be evaluated: " + "; ".join(errors))
    written = _write_equal(rows, out) + _write_natural(rows, out)
    if errors:
        err_path = out / "errors.txt"
        err_path.write_text("\n".join(errors) + "\n", encoding="utf-8")
        written.append(err_path)
    return written
