"""Reduce keys against Blender's own tools, measured inside Blender (bpy as a module).

    .venv/bin/python -P blender/bench.py [--clips 07_01,09_06,05_11.amc] [--counts 16,32]
        [--rows blender/bench_rows.jsonl] [--out results/blender.md]
    .venv/bin/python -P blender/bench.py --docs      # tables from the rows file, no measuring

For every clip (imported with Blender's BVH importer) and pose count K: streamkey `optimal`
picks K pose frames; the reduced action (LINEAR, AUTO-clamped Bezier, FIT Bezier) is
evaluated by Blender's depsgraph against the original (E in body heights squared, every
captured frame, every bone). Compared with Bake Action (uniform poses, the same pose count),
and with the Graph Editor's Decimate at the same total keyframe points as FIT, and at equal
error: the fewest FIT pose frames whose error is at most Decimate's (searched to within
`EQUAL_ERROR_GAP` of the pose count: the value is an upper bound on the fewest).

A clip named `NAME.amc` is a CMU AMC clip (skeleton `SS.asf` beside it): Blender has no AMC
importer, so it is written as BVH by streamkey's own export (`export_keyframes_bvh` with every
frame; the file's world joint positions are checked against the AMC reader's before use) and
that file is imported with Blender's BVH importer.

Every measured row is appended to the rows file (a row of the same clip and K replaced); the
tables in `blender/README.md` are regenerated from that file (between its `bench table`
markers), so no number in them is copied by hand.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bpy  # noqa: E402
import numpy as np  # noqa: E402
from streamkey_blender import keys, measure, rig  # noqa: E402

from streamkey.amc import read_amc  # noqa: E402
from streamkey.bvh import read_bvh  # noqa: E402
from streamkey.evaluate import error_e, reconstruct  # noqa: E402
from streamkey.export import export_keyframes_bvh  # noqa: E402
from streamkey.kinematics import body_height, forward_kinematics  # noqa: E402
from streamkey.motion import Motion  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "cmu"
SHORT_CLIPS = ["02_01", "02_03", "03_01", "06_06", "06_08", "06_15", "07_01", "07_05",
               "07_12", "08_01", "09_01", "09_06", "16_11", "05_11"]  # <= 600 frames
MID_CLIPS = ["06_02", "05_06", "131_01", "05_13", "05_02", "131_03", "06_12"]  # 600-1,300
LONG_CLIPS = ["05_18", "09_12", "02_07", "01_14", "02_10", "01_01", "01_11", "01_06"]  # 1,800+
AMC_CLIPS = ["09_06.amc", "35_01.amc", "07_05.amc", "05_11.amc", "131_04.amc", "49_18.amc"]
ROWS = Path(__file__).resolve().parent / "bench_rows.jsonl"
README = Path(__file__).resolve().parent / "README.md"
EQUAL_ERROR_GAP = 0.1  # the equal-error search stops when its bracket is this close
ROUND_TRIP_TOLERANCE = 1e-4  # AMC -> BVH: largest joint position change, body heights


def _position_change(a: Motion, b: Motion) -> float:
    """Largest world joint position difference of two motions, in body heights."""
    pa = forward_kinematics(a.skeleton, a.channels).positions
    pb = forward_kinematics(b.skeleton, b.channels).positions
    if pa.shape != pb.shape:
        raise ValueError(f"{a.name}: {pa.shape} joint positions against {pb.shape}")
    return float(np.max(np.abs(pa - pb)) / body_height(a.skeleton))


def amc_as_bvh(name: str, folder: Path) -> tuple[Path, float]:
    """The AMC clip `name` as a BVH file Blender's importer reads, and the largest change of a
    world joint position (body heights) from the AMC reader's: written by streamkey's export
    (`export_keyframes_bvh`, every frame, rotation channels padded to three for importers) and
    read back. A ValueError above `ROUND_TRIP_TOLERANCE`."""
    motion = read_amc(DATA / name)
    exported = folder / (Path(name).stem + "_export.bvh")
    export_keyframes_bvh(motion, np.arange(motion.n_frames), exported)
    path = exported
    change = _position_change(motion, read_bvh(exported))
    if change > ROUND_TRIP_TOLERANCE:
        raise ValueError(f"{name}: the BVH export moves a joint by {change:.3g} body heights")
    return path, change


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
                       target: float, low: int,
                       known: tuple[float, int] | None = None) -> tuple[int, int, int]:
    """Keyed frames of FIT reduction (optimal count search) with error <= target, and the
    search's bracket (a pose count that fails, one that holds): the first guess from the
    error's power law in the count (error ~ count^-3), then doubling or halving, then
    bisection until the bracket is within `EQUAL_ERROR_GAP` of the count. `known`: the error
    and keyed frames at `low` poses, already measured."""
    captured = motion.n_frames - motion.first_frame
    seen: dict[int, tuple[float, int]] = {} if known is None else {low: known}

    def fit(count: int) -> tuple[float, int]:
        if count not in seen:
            seen[count] = _fit_error(ctx, obj, act, motion, ref, start, count)
        return seen[count]

    err = fit(low)[0]
    guess = low * (err / target) ** (1 / 3) if target > 0 else float(captured)
    if err > target:
        lo, hi = low, min(captured, max(low + 1, math.ceil(guess)))
        while fit(hi)[0] > target and hi < captured:
            lo, hi = hi, min(2 * hi, captured)
    else:
        lo, hi = max(2, min(low - 1, math.floor(guess))), low
        while lo > 2 and fit(lo)[0] <= target:
            lo, hi = max(2, lo // 2), lo
        if fit(lo)[0] <= target:
            return fit(lo)[1], lo, lo
    while hi - lo > max(1, EQUAL_ERROR_GAP * hi):
        mid = (lo + hi) // 2
        if fit(mid)[0] <= target:
            hi = mid
        else:
            lo = mid
    return fit(hi)[1], lo, hi


def measure_clip(name: str, counts: list[int]) -> list[dict[str, Any]]:
    """Every row of the table for one clip (`NAME` a BVH clip, `NAME.amc` an AMC clip)."""
    round_trip = None
    with tempfile.TemporaryDirectory() as tmp:
        if name.endswith(".amc"):
            path, round_trip = amc_as_bvh(name, Path(tmp))
        else:
            path = DATA / f"{name}.bvh"
        obj = import_clip(path)
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
        row: dict[str, Any] = {"clip": name, "frames_captured": span + 1, "K": poses,
                               "bake_step": step,
                               "bake": measure.blender_error(ctx, obj, baked, ref)}
        if round_trip is not None:
            row["amc_round_trip"] = round_trip
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
        found, lo, hi = equal_error_frames(ctx, obj, act, motion, ref, start, row["decimate"],
                                           poses, (row["fit"], row["frames"]))
        row["equal_error_frames"] = found
        row["equal_error_poses"] = [lo, hi]
        rows.append(row)
        print(json.dumps(row), flush=True)
    return rows


def _count(rows: list[dict[str, Any]], test: Any) -> str:
    """'rows met of rows; clips met (every row) of clips'."""
    clips: dict[str, bool] = {}
    for r in rows:
        clips[r["clip"]] = clips.get(r["clip"], True) and bool(test(r))
    return (f"{sum(bool(test(r)) for r in rows)} of {len(rows)} rows,"
            f" {sum(clips.values())} of {len(clips)} clips")


def summary(rows: list[dict[str, Any]]) -> list[str]:
    """The acceptance lines: each criterion's rows and clips met, median and worst."""
    bake = [r["bake"] / r["fit"] for r in rows]
    fifth = [r["decimate_frames"] / r["equal_error_frames"] for r in rows]
    ratio = [r["fit"] / r["decimate"] for r in rows]
    per_clip: dict[str, list[float]] = {}
    for r in rows:
        per_clip.setdefault(r["clip"], []).append(r["fit"] / r["decimate"])
    clip_ratio = statistics.median(statistics.median(v) for v in per_clip.values())
    worst = max(rows, key=lambda r: r["fit"] / r["decimate"])
    lin = statistics.median(r["linear"] / r["streamkey_linear"] for r in rows)
    auto = statistics.median(r["auto"] / r["streamkey_slerp"] for r in rows)
    med = statistics.median
    return [f"- FIT beats Bake Action at the same pose count:"
            f" {_count(rows, lambda r: r['fit'] < r['bake'])} (Bake's error / FIT's: median"
            f" {med(bake):.3g}x, worst {min(bake):.3g}x)",
            f"- FIT needs <= 1/5 of Decimate's keyed frames at Decimate's error:"
            f" {_count(rows, lambda r: r['equal_error_frames'] * 5 <= r['decimate_frames'])}"
            f" (Decimate's frames / FIT's: median {med(fifth):.3g}x, worst {min(fifth):.3g}x)",
            f"- FIT / Decimate error at equal keyframe points: median {med(ratio):.3g} over"
            f" the rows, {clip_ratio:.3g} on the median clip; worst"
            f" {worst['fit'] / worst['decimate']:.3g} ({worst['clip']} at {worst['K']} poses);"
            f" within 1.5x on {_count(rows, lambda r: r['fit'] <= 1.5 * r['decimate'])}",
            f"- median Blender LINEAR / streamkey linear E: {lin:.3g}; Blender AUTO /"
            f" streamkey slerp E: {auto:.3g}"]


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
    lines += ["", *summary(rows)]
    return "\n".join(lines) + "\n"


