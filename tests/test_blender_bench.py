"""Reduce Keys against Blender's own tools over the shared clips, by Blender's evaluation.

The full bench (blender/bench.py, hours on this shared machine: the Graph Editor's Decimate
alone takes up to ten minutes a run on the longest clips) is too long for a test run. So the
acceptance criteria are checked on the committed rows file (blender/bench_rows.jsonl, all 35
shared clips), the README's table is checked to be generated from it, and one BVH clip and
one AMC clip are measured live (slow) and compared with their committed rows."""

from __future__ import annotations

import importlib.util
import statistics
from typing import Any

import pytest
from blender_helpers import BLENDER_DIR, require_bpy
from cmu import clips

bpy = require_bpy()

# Blender's BVH importer leaves its file to the garbage collector (a ResourceWarning there).
pytestmark = pytest.mark.filterwarnings(
    r"ignore:Exception ignored in. <_io.FileIO name='.*\.bvh':"
    "pytest.PytestUnraisableExceptionWarning")


def _bench() -> Any:
    spec = importlib.util.spec_from_file_location("blender_bench", BLENDER_DIR / "bench.py")
    assert spec and spec.loader
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


bench = _bench()
ROWS = bench.read_rows()
SHARED = sorted(name.removesuffix(".bvh") for name in clips())


def _clips_meeting(test: Any) -> tuple[int, int]:
    met: dict[str, bool] = {}
    for r in ROWS:
        met[r["clip"]] = met.get(r["clip"], True) and bool(test(r))
    return sum(met.values()), len(met)


def test_rows_are_of_shared_clips_and_the_readme_table_is_generated_from_them() -> None:
    """Every row is a shared clip's; README.md's table is `bench.py --docs`'s output."""
    assert ROWS and {r["clip"] for r in ROWS} <= set(SHARED)
    text = (BLENDER_DIR / "README.md").read_text(encoding="utf-8")
    assert f"{bench.START}\n{bench.table(ROWS)}{bench.END}" in text


def test_every_shared_clip_is_measured() -> None:
    """The rows cover every shared clip, BVH and AMC."""
    assert sorted({r["clip"] for r in ROWS}) == SHARED


def test_reduce_keys_beats_bake_action_on_95_percent_of_the_clips() -> None:
    """FIT's error below Bake Action's uniform poses at the same pose count."""
    met, total = _clips_meeting(lambda r: r["fit"] < r["bake"])
    assert met >= 0.95 * total


def test_reduce_keys_needs_a_fifth_of_decimates_frames_at_its_error_on_90_percent() -> None:
    """At Decimate's error, FIT's keyed frames at most 1/5 of Decimate's."""
    met, total = _clips_meeting(lambda r: r["equal_error_frames"] * 5 <= r["decimate_frames"])
    assert met >= 0.9 * total


def test_reduce_keys_error_within_one_and_a_half_decimates_on_the_median_clip() -> None:
    """At equal total keyframe points, FIT's error / Decimate's on the median clip."""
    per_clip: dict[str, list[float]] = {}
    for r in ROWS:
        per_clip.setdefault(r["clip"], []).append(r["fit"] / r["decimate"])
    assert statistics.median(statistics.median(v) for v in per_clip.values()) <= 1.5


@pytest.mark.slow
@pytest.mark.parametrize("clip", ["09_06", "09_06.amc"])
def test_a_live_measurement_agrees_with_its_committed_row(clip: str) -> None:
    """The bench run now on a short clip (BVH, and AMC through streamkey's BVH export)
    gives the committed row's numbers (Blender, optimal and Decimate are deterministic)."""
    (row,) = bench.measure_clip(clip, [16])
    (committed,) = [r for r in ROWS if r["clip"] == clip and r["K"] == row["K"]]
    for name in ("bake", "linear", "auto", "fit", "decimate", "streamkey_linear"):
        assert row[name] == pytest.approx(committed[name], rel=6e-3), name
    for name in ("points", "decimate_frames", "equal_error_frames"):
        assert row[name] == committed[name], name
    if clip.endswith(".amc"):
        assert row["amc_round_trip"] < bench.ROUND_TRIP_TOLERANCE
