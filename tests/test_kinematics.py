from __future__ import annotations

import numpy as np
import pytest
from cmu import DATA, clips
from scipy.spatial.transform import Rotation

from streamkey.bvh import read_bvh
from streamkey.features import compute_features
from streamkey.kinematics import body_height, forward_kinematics, pelvis_frame


def per_frame_fk(motion, frame):
    """Independent FK: one frame, scipy Rotation, a loop over joints."""
    sk = motion.skeleton
    row = motion.channels[frame]
    world, pos = [], []
    for j in range(sk.n_joints):
        names = sk.channels[j]
        start = sk.channel_start[j]
        rot = [(c[0], row[start + i]) for i, c in enumerate(names) if c.endswith("rotation")]
        r = Rotation.from_euler("".join(a for a, _ in rot) or "X", [v for _, v in rot] or [0.0],
                                degrees=True)
        if sk.parents[j] < 0:
            p = sk.offsets[j] + np.array([row[start + names.index(c)] if c in names else 0.0
                                          for c in ("Xposition", "Yposition", "Zposition")])
            world.append(r)
        else:
            par = sk.parents[j]
            p = pos[par] + world[par].apply(sk.offsets[j])
            world.append(world[par] * r)
        pos.append(p)
    return np.array(pos), world[0].as_matrix()


@pytest.mark.parametrize("name", ["07_01.bvh", "131_01.bvh", "16_11.bvh", "05_06.bvh"])
def test_vectorised_fk_matches_per_frame_scipy_computation(name):
    motion = read_bvh(DATA / name)
    fk = forward_kinematics(motion.skeleton, motion.channels)
    for frame in np.linspace(0, motion.n_frames - 1, 7).astype(int):
        expected, root = per_frame_fk(motion, frame)
        np.testing.assert_allclose(fk.positions[frame, : motion.skeleton.n_joints], expected,
                                   atol=1e-9)
        np.testing.assert_allclose(fk.root_rotation[frame], root, atol=1e-12)


@pytest.mark.parametrize("name", clips("bvh"))
def test_bone_lengths_stay_constant_over_every_frame(name):
    motion = read_bvh(DATA / name)
    fk = forward_kinematics(motion.skeleton, motion.channels)
    sk = motion.skeleton
    for j, parent in enumerate(sk.parents):
        if parent < 0:
            continue
        length = np.linalg.norm(fk.positions[:, j] - fk.positions[:, parent], axis=1)
        np.testing.assert_allclose(length, np.linalg.norm(sk.offsets[j]), atol=1e-9)


@pytest.mark.numeric
def test_fk_of_any_block_split_is_bit_identical():
    motion = read_bvh(DATA / "05_06.bvh")
    whole = forward_kinematics(motion.skeleton, motion.channels).positions
    parts = [forward_kinematics(motion.skeleton, motion.channels[i : i + k]).positions
             for i, k in zip(range(0, 886, 1), [1] * 886, strict=True)][:40]
    np.testing.assert_array_equal(np.concatenate(parts), whole[:40])
    chunked = forward_kinematics(motion.skeleton, motion.channels, chunk=37).positions
    np.testing.assert_array_equal(chunked, whole)


def test_pelvis_frame_positions_are_invariant_to_root_motion():
    motion = read_bvh(DATA / "07_01.bvh")
    fk = forward_kinematics(motion.skeleton, motion.channels)
    pelvis = pelvis_frame(fk)
    np.testing.assert_allclose(pelvis[:, 0], 0.0, atol=1e-12)
    moved = motion.channels.copy()
    moved[:, :3] += [100.0, 0.0, -50.0]
    again = pelvis_frame(forward_kinematics(motion.skeleton, moved))
    np.testing.assert_allclose(again, pelvis, atol=1e-9)


def test_features_give_foot_heights_near_the_floor_during_a_walk():
    motion = read_bvh(DATA / "07_01.bvh")
    feats = compute_features(motion)
    feet = feats.foot_heights[motion.first_frame :]
    height = body_height(motion.skeleton)
    assert 20 < height < 30  # CMU units (about 0.0564 m each)
    # Each ankle touches its lowest level for part of the walk and lifts during swing.
    for side in range(2):
        assert np.ptp(feet[:, side]) > 0.03 * height