def read_rows(path: Path = ROWS) -> list[dict[str, Any]]:
    """The rows file: one JSON row per line."""
    if not path.is_file():
        return []
    return [json.loads(line) for line in path.read_text(encoding="utf-8").splitlines()
            if line.strip()]


def add_rows(new: list[dict[str, Any]], path: Path = ROWS) -> list[dict[str, Any]]:
    """Append `new` to the rows file, replacing rows of the same clip and K."""
    keys = {(r["clip"], r["K"]) for r in new}
    rows = [r for r in read_rows(path) if (r["clip"], r["K"]) not in keys] + new
    path.write_text("".join(json.dumps(r) + "\n" for r in rows), encoding="utf-8")
    return rows


START = "<!-- bench table: generated by blender/bench.py --docs -->"
END = "<!-- end bench table -->"


def write_docs(rows: list[dict[str, Any]], readme: Path = README) -> None:
    """Replace the README's table (between the bench table markers) with `rows`'s."""
    text = readme.read_text(encoding="utf-8")
    head, rest = text.split(START, 1)
    _, tail = rest.split(END, 1)
    readme.write_text(f"{head}{START}\n{table(rows)}{END}{tail}", encoding="utf-8")


def main(argv: list[str] | None = None) -> int:
    """Measure the clips (appending to the rows file) and write the tables."""
    parser = argparse.ArgumentParser(prog="blender/bench.py")
    parser.add_argument("--clips", default=",".join(SHORT_CLIPS),
                        help="comma-separated clip names, NAME.amc for an AMC clip (default:"
                             f" the 14 of <= 600 frames; then {','.join(MID_CLIPS)}; then"
                             f" {','.join(LONG_CLIPS)}; AMC: {','.join(AMC_CLIPS)})")
    parser.add_argument("--counts", default="16,32")
    parser.add_argument("--rows", type=Path, default=ROWS, help="the rows file (JSON Lines)")
    parser.add_argument("--out", type=Path, help="also write this run's table here")
    parser.add_argument("--docs", action="store_true",
                        help="measure nothing: regenerate README.md's table from the rows file")
    parser.add_argument("--merge", type=Path, nargs="*", default=[],
                        help="measure nothing: add the JSON rows printed by other runs of this"
                             " script (their logs or rows files) to the rows file")
    args = parser.parse_args(argv)
    for log in args.merge:
        add_rows([json.loads(line) for line in log.read_text(encoding="utf-8").splitlines()
                  if line.startswith("{")], args.rows)
    if args.docs or args.merge:
        write_docs(read_rows(args.rows))
        return 0
    counts = [int(c) for c in args.counts.split(",")]
    rows = []
    for clip in args.clips.split(","):
        measured = measure_clip(clip, counts)
        add_rows(measured, args.rows)
        rows += measured
    text = table(rows)
    print(text)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text, encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
