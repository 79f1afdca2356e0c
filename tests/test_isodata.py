"""ISODATA clustering keyframes with adaptive thresholds (Zhang et al. 2013)."""

from __future__ import annotations

import csv
import math
from functools import cache

import numpy as np
import pytest
from cmu import DATA, ROOT, clips

from streamkey.amc import read_motion
from streamkey.errors import UsageError
from streamkey.evaluate import Evaluator
from streamkey.features import compute_features
from streamkey.keyframes import Keyframes
from streamkey.methods import isodata
from streamkey.motion import Motion

CLIPS = clips()
MORE_KEYS = isodata.CLUSTER_SECONDS / 2  # half the expected cluster duration: about twice K


def _descriptions() -> dict[str, str]:
    with open(DATA / "MANIFEST.csv", newline="", encoding="utf-8") as fh:
        return {r["file"]: r["description"] for r in csv.DictReader(fh)}


DESCRIPTION = _descriptions()
WALKS_AND_DANCES = [c for c in CLIPS if "walk" in DESCRIPTION[c].lower()
                    or "dance" in DESCRIPTION[c].lower()]


@cache
def load(name: str) -> Motion:
    return read_motion(DATA / name)


@cache
def keys(name: str, cluster_seconds: float = isodata.CLUSTER_SECONDS) -> Keyframes:
    return isodata.extract(load(name), cluster_seconds=cluster_seconds)


@cache
def evaluator(name: str) -> Evaluator:
    return Evaluator(load(name))


# --- building blocks -------------------------------------------------------------------------

def test_min_dispersion_split_puts_the_threshold_at_the_gap_between_two_levels() -> None:
    d = np.array([1.0, 1.2, 0.9, 5.0, 1.1, 5.3, 1.0, 4.8, 0.95])
    index, d_t = isodata.min_dispersion_split(d)
    assert d_t == 4.8 and index == 7  # the smallest value of the high class, and its pair


def test_min_dispersion_split_ignores_far_out_glitches_only_with_the_fence() -> None:
    rng = np.random.default_rng(1)
    d = np.concatenate([rng.normal(2.0, 0.3, 300), rng.normal(5.0, 0.3, 30), [80.0, 90.0]])
    assert isodata.min_dispersion_split(d)[1] == 80.0  # the paper's plain cut isolates glitches
    _, d_t = isodata.min_dispersion_split(d, fence=isodata.OUTLIER_FENCE)
    assert 3.0 < d_t < 5.0


def test_joint_weights_fall_with_depth_in_the_tree() -> None:
    skel = load("07_01.bvh").skeleton
    w = isodata.joint_weights(skel)
    assert w[0] == 1.0
    for j, p in enumerate(skel.parents):
        if p >= 0:
            assert w[j] < w[p]


def test_pose_distance_reads_the_rotation_angle_in_degrees_for_small_steps() -> None:
    motion = load("07_01.bvh")
    ch = motion.channels[motion.first_frame : motion.first_frame + 2].copy()
    ch[1] = ch[0]
    col = motion.skeleton.channel_index(0, "Yrotation")
    ch[1, col] += 2.0  # turn the root by 2 degrees
    q = isodata.pose_vectors(motion.skeleton, ch)
    step = np.linalg.norm(q[1] - q[0], axis=1)
    assert step[0] == pytest.approx(2.0, rel=1e-3)
    assert np.all(step[1:] < 1e-9)


def test_initial_classes_break_at_large_steps_and_far_from_the_class_centre() -> None:
    y = np.array([[0.0], [0.1], [0.2], [5.0], [5.2], [5.4], [5.6], [5.9]])
    adjacent = np.abs(np.diff(y[:, 0]))
    starts = isodata.initial_classes(y, adjacent, 0.5)
    # the jump starts a class at 3; at 7, 5.9 is 0.6 from the centre 5.3 of frames 3-6
    assert starts.tolist() == [0, 3, 7]


def python_initial_classes(y: np.ndarray, adjacent: np.ndarray, d_t: float,
                           scale: np.ndarray) -> np.ndarray:
    """The paper's two rules as a plain loop over frames (the numpy form the kernel replaced:
    the same row products, centre division and `diff @ diff`)."""
    starts, total, count = [0], None, 0
    for f, row in enumerate(y * scale):
        if total is None:
            total, count = row.copy(), 1
            continue
        diff = row - total / count
        if adjacent[f - 1] >= d_t or math.sqrt(diff @ diff) >= d_t:
            starts.append(f)
            total, count = row.copy(), 1
        else:
            total += row
            count += 1
    return np.array(starts)