@pytest.mark.numeric
def test_joint_heights_of_a_few_joints_equal_full_fk_bit_for_bit():
    from streamkey.kinematics import joint_heights

    for name in ("05_06.bvh", "16_11.bvh"):
        motion = read_bvh(DATA / name)
        full = forward_kinematics(motion.skeleton, motion.channels).positions
        for joints in ((4, 9), (0,), (len(motion.skeleton.names) - 1, 2)):
            got = joint_heights(motion.skeleton, motion.channels, joints)
            np.testing.assert_array_equal(got, full[:, list(joints), 1])
            one = joint_heights(motion.skeleton, motion.channels[7:8], joints)
            np.testing.assert_array_equal(one, full[7:8, list(joints), 1])


@pytest.mark.numeric
def test_unwrap_equals_numpy_for_any_layout_and_block_split():
    from streamkey.signal import unwrap_degrees, unwrap_step

    motion = read_bvh(DATA / "131_03.bvh")
    x = motion.channels[:, motion.skeleton.rotation_columns()]
    rng = np.random.default_rng(5)
    jumpy = np.cumsum(rng.normal(0, 150, (3000, 6)), axis=0) % 360 - 180
    for angles in (x, np.asfortranarray(x), jumpy):
        whole = unwrap_degrees(angles)
        np.testing.assert_array_equal(whole, np.unwrap(angles, period=360, axis=0))
        prev = off = None
        parts = []
        for lo, hi in ((0, 1), (1, 9), (9, 700), (700, len(angles))):
            out, prev, off = unwrap_step(angles[lo:hi], prev, off)
            parts.append(out)
        np.testing.assert_array_equal(np.concatenate(parts), whole)


def test_one_frame_fk_and_features_equal_the_whole_clip_bit_for_bit_on_every_clip():
    """The one-frame path (online push) and the batched path (offline) give the same bits:
    positions, end sites, root rotation, ankle heights and unwrapped rotations."""
    from streamkey.amc import read_motion
    from streamkey.features import compute_features
    from streamkey.online import FeatureStage
    from streamkey.signal import unwrap_degrees

    for name in clips():
        motion = read_motion(DATA / name)
        feats = compute_features(motion, noise_cutoff_hz=None)  # as the bare stage: raw
        first = motion.first_frame  # the stream starts at the first captured frame
        rotations = unwrap_degrees(motion.channels[first:, motion.skeleton.rotation_columns()])
        stage = FeatureStage(motion.skeleton, motion.fps, noise_cutoff_hz=None)  # raw
        given = 0
        for frame in motion.frames():
            block = stage.compute([frame])  # the first frame comes out with the second (a
            for r, i in enumerate(block.seq.tolist()):  # lead frame would be dropped)
                j = i - first
                given += 1
                np.testing.assert_array_equal(block.rotations[r], rotations[j], err_msg=name)
                if j % 97 == 0:
                    np.testing.assert_array_equal(block.foot_heights[r], feats.foot_heights[i])
                    np.testing.assert_array_equal(block.positions[r], feats.fk.positions[i])
                    np.testing.assert_array_equal(block.pelvis_positions[r],
                                                  feats.pelvis_positions[i])
        assert given == motion.n_frames - first, name


def numpy_fk(skeleton, channels):
    """Reference FK in numpy: `euler_matrices` per joint, C·R·Cᵀ for an ASF axis, a loop over
    joints composing 3x3 products and offsets (what the compiled kernel replaces)."""
    from streamkey.kinematics import euler_matrices

    n, j = len(channels), skeleton.n_joints
    world = np.empty((n, j, 3, 3))
    pos = np.empty((n, j, 3))
    for q in range(j):
        order = skeleton.rotation_order[q]
        cols = [skeleton.channel_index(q, c) for c in order]
        local = euler_matrices(channels[:, cols], order)
        pre = skeleton.pre_rotations[q]
        if pre is not None:
            local = pre @ local @ pre.T
        p = skeleton.parents[q]
        if p < 0:
            world[:, q] = local
            pos[:, q] = skeleton.offsets[q]
            for a, c in enumerate(("Xposition", "Yposition", "Zposition")):
                col = skeleton.channel_index(q, c)
                if col is not None:
                    pos[:, q, a] += channels[:, col]
        else:
            world[:, q] = world[:, p] @ local
            pos[:, q] = pos[:, p] + (world[:, p] @ skeleton.offsets[q])
    ends = [pos[:, q] + world[:, q] @ np.asarray(skeleton.end_sites[q])
            for q in sorted(skeleton.end_sites)]
    return np.concatenate([pos, np.stack(ends, axis=1)], axis=1), world[:, 0]


