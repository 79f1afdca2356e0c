"""Evaluation: reconstruction, thesis E (eq. 4.1) and PSNR (eq. 4.2), F-measure, error curves."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest
from cmu import DATA, ROOT, clips
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import maximum_bipartite_matching
from scipy.spatial.transform import Rotation

from streamkey import evaluate
from streamkey.amc import read_motion
from streamkey.errors import UsageError
from streamkey.methods import baselines
from streamkey.motion import Motion

CLIPS = clips()
RESULTS = ROOT / "results"
CROP = 1200  # error curves use the first 10 s of a clip (the longest clips run 43 s)
AXES = {"Xrotation": "X", "Yrotation": "Y", "Zrotation": "Z"}


@cache
def load(name: str) -> Motion:
    """A shared clip, BVH or AMC."""
    return read_motion(DATA / name)


def cropped(name: str) -> Motion:
    m = load(name)
    end = min(m.n_frames, m.first_frame + CROP)
    return Motion(m.skeleton, m.channels[:end], m.fps, m.first_frame, m.name)


# --- an independent per-frame reference: scipy Rotation per frame, plain loops ---------------

def joint_sequences(m: Motion) -> list[tuple[str, list[int]]]:
    out = []
    for j, order in enumerate(m.skeleton.rotation_order):
        out.append(("".join(AXES[c] for c in order),
                    [m.skeleton.channel_index(j, c) for c in order]))
    return out


def reference_reconstruction(m: Motion, keys: np.ndarray, mode: str) -> np.ndarray:
    """Per-frame reconstruction: scipy Rotation slerp via rotation vectors, one frame at a time;
    the first and last captured frames are keys whatever `keys` holds (so that E compares
    with other tools and with users' own reconstructions)."""
    raw = m.channels[m.first_frame :]
    keys = np.array(sorted({0, len(raw) - 1, *keys.tolist()}))
    rot = m.skeleton.rotation_columns()
    x = raw.copy()
    x[:, rot] = np.unwrap(raw[:, rot], period=360.0, axis=0)
    out = raw.copy()
    for i in range(len(raw)):
        if i in set(keys.tolist()):
            continue
        a = keys[keys <= i].max() if np.any(keys <= i) else keys[0]
        b = keys[keys >= i].min() if np.any(keys >= i) else keys[-1]
        t = (i - a) / (b - a) if b > a else 0.0
        out[i] = x[a] + t * (x[b] - x[a])
        if mode != "slerp":
            continue
        for seq, cols in joint_sequences(m):
            if len(seq) != 3:
                continue
            r0 = Rotation.from_euler(seq, x[a, cols], degrees=True)
            r1 = Rotation.from_euler(seq, x[b, cols], degrees=True)
            e = (r0 * Rotation.from_rotvec(t * (r0.inv() * r1).as_rotvec())).as_euler(
                seq, degrees=True)
            ref = out[i, cols]
            best = None
            for cand in (e, np.array([e[0] + 180.0, 180.0 - e[1], e[2] + 180.0])):
                cand = cand + 360.0 * np.round((ref - cand) / 360.0)
                if best is None or np.sum((cand - ref) ** 2) < np.sum((best - ref) ** 2):
                    best = cand
            out[i, cols] = best
    return out


def reference_positions(m: Motion, channels: np.ndarray) -> np.ndarray:
    """Root-relative positions of the joints (no End Sites), one frame at a time."""
    sk = m.skeleton
    seqs = joint_sequences(m)
    pos_cols = [sk.channel_index(0, c) for c in ("Xposition", "Yposition", "Zposition")]
    out = []
    for row in channels:
        world, pos = [], []
        for j in range(sk.n_joints):
            seq, cols = seqs[j]
            local = (Rotation.from_euler(seq, row[cols], degrees=True).as_matrix() if seq
                     else np.eye(3))
            pre = sk.pre_rotations[j]
            if pre is not None:
                local = pre @ local @ pre.T
            p = sk.parents[j]
            if p < 0:
                root = sk.offsets[0] + np.array([row[c] if c is not None else 0.0
                                                 for c in pos_cols])
                world.append(local)
                pos.append(root)
            else:
                world.append(world[p] @ local)
                pos.append(pos[p] + world[p] @ sk.offsets[j])
        pts = np.array(pos)
        out.append(pts - pts[0])
    return np.array(out)


def reference_scores(m: Motion, keys: np.ndarray, mode: str) -> tuple[float, float]:
    """(E, PSNR) from the per-frame reference."""
    rec = reference_reconstruction(m, keys, mode)
    orig = m.channels[m.first_frame :]
    e = float(np.mean(np.sum((reference_positions(m, rec) - reference_positions(m, orig)) ** 2,
                             axis=-1)))
    sq = []
    for r, o in zip(rec, orig, strict=True):
        for seq, cols in joint_sequences(m):
            if not seq:
                continue
            cands = [r[cols]]
            if len(set(seq)) == 3:  # the other Euler triple of the same rotation
                cands.append(np.array([r[cols[0]] + 180.0, 180.0 - r[cols[1]],
                                       r[cols[2]] + 180.0]))
            d = [(c - o[cols] + 180.0) % 360.0 - 180.0 for c in cands]
            sq.extend(min(d, key=lambda x: float(np.sum(x * x))) ** 2)
    return e, 20.0 * np.log10(360.0 / np.sqrt(np.mean(sq)))


@pytest.mark.parametrize("name", ["07_01.bvh", "05_11.amc"])
@pytest.mark.parametrize("mode", evaluate.MODES)
def test_error_and_psnr_agree_with_an_independent_per_frame_computation(name, mode):
    m = load(name)
    end = m.first_frame + 200  # a per-frame loop: keep it short
    m = Motion(m.skeleton, m.channels[:end], m.fps, m.first_frame, m.name)
    keys = baselines.decimate(m, 12).frames[1:-1]  # the ends are added by the definition
    e_ref, psnr_ref = reference_scores(m, keys - m.first_frame, mode)
    scores = evaluate.Evaluator(m).score(keys, mode)
    assert scores.error == pytest.approx(e_ref, rel=1e-9)
    assert scores.psnr == pytest.approx(psnr_ref, rel=1e-9)
    assert scores.error_normalised == pytest.approx(
        e_ref / evaluate.Evaluator(m).body_height ** 2, rel=1e-9)
    rec = evaluate.reconstruct(m, keys, mode)
    assert evaluate.error_e(m, rec) == pytest.approx(e_ref, rel=1e-9)
    assert evaluate.psnr(m, rec) == pytest.approx(psnr_ref, rel=1e-9)


def test_error_is_exactly_zero_when_every_frame_is_a_keyframe_on_every_clip():
    for name in CLIPS:
        m = load(name)
        rec = evaluate.reconstruct(m, np.arange(m.first_frame, m.n_frames))
        assert np.array_equal(rec, m.channels), name
    for name in ("07_01.bvh", "131_03.bvh", "09_06.amc"):  # the three skeleton families
        m = load(name)
        ev = evaluate.Evaluator(m)
        scores = ev.score(np.arange(m.first_frame, m.n_frames))
        assert scores.error == 0.0 and scores.psnr == float("inf"), name


def test_reconstruction_copies_keyframes_and_the_reference_frame():
    m = load("02_01.bvh")
    keys = baselines.uniform(m, 9).frames
    for mode in evaluate.MODES:
        rec = evaluate.reconstruct(m, keys, mode)
        assert np.array_equal(rec[keys], m.channels[keys])
        assert np.array_equal(rec[0], m.channels[0])  # T-pose reference frame, never scored


def test_first_and_last_captured_frames_are_keys_of_every_reconstruction():
    m = load("07_01.bvh")  # frame 0 is the T-pose reference frame
    interior = baselines.uniform(m, 12).frames[1:-1] + 3  # neither end is a key
    last = m.n_frames - 1
    for mode in evaluate.MODES:
        rec = evaluate.reconstruct(m, interior, mode)
        assert np.array_equal(rec[[m.first_frame, last]], m.channels[[m.first_frame, last]])
        assert np.array_equal(rec[interior], m.channels[interior])
        assert not np.allclose(rec[m.first_frame + 1], rec[m.first_frame])  # interpolated,
        assert not np.allclose(rec[last - 1], rec[last])  # not held from the nearest key
    ev = evaluate.Evaluator(m)
    scores = ev.score(interior)
    assert scores.count == len(interior) + 2
    with_ends = np.concatenate([[m.first_frame], interior, [last]])
    assert scores == ev.score(with_ends)


def test_error_counts_joints_not_end_sites():
    m = load("06_15.bvh")
    sk = m.skeleton
    leaves = [j for j in sk.end_sites if j not in sk.parents]  # a rotation moves End Sites only
    assert {sk.names[j] for j in leaves} >= {"Head", "LThumb", "RThumb", "LeftToeBase"}
    bent = m.channels.copy()
    cols = [sk.channel_index(j, c) for j in leaves for c in sk.rotation_order[j]]
    bent[m.first_frame :, cols] += 30.0
    ev = evaluate.Evaluator(m)
    assert ev.error_e(bent) == 0.0  # End Sites moved, every joint stayed
    assert ev.psnr(bent) < 60.0  # the rotations are wrong
    bent[m.first_frame :, sk.channel_index(sk.index("LeftHand"), "Zrotation")] += 30.0
    assert ev.error_e(bent) > 0.0


def test_psnr_scores_the_euler_triple_nearest_the_original():
    m = load("06_15.bvh")  # LThumb jumps up to 180 degrees between frames (near gimbal)
    sk = m.skeleton
    ev = evaluate.Evaluator(m)
    # the same rotations written as the other Euler triple (a + 180, 180 - b, c + 180)
    other = m.channels.copy()
    for j, order in enumerate(sk.rotation_order):
        if len(set(order)) == 3:
            c = [sk.channel_index(j, a) for a in order]
            other[:, c] = other[:, c] + np.array([180.0, 0.0, 180.0])
            other[:, c[1]] = 180.0 - m.channels[:, c[1]]
    assert ev.error_e(other) < 1e-20 and ev.psnr(other) > 200.0
    # a slerp reconstruction writes LThumb on the branch nearest the interpolated keys;
    # scored on the branch nearest the original, PSNR rises by > 1 dB (29.9 -> 31.4 dB)
    rec = evaluate.reconstruct(m, baselines.uniform(m, 20))
    cols = sk.rotation_columns()
    d = np.mod(rec[m.first_frame :, cols] - m.channels[m.first_frame :, cols] + 180.0,
               360.0) - 180.0
    naive = 20.0 * np.log10(360.0 / np.sqrt(np.mean(d * d)))
    assert ev.psnr(rec) > naive + 1.0
    j = sk.index("LThumb")
    c = [sk.channel_index(j, a) for a in sk.rotation_order[j]]
    seq = "".join(AXES[a] for a in sk.rotation_order[j])
    scored = evaluate._nearest_euler(rec[m.first_frame :, c], m.channels[m.first_frame :, c])
    changed = np.flatnonzero(np.abs(scored - rec[m.first_frame :, c]).max(axis=1) > 1.0)
    assert len(changed) > 20  # frames where the other triple is the nearer one
    r0 = Rotation.from_euler(seq, rec[m.first_frame :, c][changed], degrees=True)
    r1 = Rotation.from_euler(seq, scored[changed], degrees=True)
    assert np.allclose(r0.as_matrix(), r1.as_matrix(), atol=1e-9)  # the same rotations


def counts_for(n: int) -> list[int]:
    """Doubling series 8, 16, 32, ... up to an eighth of the frames (the thesis keeps 3-13 %)."""
    return [8 * 2**i for i in range(12) if 8 * 2**i <= max(n // 8, 16)]


@pytest.mark.slow
def test_error_falls_along_a_doubling_series_of_counts_on_every_clip():
    methods = ("uniform", "decimation", "simplification")
    lines = ["# Reconstruction error along a doubling series of keyframe counts", "",
             "Written by tests/test_evaluate.py. Slerp reconstruction; E = thesis eq. 4.1 "
             "(mean squared root-relative point distance, file units^2), E/h^2 = E divided by "
             f"body height squared, PSNR = eq. 4.2 (dB, Euler space). First {CROP} captured "
             "frames of each clip. Decimation and simplification in channel space.", "",
             "| clip | frames | K | " + " | ".join(f"E/h^2 {m}" for m in methods)
             + " | " + " | ".join(f"PSNR {m}" for m in methods) + " |",
             "|---" * (3 + 2 * len(methods)) + "|"]
    failures = []
    wins = {me: [0, 0, 0] for me in methods[1:]}
    for name in CLIPS:
        m = cropped(name)
        n = m.n_frames - m.first_frame
        ks = counts_for(n)
        curve = evaluate.error_curve(m, ks, methods)
        for i, k in enumerate(ks):
            lines.append(f"| {name} | {n} | {k} | "
                         + " | ".join(f"{curve[me][i].error_normalised:.3g}" for me in methods)
                         + " | " + " | ".join(f"{curve[me][i].psnr:.1f}" for me in methods)
                         + " |")
        for me in ("uniform", "decimation"):
            if not curve[me][-1].error < curve[me][0].error:
                failures.append((name, me))
        for i in range(len(ks)):
            for me in methods[1:]:
                wins[me][0] += curve[me][i].error < curve["uniform"][i].error
                wins[me][1] += curve[me][i].psnr > curve["uniform"][i].psnr
                wins[me][2] += 1
    lines += ["", "Against uniform sampling at the same K, over every (clip, K) row above:"]
    lines += [f"- {me}: lower E in {w[0]} of {w[2]}, higher PSNR in {w[1]} of {w[2]}."
              for me, w in wins.items()]
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "error_curves.md").write_text("\n".join(lines) + "\n", encoding="utf-8")
    assert not failures


def test_compare_at_equal_count_forces_every_method_to_k():
    m = load("07_12.bvh")
    table = evaluate.compare_at_equal_count(m, evaluate.METHODS, 20)
    assert set(table) == set(evaluate.METHODS)
    for scores in table.values():
        assert scores.count == 20 and scores.error > 0 and np.isfinite(scores.psnr)
    with pytest.raises(UsageError):
        evaluate.compare_at_equal_count(m, {"bad": lambda mo, k: baselines.uniform(mo, k + 1)},
                                        20)


frame_lists = st.lists(st.integers(0, 200), max_size=25, unique=True)


@settings(max_examples=200, deadline=None)
@given(a=frame_lists, b=frame_lists, tol=st.integers(0, 12))
def test_one_to_one_matching_is_maximum(a, b, tol):
    tp, p, r, f1 = evaluate.match_one_to_one(a, b, tol)
    if a and b:
        adj = csr_matrix(np.abs(np.subtract.outer(a, b)) <= tol)
        best = int(np.sum(maximum_bipartite_matching(adj, perm_type="column") >= 0))
    else:
        best = 0
    assert tp == best
    assert p == (tp / len(a) if a else 1.0) and r == (tp / len(b) if b else 1.0)
    assert 0.0 <= f1 <= 1.0


def test_f_measure_uses_a_quarter_of_the_keypose_interval():
    truth = [10, 50, 90, 130]  # interval 40: tolerance 10
    assert evaluate.f_measure([12, 58, 100, 131], truth) == (1.0, 1.0, 1.0)
    p, r, f1 = evaluate.f_measure([21, 50, 90], truth)
    assert (p, r) == (2 / 3, 2 / 4) and f1 == pytest.approx(2 * p * r / (p + r))
    with pytest.raises(UsageError):
        evaluate.f_measure([1], [5])


def test_bad_keyframes_and_modes_raise_usage_error():
    m = load("07_01.bvh")
    with pytest.raises(UsageError):
        evaluate.reconstruct(m, [0, 5, 10])  # frame 0 is the reference frame
    with pytest.raises(UsageError):
        evaluate.reconstruct(m, [1, 10], mode="cubic")
    with pytest.raises(UsageError):
        evaluate.reconstruct(m, [])
