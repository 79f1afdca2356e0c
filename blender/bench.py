"""Reduce keys against Blender's own tools, measured inside Blender (bpy as a module).

    .venv/bin/python -P blender/bench.py [--clips 07_01,09_06] [--counts 16,32]
        [--out results/blender.md]

For every clip (imported with Blender's BVH importer) and pose count K: streamkey `optimal`
picks K pose frames; the reduced action (LINEAR, AUTO-clamped Bezier, FIT Bezier) is
evaluated by Blender's depsgraph against the original (E in body heights squared, every
captured frame, every bone). Compared with Bake Action (uniform poses, the same pose count),
and with the Graph Editor's Decimate at the same total keyframe points as FIT, and at equal
error: the fewest FIT pose frames whose error is at most Decimate's.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bpy  # noqa: E402
from streamkey_blender import keys, measure, rig  # noqa: E402

from streamkey.evaluate import error_e, reconstruct  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "cmu"
SHORT_CLIPS = ["02_01", "02_03", "03_01", "06_06", "06_08", "06_15", "07_01", "07_05",
               "07_12", "08_01", "09_01", "09_06", "16_11", "05_11"]  # <= 600 frames
MID_CLIPS = ["06_02", "05_06", "131_01", "05_13", "05_02", "131_03", "06_12"]  # 600-1,300


def import_clip(path: Path) -> Any:
    """A fresh scene holding only the clip, imported by Blender's BVH importer."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.import_anim.bvh(filepath=str(path), update_scene_fps=True,
                            update_scene_duration=True)
    return bpy.context.active_object


def _fit_error(ctx: Any, obj: Any, act: Any, motion: Any, ref: Any, start: int,
               count: int) -> tuple[float, int]:
    k = keys.find_keys(motion, "optimal", {"count": count})
    red = keys.reduce_action(act, [start + int(f) for f in k.frames], "FIT")
    err = measure.blender_error(ctx, obj, red.action, ref)
    n = measure.keyed_frames(red.action)
    bpy.data.actions.remove(red.action)
    return err, n


def equal_error_frames(ctx: Any, obj: Any, act: Any, motion: Any, ref: Any, start: int,
                       target: float, low: int) -> int:
    """Fewest keyed frames of FIT reduction (optimal count search) with error <= target."""
    captured = motion.n_frames - motion.first_frame
    seen: dict[int, tuple[float, int]] = {}

    def fit(count: int) -> tuple[float, int]:
        if count not in seen:
            seen[count] = _fit_error(ctx, obj, act, motion, ref, start, count)
        return seen[count]

    lo, hi = 2, low
    while fit(hi)[0] > target and hi < captured:
        lo, hi = hi, min(2 * hi, captured)
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if fit(mid)[0] <= target:
            hi = mid
        else:
            lo = mid
    return fit(hi)[1]


def measure_clip(name: str, counts: list[int]) -> list[dict[str, Any]]:
    """Every row of the table for one clip."""
    obj = import_clip(DATA / f"{name}.bvh")
    ctx = bpy.context
    act = obj.animation_data.action
    start = rig.action_frames(act).start
    motion = rig.armature_motion(ctx, obj)
    ref = measure.Reference(ctx, obj, motion, start)
    span = ref.frames.stop - 1 - ref.frames.start
    rows = []
    for count in counts:
        step = max(1, round(span / (count - 1)))
        baked = measure.bake_uniform(ctx, obj, step, ref.frames)
        poses = measure.keyed_frames(baked)
        row: dict[str, Any] = {"clip": name, "K": poses, "bake_step": step,
                               "bake": measure.blender_error(ctx, obj, baked, ref)}
        k = keys.find_keys(motion, "optimal", {"count": poses})
        row["streamkey_linear"] = error_e(motion, reconstruct(motion, k, mode="linear"),
                                          normalised=True)
        row["streamkey_slerp"] = error_e(motion, reconstruct(motion, k), normalised=True)
        frames = [start + int(f) for f in k.frames]
        for mode in keys.MODES:
            red = keys.reduce_action(act, frames, mode)
            row[mode.lower()] = measure.blender_error(ctx, obj, red.action, ref)
            row["points"] = red.points
            row["frames"] = measure.keyed_frames(red.action)
        t = time.perf_counter()
        total = measure.keyframe_points(act)
        dec = measure.decimate(ctx, obj, act, ratio=1.0 - row["points"] / total)
        row["decimate_s"] = round(time.perf_counter() - t, 1)
        row["decimate"] = measure.blender_error(ctx, obj, dec, ref)
        row["decimate_points"] = measure.keyframe_points(dec)
        row["decimate_frames"] = measure.keyed_frames(dec)
        row["equal_error_frames"] = equal_error_frames(ctx, obj, act, motion, ref, start,
                                                       row["decimate"], poses)
        rows.append(row)
        print(json.dumps(row), flush=True)
    return rows


def table(rows: list[dict[str, Any]]) -> str:
    """The markdown table and the summary lines."""
    head = ("| clip | K | Bake (uniform) | LINEAR | AUTO | FIT | streamkey E lin / slerp |"
            " points | Decimate same points | Decimate frames | FIT frames at Decimate's E |")
    lines = [head, "|" + "---|" * 11]
    for r in rows:
        lines.append(
            f"| {r['clip']} | {r['K']} | {r['bake']:.3g} | {r['linear']:.3g} | {r['auto']:.3g} |"
            f" {r['fit']:.3g} | {r['streamkey_linear']:.3g} / {r['streamkey_slerp']:.3g} |"
            f" {r['points']} | {r['decimate']:.3g} | {r['decimate_frames']} |"
            f" {r['equal_error_frames']} |")
    beats = sum(r["fit"] < r["bake"] for r in rows)
    fifth = sum(r["equal_error_frames"] * 5 <= r["decimate_frames"] for r in rows)
    ratio = statistics.median(r["fit"] / r["decimate"] for r in rows)
    lin = statistics.median(r["linear"] / r["streamkey_linear"] for r in rows)
    auto = statistics.median(r["auto"] / r["streamkey_slerp"] for r in rows)
    lines += ["", f"- FIT beats Bake Action at the same pose count: {beats} of {len(rows)} rows",
              f"- FIT needs <= 1/5 of Decimate's keyed frames at Decimate's error: {fifth} of"
              f" {len(rows)} rows",
              f"- median FIT / Decimate error at equal keyframe points: {ratio:.3g}",
              f"- median Blender LINEAR / streamkey linear E: {lin:.3g}; Blender AUTO /"
              f" streamkey slerp E: {auto:.3g}"]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    """Measure the clips and write the table."""
    parser = argparse.ArgumentParser(prog="blender/bench.py")
    parser.add_argument("--clips", default=",".join(SHORT_CLIPS),
                        help="comma-separated clip names (default: the 14 of <= 600 frames;"
                             f" the README's second group: {','.join(MID_CLIPS)})")
    parser.add_argument("--counts", default="16,32")
    parser.add_argument("--out", type=Path)
    args = parser.parse_args(argv)
    counts = [int(c) for c in args.counts.split(",")]
    rows = [r for clip in args.clips.split(",") for r in measure_clip(clip, counts)]
    text = table(rows)
    print(text)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text, encoding="utf-8")
        args.out.with_suffix(".json").write_text(json.dumps(rows, indent=1), encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