@pytest.mark.numeric
@pytest.mark.parametrize("name", ["05_11.amc", "131_04.amc", "05_11.bvh", "16_11.bvh"])
def test_fk_kernel_matches_the_numpy_reference_with_and_without_asf_axes(name):
    """The kernel's explicit 3x3 arithmetic against numpy products: equal to rounding (a few
    ulps of the largest coordinate, ~1e-14 file units), on BVH and AMC (pre-rotations)."""
    from streamkey.amc import read_motion
    from streamkey.kinematics import local_rotations

    motion = read_motion(DATA / name)
    fk = forward_kinematics(motion.skeleton, motion.channels)
    positions, root = numpy_fk(motion.skeleton, motion.channels)
    scale = np.abs(positions).max()
    np.testing.assert_allclose(fk.positions, positions, rtol=0, atol=64 * np.spacing(scale))
    np.testing.assert_allclose(fk.root_rotation, root, rtol=0, atol=1e-15)
    sk = motion.skeleton
    local = local_rotations(sk, motion.channels)
    from streamkey.kinematics import euler_matrices

    for q in range(sk.n_joints):
        order = sk.rotation_order[q]
        ref = euler_matrices(motion.channels[:, [sk.channel_index(q, c) for c in order]], order)
        if sk.pre_rotations[q] is not None:
            ref = sk.pre_rotations[q] @ ref @ sk.pre_rotations[q].T
        np.testing.assert_allclose(local[:, q], ref, rtol=0, atol=1e-15)


@pytest.mark.numeric
def test_pelvis_frame_kernel_matches_numpy_and_any_subset_has_the_same_bits():
    from streamkey.kinematics import to_pelvis

    motion = read_bvh(DATA / "131_03.bvh")
    fk = forward_kinematics(motion.skeleton, motion.channels)
    full = pelvis_frame(fk, 0)
    ref = to_pelvis(fk.positions, fk.positions[:, 0], fk.root_rotation)
    np.testing.assert_allclose(full, ref, rtol=0, atol=64 * np.spacing(np.abs(ref).max()))
    points = np.array([20, 3, 35, 7])
    np.testing.assert_array_equal(pelvis_frame(fk, 0, points), full[:, points])


@pytest.mark.numeric
def test_fk_of_some_points_composes_their_chains_only_with_the_same_bits():
    from streamkey.kinematics import fk_points

    motion = read_bvh(DATA / "07_01.bvh")
    sk = motion.skeleton
    full = forward_kinematics(sk, motion.channels)
    ankle = sk.names.index("LeftFoot")
    head_end = sk.n_joints + sorted(sk.end_sites).index(sk.names.index("Head"))
    part = fk_points(sk, motion.channels, (ankle, head_end))
    assert {ankle, head_end, 0} <= part.valid and len(part.valid) < sk.n_joints // 2
    for q in part.valid:
        np.testing.assert_array_equal(part.positions[:, q], full.positions[:, q])
    np.testing.assert_array_equal(part.root_rotation, full.root_rotation)


@pytest.mark.numeric
def test_unwrap_kernel_equals_numpy_on_exact_half_turns_and_column_subsets():
    """np.unwrap's tie rule (a step of exactly ±180 is kept, +180 stays +180) and any column
    subset read straight from the channels, bit for bit."""
    from streamkey.signal import unwrap_columns, unwrap_degrees

    rng = np.random.default_rng(11)
    x = np.round(np.cumsum(rng.normal(0, 120, (2000, 5)), axis=0) % 360 - 180)
    x[10, 0], x[20, 1], x[30, 2], x[40, 3] = x[9, 0] + 180, x[19, 1] - 180, x[29, 2] + 540, -0.0
    for angles in (x, x[:, [4, 0]]):
        np.testing.assert_array_equal(unwrap_degrees(angles),
                                      np.unwrap(angles, period=360, axis=0))
    np.testing.assert_array_equal(unwrap_columns(x, np.array([3, 1])),
                                  np.unwrap(x[:, [3, 1]], period=360, axis=0))
    assert unwrap_columns(x[:0], np.array([1])).shape == (0, 1)