@pytest.mark.numeric
@pytest.mark.parametrize("name", ["05_06.bvh", "49_18.amc", "131_03.bvh"])
def test_initial_classes_kernel_equals_the_frame_by_frame_loop(name: str) -> None:
    motion = load(name)
    x = isodata.pose_vectors(motion.skeleton, motion.channels[motion.first_frame :])
    x = x.reshape(len(x), -1)
    scale = np.repeat(np.sqrt(isodata.joint_weights(motion.skeleton)), 4)
    adjacent = np.linalg.norm(np.diff(x * scale, axis=0), axis=1)
    d_t = isodata.min_dispersion_split(adjacent, isodata.OUTLIER_FENCE)[1]
    for threshold in (d_t, d_t / 2, d_t / 4):
        starts = isodata.initial_classes(x, adjacent, threshold, scale)
        assert len(starts) > 10
        np.testing.assert_array_equal(starts, python_initial_classes(x, adjacent, threshold,
                                                                     scale))


def test_derived_parameters_follow_the_papers_120_hz_values() -> None:
    p = isodata.derived_parameters(2500, 120.0, isodata.CLUSTER_SECONDS)
    assert p == {"K": 100, "O_N": 25, "I": 13}  # I = ceil(N / 2K), eq. 6


# --- the method on real data -----------------------------------------------------------------

@pytest.mark.parametrize("name", CLIPS)
def test_isodata_returns_sorted_unique_captured_frames_on_every_clip(name: str) -> None:
    motion = load(name)
    k = keys(name)
    assert len(k) >= 2
    assert np.all(np.diff(k.frames) > 0)
    assert k.frames[0] >= motion.first_frame and k.frames[-1] < motion.n_frames
    for field in ("D_T", "O_s", "O_c", "K", "O_N", "I", "initial_classes"):
        assert field in k.info
    assert k.scores.sum() == motion.n_frames - motion.first_frame  # class sizes cover the clip


@pytest.mark.parametrize("name", CLIPS)
def test_isodata_error_falls_when_shorter_clusters_ask_for_more_keys(name: str) -> None:
    few, many = keys(name), keys(name, MORE_KEYS)
    ev = evaluator(name)
    assert len(many) > len(few)
    assert ev.score(many).error < ev.score(few).error


