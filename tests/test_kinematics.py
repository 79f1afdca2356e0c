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
        feats = compute_features(motion)
        first = motion.first_frame  # the stream starts at the first captured frame
        rotations = unwrap_degrees(motion.channels[first:, motion.skeleton.rotation_columns()])
        stage = FeatureStage(motion.skeleton, motion.fps)
        for j, frame in enumerate(motion.frames()):
            block = stage.compute([frame])
            np.testing.assert_array_equal(block.rotations[0], rotations[j], err_msg=name)
            i = j + first
            if j % 97 == 0:
                np.testing.assert_array_equal(block.foot_heights[0], feats.foot_heights[i])
                np.testing.assert_array_equal(block.positions[0], feats.fk.positions[i])
                np.testing.assert_array_equal(block.pelvis_positions[0],
                                              feats.pelvis_positions[i])