def test_body_height_from_offsets_equals_the_fk_zero_pose():
    from streamkey.amc import read_motion

    for name in ("05_06.bvh", "131_04.amc"):
        sk = read_motion(DATA / name).skeleton
        pts = forward_kinematics(sk, np.zeros((1, sk.n_channels))).positions[0]
        assert body_height(sk) == pts[:, 1].max() - pts[:, 1].min()


def test_warm_up_compiles_the_feature_kernels():
    from streamkey import jit, kinematics, signal
    from streamkey.online import FeatureStage

    jit.warm_up()
    kernels = (kinematics._fk_kernel, kinematics._pelvis_kernel, kinematics._local_kernel,
               signal.unwrap_into)
    assert all(k.compiled is not None and len(k.compiled.signatures) == 1 for k in kernels)
    # Every path of the offline and online features calls them with the warmed-up types:
    # nothing compiles on a stream's first frame.
    motion = read_bvh(DATA / "05_06.bvh")
    feats = compute_features(motion)
    feats.pelvis_positions  # noqa: B018
    feats.role_positions(("head", "left_ankle"))
    stage = FeatureStage(motion.skeleton, motion.fps, noise_cutoff_hz=None)  # raw
    for frames in (motion.frames()[:1], motion.frames()[1:5]):
        block = stage.compute(frames)
        block.foot_heights  # noqa: B018
        block.pelvis_points([3, 4])
        block.slice(0, 1).materialise()
    assert all(len(k.compiled.signatures) == 1 for k in kernels)


def test_feature_block_composes_only_what_the_stream_reads():
    """Channels only: no FK; ankle heights: the leg chains; pelvis points: their chains, the
    pelvis and the root; anything read once is composed in the same pass from the next block
    on; a one-off read (`keep=False`) is not; every value has full FK's bits."""
    from streamkey.online import FeatureStage
    from streamkey.roles import MIURA_ROLES

    motion = read_bvh(DATA / "16_11.bvh")
    frames = motion.frames()
    full = compute_features(motion, noise_cutoff_hz=None)  # as the bare stage: raw
    first = motion.first_frame
    stage = FeatureStage(motion.skeleton, motion.fps, noise_cutoff_hz=None)  # raw
    block = stage.compute(frames[:3])
    assert block.rotations.shape == (3, len(stage.rotation_columns)) and block._fk is None
    np.testing.assert_array_equal(block.foot_heights, full.foot_heights[first : first + 3])
    legs = block._fk.valid
    assert len(legs) < motion.skeleton.n_joints // 2
    joints = [stage.roles[r] for r in MIURA_ROLES]
    once = stage.compute(frames[3:4])
    np.testing.assert_array_equal(once.pelvis_points(joints[:4], keep=False),
                                  full.pelvis_points(joints[:4])[first + 3 : first + 4])
    assert stage.fk_points == frozenset(stage.roles[r] for r in ("left_ankle", "right_ankle"))
    block = stage.compute(frames[4:6])
    got = block.pelvis_points(joints)
    np.testing.assert_array_equal(got, full.pelvis_positions[first + 4 : first + 6, joints])
    np.testing.assert_array_equal(got, full.role_positions(MIURA_ROLES)[first + 4 : first + 6])
    assert legs < block._fk.valid and len(block._fk.valid) < motion.skeleton.n_joints
    nxt = stage.compute(frames[6:7])
    nxt.foot_heights  # noqa: B018 - one pass composes the legs and speed's joints
    assert nxt._fk.valid == block._fk.valid
    np.testing.assert_array_equal(nxt.positions, full.fk.positions[first + 6 : first + 7])
    assert stage.fk_points is None and nxt._fk.valid is None