def test_isodata_selects_1_to_10_percent_on_walks_and_dances() -> None:
    """Zhang et al. Table 1: 3.1-4.4 % keyframes on five CMU clips at 120 Hz, with no
    per-clip parameter. The derived K (one cluster per 25 frames = 4 %) and the stop rule
    (K/2 <= count <= K) give 2-4 %; the band 1-10 % allows a factor of ~3 either side of the
    paper's range for the sampling of the stop rule and for clips unlike the paper's."""
    lines = ["| clip | description | frames | keyframes | % | K | D_T | O_s | initial |",
             "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    fractions = {}
    for name in WALKS_AND_DANCES:
        k, motion = keys(name), load(name)
        n = motion.n_frames - motion.first_frame
        fractions[name] = len(k) / n
        i = k.info
        lines.append(f"| {name} | {DESCRIPTION[name]} | {n} | {len(k)} | "
                     f"{100 * fractions[name]:.1f} | {i['K']} | {i['D_T']:.2f} | "
                     f"{i['O_s']:.1f} | {i['initial_classes']} |")
    out = ROOT / "results"
    out.mkdir(exist_ok=True)
    (out / "isodata_fractions.md").write_text(
        "# ISODATA keyframe fractions on the shared walks and dances (default parameters)\n\n"
        + "\n".join(lines) + "\n", encoding="utf-8")
    assert len(fractions) >= 10
    bad = {c: round(100 * f, 2) for c, f in fractions.items() if not 0.01 <= f <= 0.10}
    assert not bad


def test_isodata_reports_its_thresholds_to_the_log_only_when_verbose() -> None:
    motion = load("07_01.bvh")
    lines: list[str] = []
    k = isodata.extract(motion, verbose=True, log=lines.append)
    assert lines and "D_T=" in lines[0] and "O_s=" in lines[0]
    assert len(lines) == 1 + len(k.info["history"])
    quiet: list[str] = []
    isodata.extract(motion, log=quiet.append)
    assert quiet == []


def test_isodata_gives_the_same_keys_with_precomputed_features() -> None:
    motion = load("05_11.bvh")
    # the raw frames' features: isodata alone reads the raw channels (the CLI gives it the
    # filtered features, so its keys there are the filtered frames')
    raw = compute_features(motion, noise_cutoff_hz=None)
    with_features = isodata.extract(motion, features=raw)
    np.testing.assert_array_equal(with_features.frames, keys("05_11.bvh").frames)


def test_isodata_agrees_on_the_bvh_and_amc_copies_of_a_clip_within_a_few_keys() -> None:
    bvh, amc = keys("09_06.bvh"), keys("09_06.amc")
    assert abs(len(bvh) - len(amc)) <= 1


@pytest.mark.parametrize("bad", [{"cluster_seconds": 0.0}, {"cluster_seconds": float("nan")},
                                 {"max_merges": 0}, {"outlier_fence": -1.0}])
def test_isodata_rejects_bad_parameters(bad: dict[str, float]) -> None:
    with pytest.raises(UsageError):
        isodata.extract(load("07_01.bvh"), **bad)  # type: ignore[arg-type]


def numpy_initial_classes(y: np.ndarray, adjacent: np.ndarray, d_t: float,
                          scale: np.ndarray | None = None) -> np.ndarray:
    """`isodata.initial_classes` in the numpy form its kernel replaced."""
    return python_initial_classes(y, adjacent, d_t, np.ones(y.shape[1]) if scale is None
                                  else scale)


def numpy_prefix(st: isodata._Stats, idx: np.ndarray) -> np.ndarray:
    """`_Stats.prefix` in the numpy form its kernel replaced: one cumsum over every row."""
    cumulative = st.__dict__.get("numpy_cumsum")
    if cumulative is None:
        cumulative = np.concatenate([np.zeros((1, st.x.shape[1])),
                                     np.cumsum(st.x * st.scale, axis=0)])
        st.__dict__["numpy_cumsum"] = cumulative
    return cumulative[np.asarray(idx)]  # type: ignore[no-any-return]


def _result(k: Keyframes) -> dict[str, object]:
    return {"frames": k.frames.tolist(), "scores": k.scores.tolist(),
            "starts": np.asarray(k.info["class_starts"]).tolist(), "history": k.info["history"],
            "O_s": k.info["O_s"], "D_T": k.info["D_T"]}


@pytest.mark.slow
@pytest.mark.numeric
@pytest.mark.parametrize("name", CLIPS)
def test_isodata_gives_the_numpy_forms_result_on_every_shared_clip(
        name: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """Keyframes, class starts, thresholds and history bit for bit as with the numpy forms
    the kernels replaced (initial classes frame by frame, prefix sums by one cumsum), with
    and without precomputed features, both run here: numbers recorded on another machine
    would not do (numba's code and numpy's SIMD paths round differently on another CPU)."""
    motion = load(name)
    features = compute_features(motion)
    compiled = [isodata.extract(motion), isodata.extract(motion, features=features)]
    monkeypatch.setattr(isodata, "initial_classes", numpy_initial_classes)
    monkeypatch.setattr(isodata._Stats, "prefix", numpy_prefix)
    numpy_forms = [isodata.extract(motion), isodata.extract(motion, features=features)]
    for got, want in zip(compiled, numpy_forms, strict=True):
        assert _result(got) == _result(want)


@pytest.mark.numeric
def test_prefix_kernel_gives_the_running_sums_of_one_cumsum_bit_for_bit() -> None:
    motion = load("05_06.bvh")
    x = isodata.pose_vectors(motion.skeleton, motion.channels[motion.first_frame :])
    x = x.reshape(len(x), -1)
    scale = np.repeat(np.sqrt(isodata.joint_weights(motion.skeleton)), 4)
    st = isodata._Stats(x, scale)
    cumulative = np.concatenate([np.zeros((1, x.shape[1])), np.cumsum(x * scale, axis=0)])
    idx = np.array([0, 1, 7, 8, 9, len(x) - 1, len(x), 333, 16, 15])
    np.testing.assert_array_equal(st.prefix(idx), cumulative[idx])
    np.testing.assert_array_equal(st.prefix(np.arange(len(x) + 1)), cumulative)
