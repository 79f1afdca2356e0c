from __future__ import annotations

import numpy as np
from cmu import DATA

from streamkey.bvh import read_bvh
from streamkey.motion import Frame
from streamkey.online import FeatureStage, StreamGuard


def frame(seq, value=0.0, n=4):
    return Frame(seq, seq / 120.0, np.full(n, float(value)))


def test_guard_passes_consecutive_frames_and_counts_nothing_else():
    guard = StreamGuard(4)
    for seq in range(5):
        clean, gaps, restart = guard.accept(frame(seq))
        assert [f.seq for f in clean] == [seq] and not gaps and not restart
    assert guard.counters.accepted == 5 and guard.counters.gaps == 0


def test_duplicates_and_out_of_order_frames_are_dropped_and_counted():
    guard = StreamGuard(4)
    for seq in (0, 1, 1, 2, 0, 3):
        guard.accept(frame(seq))
    assert guard.counters.duplicates == 1
    assert guard.counters.out_of_order == 1
    assert guard.last is not None and guard.last.seq == 3


def test_nan_inf_and_wrong_channel_counts_are_rejected_not_raised():
    guard = StreamGuard(4)
    bad = [Frame(0, 0.0, np.array([0.0, np.nan, 0.0, 0.0])),
           Frame(1, 0.0, np.array([0.0, np.inf, 0.0, 0.0])),
           Frame(2, 0.0, np.zeros(5)), Frame(3, 0.0, np.zeros((2, 2))),
           Frame(4, 0.0, np.array(["a", "b", "c", "d"], dtype=object))]
    bad.append(Frame("x", 0.0, np.zeros(4)))  # type: ignore[arg-type]
    for f in bad:
        assert guard.accept(f) == ([], [], False)
    assert guard.counters.invalid == len(bad) and guard.counters.accepted == 0


def test_small_gap_is_bridged_by_interpolation_with_a_gap_event():
    guard = StreamGuard(4, max_bridge_frames=3)
    guard.accept(frame(10, 0.0))
    clean, gaps, restart = guard.accept(frame(14, 8.0))
    assert not restart
    assert [f.seq for f in clean] == [11, 12, 13, 14]
    np.testing.assert_allclose([f.channels[0] for f in clean], [2.0, 4.0, 6.0, 8.0])
    assert len(gaps) == 1 and gaps[0].first == 11 and gaps[0].last == 13 and gaps[0].bridged


def test_large_gap_restarts_the_window():
    guard = StreamGuard(4, max_bridge_frames=3)
    guard.accept(frame(10))
    clean, gaps, restart = guard.accept(frame(15))
    assert restart and [f.seq for f in clean] == [15]
    assert gaps[0].to_dict()["missing"] == 4 and not gaps[0].bridged
    assert guard.counters.restarts == 1


def test_feature_stage_gives_the_same_features_for_any_block_split():
    motion = read_bvh(DATA / "05_06.bvh")
    frames = motion.frames()
    whole = FeatureStage(motion.skeleton, motion.fps).compute(frames)
    stage = FeatureStage(motion.skeleton, motion.fps)
    parts = [stage.compute(frames[i : i + k]) for i, k in ((0, 1), (1, 5), (6, 200), (206, 679))]
    for name in ("rotations", "pelvis_positions", "foot_heights", "positions"):
        np.testing.assert_array_equal(np.concatenate([getattr(p, name) for p in parts]),
                                      getattr(whole, name), err_msg=name)


def test_a_seq_far_back_means_the_source_restarted():
    guard = StreamGuard(4, max_reorder_frames=50)
    for seq in range(300, 310):
        guard.accept(frame(seq))
    clean, events, restart = guard.accept(frame(0))
    assert restart and [f.seq for f in clean] == [0]
    assert events[0].status == "restart" and guard.counters.restarts == 1
    assert guard.accept(frame(1))[0][0].seq == 1
